"""``magtune bag info|recover``: inspect a recorded bag, or repair one left unfinished.

``magtune bag info bags/NAME`` prints topics, counts, times and integrity (JSON with --json); exit status 1 when the bag
is not complete (damaged or unfinished: ``magtune bag recover`` it), 0 when it is.
``magtune bag recover bags/NAME`` rebuilds a bag left unfinished by a crash (SIGKILL, power
loss) or damaged on disk into ``bags/NAME_recovered`` (the input is never modified unless
``--in-place``): every chunk whose CRC is good is kept, the summary and ``metadata.yaml`` are
rebuilt, and the report says how many messages were recovered out of how many expected.
"""
from __future__ import annotations

import errno
import sys
from pathlib import Path

from .. import bags
from ..bags import recover
from ..bags.integrity import integrity_lines
from ..base import jsonout
from ..base.atomic import output_lock
from ..base.errors import ConfigError
from .common import CommandError


def register(sub) -> None:
    b = sub.add_parser("bag", help="inspect or repair recorded bags")
    bs = b.add_subparsers(dest="bag_cmd", required=True)
    i = bs.add_parser("info", help="topics, counts, duration, integrity (chunk CRCs), timing checks")
    i.add_argument("bag", help="bag directory (bags/NAME) or .mcap file")
    i.add_argument("--json", action="store_true", help="print the summary as JSON")
    i.add_argument("--ts", type=float, default=None,
                   help="tolerance of |log_time - stamp| in s (default: ts of metadata.yaml, else the /clock period)")
    i.set_defaults(func=run_info)
    r = bs.add_parser("recover", help="rebuild a damaged or unfinished bag (the input is never modified)")
    r.add_argument("bag", help="bag directory (bags/NAME) or .mcap file")
    r.add_argument("-o", "--output", default=None,
                   help="new bag directory (default: bags/NAME_recovered beside the input)")
    r.add_argument("--in-place", action="store_true",
                   help="replace the bag's MCAP and metadata.yaml (the damaged file is kept as .damaged)")
    r.set_defaults(func=run_recover)


def run_info(args) -> int:
    if args.ts is not None and not (0 < args.ts < float("inf")):
        raise ConfigError("--ts", None, f"expected a positive finite step in s, got {args.ts}")
    try:
        inf = bags.info(args.bag, ts=args.ts)
    except OSError as exc:
        raise ConfigError(args.bag, None, f"cannot read the bag: {exc.strerror or exc}") from None
    damaged = 0 if inf["complete"] else 1  # exit status: a script must not take a damaged bag for a good one
    if args.json:
        print(jsonout.dumps(inf, indent=1))
        return damaged
    integ, timing = inf["integrity"], inf["timing"]
    state = "complete" if inf["complete"] else "DAMAGED/UNFINISHED: run magtune bag recover"
    print(f"bag:      {inf['path']} ({inf['size_bytes']} bytes, {state})")
    print(f"messages: {inf['message_count']} in {inf['chunks']} chunks, "
          f"{inf['duration_s']:.3f} s from {inf['start_ns'] * 1e-9:.3f} s")
    print(f"start:    {inf['start_utc'] or '-'} ({inf['start_ns'] * 1e-9:.9f} s)")
    print(f"end:      {inf['end_utc'] or '-'} ({inf['end_ns'] * 1e-9:.9f} s)")
    print(f"storage:  {inf['storage_identifier']}   ROS distro: {inf['ros_distro'] or '-'}")
    print(f"files:    {len(inf['files'])}")
    for f in inf["files"]:
        print(f"  {f['path']}  {f['size_bytes']} bytes  {f['message_count']} messages"
              + ("" if f["complete"] else "  UNFINISHED/DAMAGED"))
    for name in inf["missing_files"]:
        print(f"  {name}  MISSING (listed in metadata.yaml)")
    for name, t in inf["topics"].items():
        print(f"  {name:32s} {t['type']:40s} {t['count']:8d}")
    for line in integrity_lines(integ):
        print(f"warning: {line}")
    for line in timing["warnings"]:
        print(f"warning: {line}")
    return damaged


#: Write errors that more space (or a larger quota or file-size limit) cures.
NO_SPACE = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def _recover_lock(args):
    """The lock of what ``bag recover`` writes: the output directory, or the bag itself in place."""
    if not args.in_place:
        return output_lock(args.output or recover.default_output(args.bag), "magtune bag recover", option="--output")
    bag = Path(args.bag)
    return output_lock(bag, "magtune bag recover --in-place", directory=bag.is_dir(), option="BAG")


def run_recover(args) -> int:
    recover.check_storage(args.bag)  # the input's problems first (no output directory made for them)
    try:
        with _recover_lock(args):  # one writer per output, for the whole run
            rep = recover.recover(args.bag, args.output, in_place=args.in_place)
    except OSError as exc:  # the partial output is already removed
        if exc.errno in NO_SPACE:  # disk full, quota, file-size limit
            raise CommandError(f"{args.bag}: cannot write the recovered bag ({exc.strerror or exc}); nothing was "
                               "written and the bag is untouched: free some space and run it again") from None
        raise CommandError(f"{args.bag}: {exc.filename or 'the bag'}: {exc.strerror or exc}; nothing was written and "
                           "the bag is untouched") from None
    print(jsonout.dumps(rep, indent=1))
    exp, meta = rep["messages_expected"], rep.get("messages_expected_metadata")
    print(f"recovered {rep['messages_recovered']} of {exp} messages"
          + (f" (metadata.yaml: {meta})" if meta is not None and meta != exp else "")
          + f" into {rep['output']} ({len(rep['recovered_files'])} file(s); "
          + ("original kept: " if args.in_place else "original untouched: ") + f"{rep['original_kept']})", file=sys.stderr)
    for line in integrity_lines(rep):
        print(f"warning: {line}", file=sys.stderr)
    return 0
