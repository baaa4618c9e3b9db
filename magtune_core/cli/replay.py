"""``magtune replay``: republish a recorded bag with /clock through the player node.

``magtune replay bags/NAME [--rate R] [--topics ...] [--exclude REGEX] [--start S]
[--playback-duration S] [--playback-until T] [--start-paused] [--loop] [--foxglove [PORT]]
[--ros-args -r /a:=/b ...]`` validates the options against the bag (exit 2 with the reason),
runs the ``player`` executable of magtune_ros (see :mod:`magtune_core.ros.replay`) and returns
its exit status.
"""
from __future__ import annotations

import argparse
import sys

from ..bags.live import DEFAULT_PORT
from ..bags.playback import DEFAULT_WAIT_SUBSCRIBERS, ReplayOptions
from ..bags.scan import check_file
from ..ros.process import DDS_INTERFACES
from ..ros.replay import run_player


def register(sub) -> None:
    p = sub.add_parser("replay", help="republish a recorded bag (player node) with /clock",
                       description="Republish a recorded bag with /clock (the player node). Control services "
                                   "of the node /magtune_player, with the rosbag2_interfaces types of ros2 bag "
                                   "play: pause, resume, toggle_paused, is_paused, get_rate, set_rate, play_next, "
                                   "seek.")
    p.add_argument("bag", help="bag directory (bags/NAME) or .mcap file")
    p.add_argument("--rate", type=float, default=1.0, help="speed factor > 0 (0: as fast as acknowledged)")
    p.add_argument("--topics", nargs="+", default=None, help="only these topics (each must be in the bag)")
    p.add_argument("--exclude", default=None, metavar="REGEX", help="leave out the topics matching REGEX")
    p.add_argument("--start", type=float, default=0.0, help="skip the first S seconds of the bag")
    p.add_argument("--playback-duration", type=float, default=0.0, metavar="S",
                   help="stop S bag seconds after the start point (0: play to the end)")
    p.add_argument("--playback-until", type=float, default=None, metavar="T",
                   help="stop after log time T [s] (sim seconds; seconds since 1970 for --epoch-time bags)")
    p.add_argument("--start-paused", action="store_true",
                   help="start paused; resume with: ros2 service call /magtune_player/resume "
                        "rosbag2_interfaces/srv/Resume")
    p.add_argument("--loop", action="store_true", help="repeat until interrupted")
    p.add_argument("--no-clock", action="store_true", help="do not publish /clock")
    p.add_argument("--wait-subscribers", type=float, default=DEFAULT_WAIT_SUBSCRIBERS, metavar="S",
                   help=f"wait up to S seconds for a subscriber on every topic (default {DEFAULT_WAIT_SUBSCRIBERS:g}; "
                        "0: do not wait)")
    p.add_argument("--progress", choices=("auto", "on", "off"), default="auto",
                   help="progress line on stderr (auto: when it is a terminal)")
    p.add_argument("--foxglove", type=int, nargs="?", const=DEFAULT_PORT, default=None, metavar="PORT",
                   help=f"stream to Foxglove over WebSocket on localhost:PORT (default {DEFAULT_PORT})")
    p.add_argument("--dds-interfaces", choices=DDS_INTERFACES, default="loopback",
                   help="DDS network scope of the player: loopback (default: every DDS socket on 127.0.0.1) or all "
                        "(subscribers on other hosts; docs/reliability.md)")
    p.add_argument("--ros-args", nargs=argparse.REMAINDER, default=[], dest="ros_args",
                   help="everything after it goes to the player node (e.g. -r /sensors/attitude:=/other)")
    p.set_defaults(func=run)


def run(args) -> int:
    check_file(args.bag)  # missing, empty, no .mcap, not MCAP: one line, exit 2, nothing started
    return run_player(args.bag, ReplayOptions(
        rate=args.rate, topics=args.topics, exclude=args.exclude, start=args.start,
        playback_duration=args.playback_duration, playback_until=args.playback_until, loop=args.loop,
        no_clock=args.no_clock, start_paused=args.start_paused, wait_subscribers=args.wait_subscribers,
        progress=args.progress, foxglove=args.foxglove, ros_args=list(args.ros_args or [])),
        warn=lambda line: print(f"magtune replay: warning: {line}", file=sys.stderr, flush=True),
        dds_interfaces=args.dds_interfaces)
