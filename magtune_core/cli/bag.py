"""``magtune bag info|recover``: inspect a recorded bag, or repair one left unfinished.

``magtune bag info bags/NAME`` prints topics, counts, times and integrity (JSON with --json).
``magtune bag recover bags/NAME`` rewrites a bag left unfinished by a crash (SIGKILL, power
loss): every complete chunk is kept, the summary and ``metadata.yaml`` are rebuilt, and the
report says what was recovered and what was lost.
"""
from __future__ import annotations

import json

from .. import bags
from ..bags import recover
from .common import CommandError


def register(sub) -> None:
    b = sub.add_parser("bag", help="inspect or repair recorded bags")
    bs = b.add_subparsers(dest="bag_cmd", required=True)
    i = bs.add_parser("info", help="topics, counts, duration, integrity")
    i.add_argument("bag", help="bag directory (bags/NAME) or .mcap file")
    i.add_argument("--json", action="store_true", help="print the summary as JSON")
    i.set_defaults(func=run_info)
    r = bs.add_parser("recover", help="rebuild summary + metadata.yaml of an unfinished bag")
    r.add_argument("bag", help="bag directory (bags/NAME)")
    r.add_argument("--keep-original", action="store_true", help="keep the damaged file as .damaged")
    r.set_defaults(func=run_recover)


def run_info(args) -> int:
    try:
        inf = bags.info(args.bag)
    except (OSError, ValueError) as exc:
        raise CommandError(str(exc)) from None
    if args.json:
        print(json.dumps(inf, indent=1))
        return 0
    print(f"bag:      {inf['path']} ({inf['size_bytes']} bytes, "
          f"{'complete' if inf['complete'] else 'UNFINISHED/DAMAGED: run magtune bag recover'})")
    print(f"messages: {inf['message_count']} in {inf['chunks']} chunks, "
          f"{inf['duration_s']:.3f} s from {inf['start_ns'] * 1e-9:.3f} s")
    print(f"start:    {inf['start_utc'] or '-'} ({inf['start_ns'] * 1e-9:.9f} s)")
    print(f"end:      {inf['end_utc'] or '-'} ({inf['end_ns'] * 1e-9:.9f} s)")
    print(f"storage:  {inf['storage_identifier']}   ROS distro: {inf['ros_distro'] or '-'}")
    print(f"files:    {len(inf['files'])}")
    for f in inf["files"]:
        print(f"  {f['path']}  {f['size_bytes']} bytes  {f['message_count']} messages"
              + ("" if f["complete"] else "  UNFINISHED/DAMAGED"))
    for name, t in inf["topics"].items():
        print(f"  {name:32s} {t['type']:40s} {t['count']:8d}")
    return 0


def run_recover(args) -> int:
    try:
        rep = recover.recover(args.bag, keep_original=args.keep_original)
    except (OSError, ValueError) as exc:
        raise CommandError(str(exc)) from None
    print(json.dumps(rep, indent=1))
    return 0
