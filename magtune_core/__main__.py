"""``python -m magtune_core ARGS``: the ``magtune`` command line."""
import sys

from .cli import main

sys.exit(main())
