"""``magtune report``: paper Figs. 2-5 and figures of merit from recorded bags (:mod:`..studies.report`)."""
from __future__ import annotations

import sys
from pathlib import Path

from ..bags.scan import check_file
from ..base.atomic import output_lock
from ..base.errors import ConfigError
from ..base.topics import DIPOLE, TRUTH
from ..onboard.law import DEFAULT_DIPOLE_LIMIT
from ..studies import report
from .bag import integrity_lines
from .common import CommandError, check_output, plain_summary, say


def register(sub) -> None:
    p = sub.add_parser("report", help="paper Figs. 2-5 and figures of merit from recorded bags",
                       description=plain_summary(report.__doc__))
    p.add_argument("bags", nargs="+", help="bag directories (bags/NAME)")
    p.add_argument("--out", required=True,
                   help="output directory (reports/NAME/); its figures, summary.md/.json and report.html are "
                        "rewritten")
    p.add_argument("--run", default=None,
                   help="only this run in Figs. 4-5 (bag name, or bag/NS for a namespaced satellite; default: "
                        "every run, one panel each)")
    p.add_argument("--dipole-limit", type=float, default=DEFAULT_DIPOLE_LIMIT,
                   help=f"per-axis dipole limit drawn in Fig. 5 [A m^2] (default {DEFAULT_DIPOLE_LIMIT:g}, the "
                        "simulator's dipole_limit)")
    p.add_argument("--labels", nargs="+", default=None,
                   help="legend labels, one per bag (default: custom_data sigma or bag name)")
    p.add_argument("--truth-topic", default=TRUTH, help=f"nav_msgs/Odometry truth topic (default {TRUTH})")
    p.add_argument("--dipole-topic", default=DIPOLE, help=f"dipole command topic (default {DIPOLE})")
    p.add_argument("--truth-twist", choices=report.TWIST_MODES, default="relative",
                   help="how to read the truth twist when the bag has no sim/inertial_rate topic: relative "
                        "(default; body w.r.t. orbital frame, REP-105) or inertial (bags recorded before 0.3)")
    p.add_argument("--orbit-period", type=float, default=None, help="s (default: spacecraft.yaml)")
    p.set_defaults(func=run)


def run(args) -> int:
    check_output(args.out, option="--out", directory=True)
    if not args.dipole_limit > 0:
        raise CommandError("--dipole-limit must be positive", code=2)
    for b in args.bags:  # missing, loop, no .mcap, not MCAP: one line, exit 2, before any work
        check_file(b)
    with output_lock(args.out, "magtune report"):  # one writer per output, for the whole run
        say("report", f"decoding {len(args.bags)} bag(s) and drawing Figs. 2-5 into {args.out}")
        try:
            s = report.make_report(args.bags, args.out, run=args.run, truth=args.truth_topic,
                                   dipole=args.dipole_topic, orbit_period=args.orbit_period, labels=args.labels,
                                   dipole_limit=args.dipole_limit, twist=args.truth_twist)
        except ConfigError:
            raise
        except (OSError, ValueError) as exc:
            raise CommandError(str(exc)) from None
        print(Path(args.out, "summary.md").read_text())
    for name, run in s.items():  # every damaged or missing file, every count metadata.yaml gets wrong
        for line in [] if run["integrity"]["complete"] else integrity_lines(run["integrity"]) or ["bag not complete"]:
            print(f"magtune report: warning: {name}: {line}", file=sys.stderr)
    return 0 if s else 1
