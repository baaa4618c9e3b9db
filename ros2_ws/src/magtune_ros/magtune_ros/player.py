"""``player`` node: republish a bag's messages at their recorded (sim) times, with ``/clock``.

Usage (``ros2 run magtune_ros player`` or ``install/magtune_ros/lib/magtune_ros/player``)::

    player bags/NAME [--rate R] [--topics /a /b] [--exclude REGEX] [--start S]
                     [--playback-duration S] [--playback-until T] [--start-paused] [--loop]
                     [--no-clock] [--depth N] [--wait-subscribers S] [--progress auto|on|off]
                     [--foxglove PORT] [--ros-args -r /a:=/b ...]

Options are validated against the bag first (:func:`magtune_core.bags.playback.validate`): a bad
rate, a start past the end, an unknown topic, ... print one line and exit with status 2.

* every message is published as its recorded CDR bytes (``Publisher.publish(bytes)`` ->
  ``publish_raw``; nothing is deserialized); publishers use the recorded offered QoS
  (reliable unless a recorded publisher was best effort; transient-local if all were);
* ``/clock`` (rosgraph_msgs/Clock) is published whenever the log time advances, before the
  messages of that time, so nodes with ``use_sim_time`` follow the recording; if the bag has
  its own ``/clock`` and it is selected, that one is replayed instead;
* ``--topics A B ...``: only these; messages of one log time (a recorder receives the topics of one sim
  instant in either order) are played in the order of the list, e.g. the field before the attitude
  sample, as the sensors node publishes them (a controller answers an attitude sample without its field);
* ``--rate R``: R times the recorded speed (log time vs. wall time); ``--rate 0``: as fast as
  DDS accepts (reliable KEEP_ALL publishers: nothing a subscriber has not acknowledged is
  dropped). Before exiting the player waits for all acks;
* ``--start S`` skips the first S seconds; ``--playback-duration S`` stops S bag seconds after
  the start point; ``--playback-until T`` stops after log time T [s]; ``--loop`` repeats;
* control services, the ``rosbag2_interfaces`` types of ``ros2 bag play`` (``ros2 service call
  /magtune_player/resume rosbag2_interfaces/srv/Resume``): ``pause``, ``resume``,
  ``toggle_paused``, ``is_paused``, ``get_rate``, ``set_rate`` (rate > 0), ``play_next`` (one
  message while paused), ``seek`` (log time inside the bag); ``--start-paused`` waits for them;
* ``--wait-subscribers S`` (default 5): before the first message, wait up to S wall seconds
  until every selected topic has a subscriber (0: do not wait);
* progress on stderr (``[RUNNING] bag time ... progress ...``), by default when it is a terminal;
* ``--foxglove PORT``: also stream every published message to a Foxglove WebSocket server
  (:mod:`magtune_core.bags.live`) at its log time;
* a truncated/corrupt bag (no summary) is scanned: what is readable is replayed and the
  final JSON line on stdout reports what was not (``unreadable``).
"""
from __future__ import annotations

import argparse
import json
import sys
import threading
import time

from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbag2_interfaces import srv as bag_srv

from magtune_core import bags as baglib
from magtune_core.bags.playback import DEFAULT_WAIT_SUBSCRIBERS, SERVICES, ReplayOptions, validate

from .bag_common import message_class, offer_from_recorded
from .main import run

CLOCK = "/clock"


def parse_args(argv):
    """The command line (bag, rate, window, topics, ...) without the ROS arguments; Player.parse_options validates it against the bag."""
    p = argparse.ArgumentParser(prog="player", description=__doc__.split("\n\n")[0])
    p.add_argument("bag", help="bag directory (or .mcap file)")
    p.add_argument("--rate", type=float, default=1.0, help="speed factor > 0; 0 = as fast as acked")
    p.add_argument("--topics", nargs="*", default=None, help="only these topics; messages of one time in this order")
    p.add_argument("--exclude", default=None, metavar="REGEX", help="leave out topics matching REGEX")
    p.add_argument("--start", type=float, default=0.0, help="skip the first S seconds")
    p.add_argument("--playback-duration", type=float, default=0.0, help="play S bag seconds (0: to the end)")
    p.add_argument("--playback-until", type=float, default=None, help="stop after log time T [s]")
    p.add_argument("--start-paused", action="store_true", help="wait for resume/play_next")
    p.add_argument("--loop", action="store_true")
    p.add_argument("--no-clock", action="store_true", help="do not publish /clock")
    p.add_argument("--depth", type=int, default=1000, help="publisher queue depth")
    p.add_argument("--ack-every", type=int, default=0,
                   help="rate 0: also wait for acks every N messages (0: never)")
    p.add_argument("--order", choices=("log", "publish"), default="log",
                   help="timeline: receive (log) time, as rosbag2 play, or publish time")
    p.add_argument("--wait-subscribers", type=float, default=DEFAULT_WAIT_SUBSCRIBERS,
                   help="wait up to S seconds until every topic has a subscriber (0: no wait)")
    p.add_argument("--progress", default="auto", help="progress line on stderr: auto (if a terminal), on, off")
    p.add_argument("--foxglove", type=int, default=None, metavar="PORT",
                   help="also stream to a Foxglove WebSocket server on PORT (0: any free port)")
    return p.parse_args(argv)


def options_of(args) -> ReplayOptions:
    """The ReplayOptions of the parsed command line: what magtune_core.bags.playback.validate checks."""
    return ReplayOptions(rate=args.rate, topics=args.topics, exclude=args.exclude, start=args.start,
                         playback_duration=args.playback_duration, playback_until=args.playback_until,
                         loop=args.loop, no_clock=args.no_clock, start_paused=args.start_paused,
                         wait_subscribers=args.wait_subscribers, progress=args.progress, foxglove=args.foxglove)


class PlayState:
    """Pause / rate / seek / play-next requests shared by the service callbacks and the play loop."""

    def __init__(self, paused: bool, rate: float):
        self.cond = threading.Condition()
        self.paused = paused
        self.rate = rate
        self.seek_ns: int | None = None
        self.next_requests = 0
        self.exhausted = False    # the window is played out (play_next then fails)
        self.version = 0          # bumped on every change: the play loop re-anchors its timing

    def change(self, **kw):
        """Set attributes under the lock, bump ``version`` and wake the play loop (which re-anchors its timing)."""
        with self.cond:
            for k, v in kw.items():
                setattr(self, k, v)
            self.version += 1
            self.cond.notify_all()


class Player(Node):
    """Publishers for the selected topics of one bag, plus ``/clock`` and the control services."""

    NODE_NAME = "player"
    EXECUTOR = SingleThreadedExecutor

    @staticmethod
    def parse_options(argv):
        """The command line and the playback window it selects (ConfigError: exit status 2)."""
        args = parse_args(argv)
        return args, validate(args.bag, options_of(args))

    def __init__(self, options):
        args, sel = options
        super().__init__("magtune_player",
                         parameter_overrides=[Parameter("use_sim_time", value=False)])
        self.args, self.sel, self.stop = args, sel, threading.Event()
        self.show_progress = args.progress == "on" or (args.progress == "auto" and sys.stderr.isatty())
        self.state = PlayState(args.start_paused, args.rate)
        topics = baglib.topics_of(args.bag)
        self.topics = {n: topics[n] for n in sel.topics}
        self.pubs = {}
        for name, info in self.topics.items():
            qos = offer_from_recorded(info.offered_qos_profiles, args.depth)
            if args.rate == 0:
                qos.history = HistoryPolicy.KEEP_ALL
            self.pubs[name] = self.create_publisher(message_class(info.type), name, qos)
        self.clock_pub = None
        if not args.no_clock and CLOCK not in self.pubs:
            from rosgraph_msgs.msg import Clock as ClockMsg
            self._clock_msg = ClockMsg()
            self.clock_pub = self.create_publisher(
                ClockMsg, CLOCK, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.live = None
        if args.foxglove is not None:
            from magtune_core.bags.live import LiveServer
            self.live = LiveServer(args.foxglove, name="magtune replay")
            for name, info in self.topics.items():
                self.live.add_topic(name, info.type)
            if self.clock_pub is not None:
                self.live.add_topic(CLOCK, "rosgraph_msgs/msg/Clock")
            print(f"magtune-player foxglove ws://127.0.0.1:{self.live.port}", flush=True)
        for name, typ in SERVICES.items():
            self.create_service(getattr(bag_srv, typ), f"~/{name}", getattr(self, f"_srv_{name}"))
        self.bag_time = sel.start_ns   # log time of the last message published

    # ---------------------------------------------------------------- services
    def _srv_pause(self, req, res):
        self.state.change(paused=True)
        return res

    def _srv_resume(self, req, res):
        self.state.change(paused=False)
        return res

    def _srv_toggle_paused(self, req, res):
        self.state.change(paused=not self.state.paused)
        return res

    def _srv_is_paused(self, req, res):
        res.paused = bool(self.state.paused)
        return res

    def _srv_get_rate(self, req, res):
        res.rate = float(self.state.rate)
        return res

    def _srv_set_rate(self, req, res):
        ok = req.rate > 0 and req.rate < float("inf")
        if ok:
            self.state.change(rate=float(req.rate))
        res.success = bool(ok)
        return res

    def _srv_play_next(self, req, res):
        st = self.state
        with st.cond:
            if not st.paused:
                res.success = False
                return res
            st.next_requests += 1
            st.version += 1
            st.cond.notify_all()
            # answer once the loop has published it (or gave up: end of the window); the loop may
            # still be waiting for subscribers (--wait-subscribers) before its first message
            end = time.monotonic() + 5.0 + self.args.wait_subscribers
            while st.next_requests > 0 and time.monotonic() < end and not self.stop.is_set():
                st.cond.wait(0.05)
            res.success = st.next_requests == 0 and not st.exhausted
            st.next_requests = 0
        return res

    def _srv_seek(self, req, res):
        t = int(req.time.sec) * 1_000_000_000 + int(req.time.nanosec)
        ok = self.sel.bag_start_ns <= t <= self.sel.bag_end_ns
        if ok:
            self.state.change(seek_ns=t)
        res.success = bool(ok)
        return res

    # ---------------------------------------------------------------- playing
    def wait_subscribers(self, timeout: float) -> bool:
        """Wait up to ``timeout`` wall s until every topic has a subscriber; True if all do, False on timeout or stop."""
        end = time.monotonic() + timeout
        while time.monotonic() < end and not self.stop.is_set():
            if all(p.get_subscription_count() > 0 for p in self.pubs.values()):
                return True
            time.sleep(0.02)
        return False

    def publish_clock(self, t_ns: int):
        """Publish /clock at log time ``t_ns`` (and stream it to Foxglove): nodes with use_sim_time follow the recording."""
        m = self._clock_msg
        m.clock.sec, m.clock.nanosec = divmod(int(t_ns), 1_000_000_000)
        self.clock_pub.publish(m)
        if self.live is not None:
            from rclpy.serialization import serialize_message
            self.live.log(CLOCK, serialize_message(m), t_ns)

    def spin(self, executor, stop: threading.Event) -> int:
        """Serve the control services on a thread while the main thread plays the window
        (``--loop``: again until stopped); print the JSON report of what was published."""
        self.stop = stop
        spinner = threading.Thread(target=lambda: _spin(executor, stop), name="services", daemon=True)
        spinner.start()
        args, counts, report, loops = self.args, {}, {}, 0
        t_start = time.monotonic()
        try:
            if args.start_paused:
                print("magtune-player paused", flush=True)
            if args.wait_subscribers > 0 and not self.wait_subscribers(args.wait_subscribers):
                self.get_logger().warning(f"not every topic has a subscriber after {args.wait_subscribers:g} s; "
                                          "playing anyway")
            print("magtune-player playing", flush=True)
            while not stop.is_set():
                self.play_once(counts, report)
                loops += 1
                if not args.loop:
                    break
            self.progress(final=True)
            self.wait_acked()
        finally:
            stop.set()
            with self.state.cond:
                self.state.cond.notify_all()
            self._report(counts, report, loops, time.monotonic() - t_start)
            spinner.join(2.0)
        return 0

    def _report(self, counts: dict, report: dict, loops: int, elapsed: float) -> None:
        out = {"bag": str(self.args.bag), "published": dict(sorted(counts.items())), "loops": loops,
               "wall_s": round(elapsed, 3), "complete": bool(report.get("complete", True))}
        if not out["complete"]:
            out["unreadable"] = {k: report.get(k) for k in (
                "chunks_bad", "unreadable_tail_bytes", "problem", "messages_recovered",
                "messages_expected", "messages_in_damaged_chunks")}
            self.get_logger().warning(f"bag is damaged; replayed what was readable: {out['unreadable']}")
        print(json.dumps(out), flush=True)

    def finish(self) -> None:
        """Close the Foxglove server, if any (called by ``main.run`` at shutdown)."""
        if self.live is not None:
            self.live.close()
            self.live = None

    def wait_acked(self, timeout_s: float = 10.0):
        """Wait (up to ``timeout_s`` per publisher) until every subscriber acknowledged what was published: nothing lost on exit."""
        for p in self.pubs.values():
            if p.get_subscription_count() > 0:
                p.wait_for_all_acked(Duration(seconds=timeout_s))
        if self.clock_pub is not None and self.clock_pub.get_subscription_count() > 0:
            self.clock_pub.wait_for_all_acked(Duration(seconds=timeout_s))

    def play_once(self, counts: dict, report: dict) -> None:
        """One pass over the playback window (restarted from the target on a seek)."""
        a, st, sel = self.args, self.state, self.sel
        start_ns = sel.start_ns
        last_clock = None
        while True:
            with st.cond:
                st.seek_ns = None
                version = st.version
            anchor_wall, anchor_bag = time.monotonic(), None
            since_ack = 0
            seeked = False
            msgs = baglib.iter_messages(a.bag, topics=list(self.pubs), start_ns=start_ns, report=report, order=a.order)
            for m in baglib.ties_in_topic_order(msgs, a.topics or (), a.order):
                t = m.log_time if a.order == "log" else m.publish_time
                if t > sel.end_ns:
                    break
                if anchor_bag is None:  # timing starts at the first message (reading and the
                    anchor_bag, anchor_wall = t, time.monotonic()  # integrity check come before it)
                stepped = False
                with st.cond:
                    while True:
                        if self.stop.is_set():
                            return
                        if st.seek_ns is not None:
                            seeked = True
                            break
                        if st.version != version:    # pause/resume/rate change: re-anchor the timing
                            version = st.version
                            anchor_wall, anchor_bag = time.monotonic(), t
                        if st.paused:
                            if st.next_requests > 0:
                                stepped = True
                                break
                            st.cond.wait(0.1)
                            continue
                        rate = st.rate
                        if rate <= 0:
                            break
                        delay = anchor_wall + (t - anchor_bag) / 1e9 / rate - time.monotonic()
                        if delay <= 0:
                            break
                        st.cond.wait(min(delay, 0.1))
                if seeked:
                    break
                if self.clock_pub is not None and (last_clock is None or t > last_clock):
                    self.publish_clock(t)
                    last_clock = t
                    counts[CLOCK] = counts.get(CLOCK, 0) + 1
                self.pubs[m.topic].publish(m.data)
                if self.live is not None:
                    self.live.log(m.topic, m.data, t)
                counts[m.topic] = counts.get(m.topic, 0) + 1
                self.bag_time = t
                self.progress()
                if stepped:
                    with st.cond:
                        st.next_requests = max(0, st.next_requests - 1)
                        version = st.version = st.version + 1
                        st.cond.notify_all()
                    anchor_wall, anchor_bag = time.monotonic(), t
                since_ack += 1
                if a.rate == 0 and a.ack_every and since_ack >= a.ack_every:
                    self.wait_acked()
                    since_ack = 0
            if seeked:
                start_ns, last_clock = st.seek_ns, None
                continue
            # end of the window: a paused player stays paused until resumed (to allow a seek back)
            with st.cond:
                st.exhausted = True
                st.next_requests = 0
                st.cond.notify_all()
                while st.paused and st.seek_ns is None and not self.stop.is_set():
                    st.cond.wait(0.1)
                seek = st.seek_ns
                st.exhausted = False
            if seek is None:
                return
            start_ns, last_clock = seek, None

    _last_progress = 0.0

    def progress(self, final: bool = False):
        """The progress line on stderr, if shown: at most every 0.2 s, or now with a newline when ``final``."""
        if not self.show_progress:
            return
        now = time.monotonic()
        if not final and now - self._last_progress < 0.2:
            return
        self._last_progress = now
        sel = self.sel
        span = max(1, sel.end_ns - sel.start_ns)
        frac = min(1.0, max(0.0, (self.bag_time - sel.start_ns) / span))
        status = "PAUSED " if self.state.paused else "RUNNING"
        sys.stderr.write(f"\r[{status}] bag time {self.bag_time * 1e-9:14.3f} s  duration "
                         f"{(self.bag_time - sel.bag_start_ns) * 1e-9:10.3f} s  progress {100 * frac:5.1f} %"
                         + ("\n" if final else ""))
        sys.stderr.flush()


def main(argv=None):
    """Entry point of the player node (console script): run(Player)'s exit status."""
    return run(Player, argv)


def _spin(executor, stop: threading.Event):
    while not stop.is_set():
        try:
            executor.spin_once(timeout_sec=0.1)
        except Exception:  # noqa: BLE001 - shutdown races end the service thread
            if stop.is_set():
                return
            raise


if __name__ == "__main__":
    raise SystemExit(main())
