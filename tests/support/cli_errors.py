"""The bad-input contract of every command, asserted one way: exit 2 and one line, no traceback."""
from __future__ import annotations

from magtune_core.cli import main as cli_main


def one_line_exit2(capsys, argv) -> str:
    """Run ``magtune argv`` in-process; assert exit 2 with exactly one stderr line; return that line."""
    code = cli_main(argv)
    err = capsys.readouterr().err
    assert code == 2, (argv, err)
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    return err
