"""The ``magtune`` command line: one module per subcommand, registered here, top of the layers.

Errors a user can cause print one line naming the file, the field and what was expected, and
exit with status 2 (bad input, nothing started) or 1 (a run failed): see
:func:`magtune_core.cli.common.run_command`. ``python -m magtune_core ARGS`` == ``magtune ARGS``.
"""
from __future__ import annotations

import argparse

from .. import __version__
from . import analyze, bag, campaign, export, export_check, fit_field, front, replay, report, sampling, sil, table1, tune, verify
from .common import DEFAULT_CONFIG, run_command

#: Subcommands in the order ``magtune --help`` lists them.
COMMANDS = (tune, verify, analyze, table1, front, fit_field, sil, replay, bag, report, sampling, campaign, export, export_check)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="magtune", description="H-infinity tuning of projection-based magnetorquer "
                                 "attitude controllers (Zanchettin & Lovera, IFAC 2011) and their ROS 2 SIL")
    ap.add_argument("--version", action="version", version=f"magtune {__version__}")
    ap.add_argument("--config", default=DEFAULT_CONFIG, help="spacecraft/orbit parameter file (default: config/spacecraft.yaml of the repository, "
                                                     "from any working directory)")
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for mod in COMMANDS:
        mod.register(sub)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(args)
