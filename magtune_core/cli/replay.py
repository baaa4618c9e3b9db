"""``magtune replay``: republish a recorded bag with /clock through the player node.

``magtune replay bags/NAME [--rate R] [--topics ...] [--start S] [--loop]`` runs the ``player``
executable of magtune_ros (see :mod:`magtune_core.ros.replay`) and returns its exit status.
"""
from __future__ import annotations

from ..bags.scan import check_file
from ..ros.replay import ReplayOptions, run_player


def register(sub) -> None:
    p = sub.add_parser("replay", help="republish a recorded bag (player node) with /clock")
    p.add_argument("bag", help="bag directory (bags/NAME)")
    p.add_argument("--rate", type=float, default=1.0, help="speed factor (0: as fast as possible)")
    p.add_argument("--topics", nargs="+", default=None, help="only these topics")
    p.add_argument("--start", type=float, default=0.0, help="skip the first S seconds")
    p.add_argument("--loop", action="store_true", help="repeat until interrupted")
    p.add_argument("--no-clock", action="store_true", help="do not publish /clock")
    p.add_argument("--wait-subscribers", type=float, default=0.0,
                   help="wait up to S seconds for a subscriber on every topic")
    p.set_defaults(func=run)


def run(args) -> int:
    check_file(args.bag)  # missing, empty, no .mcap, not MCAP: one line, exit 2, nothing started
    return run_player(args.bag, ReplayOptions(rate=args.rate, topics=args.topics, start=args.start, loop=args.loop,
                                              no_clock=args.no_clock, wait_subscribers=args.wait_subscribers))
