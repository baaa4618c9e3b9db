"""``magtune replay`` and ``magtune bag info|recover``: CLI entry points (no rclpy here).

``magtune replay bags/NAME [--rate R] [--topics ...] [--start S] [--loop]`` runs the ``player``
executable of magtune_ros (``<prefix>/lib/magtune_ros/player``, where ``ros2 run`` looks) as a
subprocess with the caller's ROS environment (ROS_DOMAIN_ID etc.), forwards Ctrl-C/SIGTERM to
it and returns its exit status; the player prints a JSON line with what it published and,
for a damaged bag, what it could not read.

``magtune bag info bags/NAME`` prints topics, counts, times and integrity (JSON with --json).
``magtune bag recover bags/NAME`` rewrites a bag left unfinished by a crash (SIGKILL, power
loss): every complete chunk is kept, the summary and ``metadata.yaml`` are rebuilt, and the
report says what was recovered and what was lost.

Registration (cli.py)::

    from magtune_core import replay, report
    replay.add_parser(sub)       # adds 'replay' and 'bag'
    report.add_parser(sub)       # adds 'report'
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

from . import bag as baglib
from . import bag_recover

PACKAGE = "magtune_ros"
ROOT = Path(__file__).resolve().parents[1]


def find_executable(exe: str, package: str = PACKAGE) -> Path:
    """``<prefix>/lib/<package>/<exe>`` for the first AMENT_PREFIX_PATH prefix that has it,
    else the workspace's ``ros2_ws/install/<package>``."""
    prefixes = [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    prefixes.append(ROOT / "ros2_ws" / "install" / package)
    for pre in prefixes:
        cand = pre / "lib" / package / exe
        if cand.is_file() and os.access(cand, os.X_OK):
            return cand
    raise FileNotFoundError(f"'{exe}' of {package} not found (run scripts/bootstrap.sh and "
                            f"source scripts/env.sh)")


def _child_env() -> dict:
    env = dict(os.environ)
    inst = ROOT / "ros2_ws" / "install" / PACKAGE
    site = inst / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"
    env["AMENT_PREFIX_PATH"] = os.pathsep.join(
        [str(inst)] + [p for p in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p])
    env["PYTHONPATH"] = os.pathsep.join(
        [str(site), str(ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    return env


def player_command(args) -> list[str]:
    cmd = [str(find_executable("player")), str(args.bag), "--rate", str(args.rate)]
    if args.topics:
        cmd += ["--topics", *args.topics]
    if args.start:
        cmd += ["--start", str(args.start)]
    if args.loop:
        cmd.append("--loop")
    if args.no_clock:
        cmd.append("--no-clock")
    if args.wait_subscribers:
        cmd += ["--wait-subscribers", str(args.wait_subscribers)]
    return cmd


def cmd_replay(args) -> int:
    if not Path(args.bag).exists():
        print(f"magtune replay: {args.bag}: no such bag", file=sys.stderr)
        return 1
    try:
        cmd = player_command(args)
    except FileNotFoundError as exc:
        print(f"magtune replay: {exc}", file=sys.stderr)
        return 1
    proc = subprocess.Popen(cmd, env=_child_env(), start_new_session=True)

    def forward(signum, frame):  # noqa: ARG001
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)

    old = {s: signal.signal(s, forward) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        return proc.wait()
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def cmd_info(args) -> int:
    try:
        inf = baglib.info(args.bag)
    except (OSError, ValueError) as exc:
        print(f"magtune bag info: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(inf, indent=1))
        return 0
    print(f"bag:      {inf['path']} ({inf['size_bytes']} bytes, "
          f"{'complete' if inf['complete'] else 'UNFINISHED/DAMAGED: run magtune bag recover'})")
    print(f"messages: {inf['message_count']} in {inf['chunks']} chunks, "
          f"{inf['duration_s']:.3f} s from {inf['start_ns'] * 1e-9:.3f} s")
    for name, t in inf["topics"].items():
        print(f"  {name:32s} {t['type']:40s} {t['count']:8d}")
    return 0


def cmd_recover(args) -> int:
    try:
        rep = bag_recover.recover(args.bag, keep_original=args.keep_original)
    except (OSError, ValueError) as exc:
        print(f"magtune bag recover: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(rep, indent=1))
    return 0


def add_parser(subparsers) -> None:
    """Register ``replay`` and ``bag {info,recover}`` on an argparse subparsers object."""
    p = subparsers.add_parser("replay", help="republish a recorded bag (player node) with /clock")
    p.add_argument("bag", help="bag directory (bags/NAME)")
    p.add_argument("--rate", type=float, default=1.0, help="speed factor (0: as fast as possible)")
    p.add_argument("--topics", nargs="+", default=None, help="only these topics")
    p.add_argument("--start", type=float, default=0.0, help="skip the first S seconds")
    p.add_argument("--loop", action="store_true", help="repeat until interrupted")
    p.add_argument("--no-clock", action="store_true", help="do not publish /clock")
    p.add_argument("--wait-subscribers", type=float, default=0.0,
                   help="wait up to S seconds for a subscriber on every topic")
    p.set_defaults(func=cmd_replay)

    b = subparsers.add_parser("bag", help="inspect or repair recorded bags")
    bs = b.add_subparsers(dest="bag_cmd", required=True)
    i = bs.add_parser("info", help="topics, counts, duration, integrity")
    i.add_argument("bag")
    i.add_argument("--json", action="store_true")
    i.set_defaults(func=cmd_info)
    r = bs.add_parser("recover", help="rebuild summary + metadata.yaml of an unfinished bag")
    r.add_argument("bag")
    r.add_argument("--keep-original", action="store_true", help="keep the damaged file as .damaged")
    r.set_defaults(func=cmd_recover)


def main(argv=None) -> int:
    from .cli import command_main
    return command_main(None, argv)


if __name__ == "__main__":
    sys.exit(main())
