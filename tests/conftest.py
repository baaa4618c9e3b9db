"""Shared test setup: the helpers in tests/support are importable by name, markers are defined
in pyproject.toml (``ros``: starts real rclpy nodes over DDS; ``slow``: long numerical checks)."""
from __future__ import annotations

import sys
from pathlib import Path

SUPPORT = Path(__file__).resolve().parent / "support"
if str(SUPPORT) not in sys.path:
    sys.path.insert(0, str(SUPPORT))
