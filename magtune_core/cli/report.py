"""``magtune report``: paper Figs. 2-5 and figures of merit from recorded bags (:mod:`..studies.report`)."""
from __future__ import annotations

from pathlib import Path

from ..base.topics import DIPOLE, TRUTH
from ..studies import report
from .common import CommandError, plain_summary


def register(sub) -> None:
    p = sub.add_parser("report", help="paper Figs. 2-5 and figures of merit from recorded bags",
                       description=plain_summary(report.__doc__))
    p.add_argument("bags", nargs="+", help="bag directories (bags/NAME)")
    p.add_argument("--out", required=True, help="output directory (reports/NAME/)")
    p.add_argument("--run", default=None, help="bag name for Figs. 4-5 (default: largest sigma)")
    p.add_argument("--labels", nargs="+", default=None,
                   help="legend labels, one per bag (default: custom_data sigma or bag name)")
    p.add_argument("--truth-topic", default=TRUTH, help=f"nav_msgs/Odometry truth topic (default {TRUTH})")
    p.add_argument("--dipole-topic", default=DIPOLE, help=f"dipole command topic (default {DIPOLE})")
    p.add_argument("--orbit-period", type=float, default=None, help="s (default: spacecraft.yaml)")
    p.set_defaults(func=run)


def run(args) -> int:
    try:
        s = report.make_report(args.bags, args.out, run=args.run, truth=args.truth_topic,
                               dipole=args.dipole_topic, orbit_period=args.orbit_period, labels=args.labels)
    except (OSError, ValueError) as exc:
        raise CommandError(str(exc)) from None
    print(Path(args.out, "summary.md").read_text())
    return 0 if s else 1
