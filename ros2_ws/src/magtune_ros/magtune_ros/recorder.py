"""``recorder`` node: record topics to a rosbag2-compatible MCAP bag (``magtune_core.bags``).

Usage (``ros2 run magtune_ros recorder`` or ``install/magtune_ros/lib/magtune_ros/recorder``)::

    recorder -o bags/NAME [--topics /a /b:pkg/msg/Type ...] [--all] [--custom-data k=v ...]
             [--chunk-size BYTES] [--flush-period S] [--depth N] [--wall-time]
             [--max-messages N] [--duration S] [-e REGEX] [-x REGEX]
             [--max-bag-size BYTES] [--max-bag-duration S]
    recorder --ros-args -p path:=bags/NAME [-p topics:="['/a', ...]"] [-p custom_data:="['sigma=60']"]

Every option is also a ROS parameter of the same name (``path`` for ``-o``; dashes become
underscores); a command-line option wins over the parameter. Without ``--topics`` and
``--all`` the project's topics (:data:`magtune_core.base.topics.PROJECT_TOPICS`) are recorded;
the project's topics under a namespace (``/sat1/sim/truth``) get their type and durability too.

Design:

* subscriptions are ``raw=True`` (the callback gets the serialized CDR bytes; nothing is
  deserialized); QoS adapted to the publishers' offers (reliable when they all are), KEEP_LAST
  with a deep queue (``--depth``, default 10000: seconds of backlog at full SIL speed);
* log time of a message with a header (every project topic but ``/clock``) = its header stamp
  in sim-time mode: so a bag's log time is never earlier than the stamp nor later by any amount,
  whatever the load (the lockstep publishers stamp each sample with the sim time of the step it
  belongs to, which is the sim time at which it was sent). Under CPU load the mapping below
  drifted by up to +-100 s (issue #10), which made replayed inputs stale;
* otherwise (``/clock``, headerless types) log time = receive time in sim time (unless
  ``--wall-time``): the recorder always listens to
  ``/clock`` and keeps a table (DDS receive wall time of each ``/clock`` sample -> its sim
  time); a message gets the sim time of the last ``/clock`` that DDS delivered before the
  message itself (``MessageInfo.received_timestamp``). So the log time does not depend on how
  far the Python executor lags behind at full SIL speed. publish_time is the sim time at the
  publisher's send (``source_timestamp`` mapped through the /clock samples' own source
  stamps, as rosbag2's send_timestamp); it differs from log_time only for samples delivered
  late, e.g. the transient-local history a late-matching recorder receives;
* the executor thread only appends ``(topic, receive stamp, bytes, source stamp)`` to a
  deque (each callback also drains every sample already queued on its subscription); a
  writer thread drains the deque into the MCAP writer, so disk I/O and zstd never block message intake;
* every completed chunk goes straight to the OS, and the open chunk is closed every
  ``--flush-period`` wall seconds (default 1 s): after SIGKILL at most that much is lost;
* SIGINT/SIGTERM: stop taking new work, drain what DDS already delivered, write the summary
  and ``metadata.yaml``, print a JSON line with the per-topic counts, exit 0.

Topics given with a type (``/name:pkg/msg/Type``) are subscribed at once, so the recorder is
ready before any publisher exists (``magtune-recorder ready`` is printed on stdout); topics
without a type, and ``--all``, are discovered from the graph every 0.2 s.
"""
from __future__ import annotations

import argparse
import bisect
import collections
import json
import struct
import sys
import threading
import time

from rclpy.clock import Clock, ClockType
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

from magtune_core.bags import msgdefs
from magtune_core.bags.msgdefs import normalize_type
from magtune_core.bags.record_options import RECORDER_FIELDS, recording_options
from magtune_core.bags.timing import has_header, stamp_from_cdr
from magtune_core.bags.writer import BagWriter
from magtune_core.base.errors import ConfigError
from magtune_core.base.topics import project_topic

from .bag_common import HIDDEN_TOPICS, adapt_request, message_class, qos_profile_dict
from .main import run
from .params import ParamError, declare_fields

CLOCK = "/clock"


def parse_args(argv):
    """The command line without the ROS arguments; an option left out is None, so the ROS parameter of that name applies."""
    p = argparse.ArgumentParser(prog="recorder", description=__doc__.split("\n\n")[0])
    p.add_argument("-o", "--output", "--path", dest="output", default=None,
                   help="bag directory to create (bags/NAME)")
    p.add_argument("--topics", nargs="*", default=None,
                   help="topics to record: /name or /name:pkg/msg/Type (typed: subscribed at once)")
    p.add_argument("--all", action="store_true", default=None, help="record every discovered topic")
    p.add_argument("--include-hidden", action="store_true", default=None,
                   help="with --all, also /rosout and /parameter_events")
    p.add_argument("--custom-data", nargs="*", default=None, metavar="KEY=VALUE",
                   help="stored in metadata.yaml custom_data (e.g. sigma=60)")
    p.add_argument("--chunk-size", type=int, default=None, help="MCAP chunk size in bytes")
    p.add_argument("--flush-period", type=float, default=None,
                   help="close the open chunk every S wall seconds (crash safety; default 1)")
    p.add_argument("--depth", type=int, default=None, help="subscription queue depth (10000)")
    p.add_argument("--wall-time", action="store_true", default=None, help="log wall time, not sim time")
    p.add_argument("--max-messages", type=int, default=None, help="stop after N messages (0: never)")
    p.add_argument("--duration", type=float, default=None, help="stop after S wall seconds (0: never)")
    p.add_argument("-e", "--regex", default=None, metavar="REGEX",
                   help="also record every discovered topic matching REGEX (as ros2 bag record -e)")
    p.add_argument("-x", "--exclude", default=None, metavar="REGEX",
                   help="never record topics matching REGEX (applies to --topics, --regex and --all)")
    p.add_argument("-b", "--max-bag-size", type=int, default=None, metavar="BYTES",
                   help="split: start NAME_<i+1>.mcap when the file holds BYTES (at a chunk boundary; 0: never)")
    p.add_argument("-d", "--max-bag-duration", type=float, default=None, metavar="S",
                   help="split: start a new file every S seconds of log time (0: never)")
    p.add_argument("--overwrite", action="store_true", default=None)
    return p.parse_args(argv)


def resolve_options(node: Node, args) -> argparse.Namespace:
    """Command-line options, else ROS parameters (:data:`RECORDER_FIELDS`), else defaults;
    validated once (:func:`magtune_core.bags.record_options.recording_options`)."""
    values = declare_fields(node, RECORDER_FIELDS)
    values.update({("path" if k == "output" else k): v for k, v in vars(args).items() if v is not None})
    try:
        v = recording_options(values, f"node '{node.get_name()}'")
    except ConfigError as exc:
        raise ParamError(exc.field or "?", exc.expected) from None
    v["output"] = v.pop("path")
    return argparse.Namespace(**v)


class SimClockMap:
    """Maps DDS receive timestamps (wall ns) to sim time, from the ``/clock`` samples seen.

    Each ``/clock`` sample is stored with the wall time DDS received it; a message received at
    wall time ``w`` gets the sim time of the last ``/clock`` received at or before ``w``. This
    is the sim time at reception, independent of how far the executor lags behind.
    """

    def __init__(self):
        self.walls: list[int] = []
        self.sims: list[int] = []
        self.source: "SimClockMap | None" = None   # same table keyed by source timestamps

    def add(self, wall_ns: int, sim_ns: int) -> None:
        """Store a /clock sample: its receive wall time (clamped so the table stays sorted) and its sim time."""
        if self.walls and wall_ns < self.walls[-1]:
            wall_ns = self.walls[-1]          # keep the table sorted (equal stamps are fine)
        self.walls.append(wall_ns)
        self.sims.append(sim_ns)

    @property
    def last_wall(self) -> int:
        """Receive wall time of the newest /clock sample (-1 before any): the writer's readiness test."""
        return self.walls[-1] if self.walls else -1

    def sim_at(self, wall_ns: int) -> int:
        """Sim time of the last /clock received at or before ``wall_ns`` (earlier: the earliest sim time known)."""
        i = bisect.bisect_right(self.walls, wall_ns) - 1
        # received before the first /clock: the earliest sim time known (the run's start; 0 or the
        # scenario epoch), not 0, which would put an epoch-stamped bag's start in 1970
        return self.sims[i] if i >= 0 else (self.sims[0] if self.sims else 0)


def _has_header(typ: str) -> bool:
    """True if the type's first field is a std_msgs/Header (False for unknown types)."""
    try:
        return has_header(msgdefs.full_definition(typ))
    except Exception:  # noqa: BLE001 - a type the typestore does not know: no stamp used
        return False


def clock_from_cdr(data: bytes) -> int:
    """Sim time (ns) of a serialized rosgraph_msgs/Clock (CDR: 4-byte header, int32, uint32)."""
    endian = "<" if data[1] == 1 else ">"
    sec, nsec = struct.unpack_from(endian + "iI", data, 4)
    return sec * 1_000_000_000 + nsec


class BagWriterThread(threading.Thread):
    """Drains the intake deque into a :class:`BagWriter`; flushes the chunk periodically.

    Items carry the DDS receive time (wall ns). In sim-time mode an item is written once the
    clock map has a ``/clock`` sample received after it (so its sim time is final), or after
    ``hold_s`` seconds without one (end of the run), or at shutdown.
    """

    def __init__(self, writer: BagWriter, flush_period: float, clock_map: SimClockMap | None,
                 hold_s: float = 0.5):
        super().__init__(name="bag-writer", daemon=True)
        self.writer = writer
        self.queue: collections.deque = collections.deque()
        self.flush_period = flush_period
        self.clock_map = clock_map
        self.hold_ns = int(hold_s * 1e9)
        self._halt = threading.Event()
        self.written = 0
        self.error: BaseException | None = None

    def _ready(self, wall_ns: int) -> bool:
        cm = self.clock_map
        # (nothing is written before the first /clock: its sim time is the run's start)
        return (cm is None or self._halt.is_set() or cm.last_wall > wall_ns
                or (bool(cm.walls) and time.time_ns() - wall_ns > self.hold_ns))

    def run(self):
        """Thread body: write the queued registrations and messages (once their sim time is final), flush every ``flush_period``,
        until halted and drained; an exception is kept in ``error``."""
        last_flush = time.monotonic()
        dirty = False
        q, w, cm = self.queue, self.writer, self.clock_map
        try:
            while True:
                n = 0
                while q:
                    item = q[0]
                    if item[0] is None:          # topic registration
                        _, name, typ, profiles = item
                        w.add_topic(name, typ, profiles)
                    else:
                        if not self._ready(item[1]):
                            break
                        if cm is None:
                            t, tp = item[1], item[3]
                        else:
                            t, tp = cm.sim_at(item[1]), cm.source.sim_at(item[3])
                            s = stamp_from_cdr(item[2]) if item[4] else None
                            if s:  # stamped message: logged at its header stamp (see module doc)
                                t = s
                        w.write(item[0], item[2], t, tp)
                        n += 1
                        self.written += 1  # counted per message: a failing batch keeps what is on disk
                    q.popleft()
                dirty = dirty or n > 0
                now = time.monotonic()
                if dirty and now - last_flush >= self.flush_period:
                    w.flush()
                    dirty, last_flush = False, now
                if self._halt.is_set() and not q:
                    break
                if n == 0:
                    time.sleep(0.002)
        except BaseException as exc:  # noqa: BLE001 - reported by the node on exit
            self.error = exc

    def finish(self):
        """Stop, write what is queued, close the bag. After a write error (disk full) the bag
        is left as it is: every chunk completed before the error is readable and
        ``magtune bag recover`` rebuilds it (closing could not succeed on a full disk)."""
        self._halt.set()
        self.join()
        if self.error is None:
            try:
                self.writer.close()
            except Exception as exc:  # noqa: BLE001 - reported by the node on exit
                self.error = exc


class Recorder(Node):
    """Subscribes raw to the selected topics and hands the bytes to the writer thread."""

    NODE_NAME = "recorder"
    EXECUTOR = SingleThreadedExecutor
    START_ERRORS = (FileExistsError, OSError, ValueError)
    parse_options = staticmethod(parse_args)

    def __init__(self, cli_args):
        super().__init__(self.NODE_NAME)
        self.closed = False
        self.args = args = resolve_options(self, cli_args)
        custom = dict(kv.split("=", 1) for kv in args.custom_data)
        self.bag = BagWriter(args.output, chunk_size=args.chunk_size, custom_data=custom,
                             overwrite=args.overwrite, max_bytes=args.max_bag_size,
                             max_duration_ns=int(args.max_bag_duration * 1e9))
        self.clock_map = None if args.wall_time else SimClockMap()
        if self.clock_map is not None:
            self.clock_map.source = SimClockMap()
        self.thread = BagWriterThread(self.bag, args.flush_period, self.clock_map)
        self.thread.start()
        self.wanted: dict[str, str | None] = {}
        for spec in args.topics:
            name, _, typ = spec.partition(":")
            name = "/" + name.lstrip("/")
            if not typ and project_topic(name):  # also under a namespace: /sat1/sim/truth
                typ = project_topic(name)[0]
            if args.exclude is not None and args.exclude.search(name):
                continue
            self.wanted[name] = normalize_type(typ) if typ else None
        self.subs = {}
        self.types: dict[str, str] = {}
        self.registered: set[str] = set()
        self.matched: set[str] = set()
        self.all_matched = False
        self.counts: collections.Counter = collections.Counter()
        self.received = 0
        self.max_lag_ns = 0  # largest (take time - DDS receive time): how far intake lagged
        if self.clock_map is not None:
            self._subscribe(CLOCK, "rosgraph_msgs/msg/Clock")
        for name, typ in self.wanted.items():
            if typ and name not in self.subs:
                self._subscribe(name, typ)
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(0.2, self._discover, clock=self._steady)
        self.create_timer(0.02, self._report_matches, clock=self._steady)
        self._discover()

    def spin(self, executor, stop) -> int:
        """Record until a stop signal, ``max_messages`` or ``duration``; drain; close the bag."""
        args = self.args
        print("magtune-recorder ready", flush=True)
        t0 = time.monotonic()
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.1)
            if args.max_messages and self.received >= args.max_messages:
                break
            if args.duration and time.monotonic() - t0 >= args.duration:
                break
            if self.thread.error:
                break
        # drain what DDS has already delivered: spin until 3 idle rounds of 50 ms
        idle = 0
        while idle < 3 and not self.thread.error and not (args.max_messages and self.received >= args.max_messages):
            before = self.received
            executor.spin_once(timeout_sec=0.05)
            idle = idle + 1 if self.received == before else 0
        return self.finish()

    def finish(self) -> int:
        """Close the bag (once), print the JSON summary; 1 if writing failed."""
        if self.closed:
            return 0
        self.closed = True
        self.thread.finish()
        summary = {"bag": str(self.bag.dir), "messages": self.thread.written,
                   "per_topic": dict(sorted(self.counts.items())),
                   "max_intake_lag_s": round(self.max_lag_ns * 1e-9, 4)}
        print(json.dumps(summary), flush=True)
        err = self.thread.error
        if err is None:
            return 0
        why = getattr(err, "strerror", None) or str(err)
        print(f"recorder: writing {self.bag.dir} failed ({why}) after {self.thread.written} messages; "
              f"the chunks written before are readable: magtune bag recover {self.bag.dir}",
              file=sys.stderr, flush=True)
        return 1

    def _selected(self, name: str) -> bool:
        a = self.args
        if a.exclude is not None and a.exclude.search(name):
            return False
        return name in self.wanted or ((a.all or (a.regex is not None and a.regex.search(name))) and (
            a.include_hidden or name not in HIDDEN_TOPICS))

    def _report_matches(self):
        """Print ``magtune-recorder matched /topic`` once per topic when its first publisher is
        matched, and ``magtune-recorder matched all`` when every requested topic is (a runner
        can wait for these lines before starting the publishers' clock)."""
        for name, sub in self.subs.items():
            if name not in self.matched and sub.get_publisher_count() > 0:
                self.matched.add(name)
                print(f"magtune-recorder matched {name}", flush=True)
        if not self.all_matched and self.wanted and all(n in self.matched for n in self.wanted):
            self.all_matched = True
            print("magtune-recorder matched all", flush=True)

    def _discover(self):
        """Subscribe to newly seen selected topics; downgrade a reliable subscription made
        before its publishers existed if one of them turns out to be best effort."""
        self._report_matches()
        for name, types in self.get_topic_names_and_types():
            if name not in self.subs and types and self._selected(name):
                self._subscribe(name, normalize_type(types[0]))
        for name, sub in list(self.subs.items()):
            offers = [i.qos_profile for i in self.get_publishers_info_by_topic(name)]
            q = sub.qos_profile
            if (q.reliability == ReliabilityPolicy.RELIABLE and any(
                    o.reliability == ReliabilityPolicy.BEST_EFFORT for o in offers)) or (
                    q.durability == DurabilityPolicy.TRANSIENT_LOCAL and any(
                    o.durability == DurabilityPolicy.VOLATILE for o in offers)):
                self.get_logger().warning(f"{name}: a publisher's QoS is incompatible; resubscribing")
                self.destroy_subscription(sub)
                del self.subs[name]
                self._subscribe(name, self.types[name])

    def _subscribe(self, name: str, typ: str):
        offered = [i.qos_profile for i in self.get_publishers_info_by_topic(name)]
        qos = adapt_request(offered, self.args.depth)
        if not offered and (project_topic(name) or ("", ""))[1] == "transient_local":
            # subscribed before its publisher exists: ask for the late-joiner history the
            # project's lockstep publishers keep (transient-local, depth 100)
            qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
        holder = {}
        self.types[name] = typ
        sub = self.create_subscription(message_class(typ), name,
                                       self._make_callback(name, typ, holder), qos, raw=True)
        holder["sub"] = sub
        self.subs[name] = sub

    def _make_callback(self, name: str, typ: str, holder: dict):
        """Callback that also drains every further sample already queued on the subscription
        (one executor round per burst instead of per message)."""
        q = self.thread.queue
        record = self._selected(name)
        cm = self.clock_map if name == CLOCK else None
        stamped = name != CLOCK and _has_header(typ)

        def handle(data: bytes, info: dict):
            wall = info["received_timestamp"]
            lag = time.time_ns() - wall
            if lag > self.max_lag_ns:
                self.max_lag_ns = lag
            if cm is not None:
                t_sim = clock_from_cdr(data)
                cm.add(wall, t_sim)
                cm.source.add(info["source_timestamp"], t_sim)
            if not record:
                return
            if name not in self.registered:
                self.registered.add(name)
                offered = [qos_profile_dict(i.qos_profile)
                           for i in self.get_publishers_info_by_topic(name)]
                q.append((None, name, typ, offered))
            q.append((name, wall, data, info["source_timestamp"], stamped))
            self.counts[name] += 1
            self.received += 1

        def callback(data: bytes, info: dict):
            handle(data, info)
            sub = holder["sub"]
            with sub.handle:
                while True:
                    r = sub.handle.take_message(sub.msg_type, True)
                    if r is None:
                        break
                    handle(r[0], r[1])
        return callback


def main(argv=None):
    """Entry point of the recorder node (console script): run(Recorder)'s exit status."""
    return run(Recorder, argv)


if __name__ == "__main__":
    raise SystemExit(main())
