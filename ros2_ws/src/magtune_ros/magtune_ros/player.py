"""``player`` node: republish a bag's messages at their recorded (sim) times, with ``/clock``.

Usage (``ros2 run magtune_ros player`` or ``install/magtune_ros/lib/magtune_ros/player``)::

    player bags/NAME [--rate R] [--topics /a /b] [--start S] [--loop] [--no-clock]
                     [--depth N] [--wait-subscribers S] [--ack-every N]

* every message is published as its recorded CDR bytes (``Publisher.publish(bytes)`` ->
  ``publish_raw``; nothing is deserialized); publishers use the recorded offered QoS
  (reliable unless a recorded publisher was best effort; transient-local if all were);
* ``/clock`` (rosgraph_msgs/Clock) is published whenever the log time advances, before the
  messages of that time, so nodes with ``use_sim_time`` follow the recording; if the bag has
  its own ``/clock`` and it is selected, that one is replayed instead;
* ``--rate R``: R times the recorded speed (log time vs. wall time); ``--rate 0``: as fast as
  DDS accepts. Publishers are then reliable KEEP_ALL, so the player never drops a sample
  that a subscriber has not acknowledged; a subscriber loses nothing if its own history is
  deep enough for the burst (KEEP_ALL, or KEEP_LAST depth >= messages per topic), otherwise
  use a finite rate. (``--ack-every N`` additionally blocks on ``wait_for_all_acked`` every N
  messages; with Fast DDS an ack waits for the writer's next heartbeat, about 3 s, so this is
  a coarse throttle, off by default.) Before exiting the player waits for all acks;
* ``--start S`` skips the first S seconds of the bag; ``--loop`` repeats until SIGINT;
* ``--order publish`` replays on the publish-time timeline instead of the receive (log) time
  (they differ only for samples a recorder received late, e.g. transient-local history);
* a truncated/corrupt bag (no summary) is scanned: what is readable is replayed and the
  final JSON line on stdout reports what was not (``unreadable``).
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from magtune_core import bags as baglib

from .bag_common import install_stop_handlers, message_class, offer_from_recorded

CLOCK = "/clock"


def parse_args(argv):
    p = argparse.ArgumentParser(prog="player", description=__doc__.split("\n\n")[0])
    p.add_argument("bag", help="bag directory (or .mcap file)")
    p.add_argument("--rate", type=float, default=1.0, help="speed factor; 0 = as fast as acked")
    p.add_argument("--topics", nargs="*", default=None, help="only these topics")
    p.add_argument("--start", type=float, default=0.0, help="skip the first S seconds")
    p.add_argument("--loop", action="store_true")
    p.add_argument("--no-clock", action="store_true", help="do not publish /clock")
    p.add_argument("--depth", type=int, default=1000, help="publisher queue depth")
    p.add_argument("--ack-every", type=int, default=0,
                   help="rate 0: also wait for acks every N messages (0: never)")
    p.add_argument("--order", choices=("log", "publish"), default="log",
                   help="timeline: receive (log) time, as rosbag2 play, or publish time")
    p.add_argument("--wait-subscribers", type=float, default=0.0,
                   help="wait up to S seconds until every topic has a subscriber")
    return p.parse_args(argv)


class Player(Node):
    """Publishers for the selected topics of one bag, plus ``/clock``."""

    def __init__(self, args):
        super().__init__("magtune_player",
                         parameter_overrides=[Parameter("use_sim_time", value=False)])
        self.args = args
        topics = baglib.topics_of(args.bag)
        if args.topics:
            missing = [t for t in args.topics if t not in topics]
            if missing:
                self.get_logger().warning(f"topics not in bag: {missing}")
            topics = {n: t for n, t in topics.items() if n in args.topics}
        self.topics = topics
        self.pubs = {}
        for name, info in topics.items():
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

    def wait_subscribers(self, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if all(p.get_subscription_count() > 0 for p in self.pubs.values()):
                return True
            time.sleep(0.02)
        return False

    def publish_clock(self, t_ns: int):
        m = self._clock_msg
        m.clock.sec, m.clock.nanosec = divmod(int(t_ns), 1_000_000_000)
        self.clock_pub.publish(m)

    def wait_acked(self, timeout_s: float = 10.0):
        for p in self.pubs.values():
            if p.get_subscription_count() > 0:
                p.wait_for_all_acked(Duration(seconds=timeout_s))
        if self.clock_pub is not None and self.clock_pub.get_subscription_count() > 0:
            self.clock_pub.wait_for_all_acked(Duration(seconds=timeout_s))

    def play_once(self, stop, counts: dict, report: dict) -> None:
        """One pass over the bag."""
        a = self.args
        start_ns = None
        meta_start = _bag_start(a.bag)
        if a.start > 0:
            start_ns = meta_start + int(a.start * 1e9)
        wall0 = time.monotonic()
        t0 = None
        last_clock = None
        since_ack = 0
        for m in baglib.iter_messages(a.bag, topics=list(self.pubs), start_ns=start_ns,
                                      report=report, order=a.order):
            if stop.is_set():
                return
            t = m.log_time if a.order == "log" else m.publish_time
            if t0 is None:
                t0 = t
            if a.rate > 0:
                delay = wall0 + (t - t0) / 1e9 / a.rate - time.monotonic()
                if delay > 0:
                    if stop.wait(delay):
                        return
            if self.clock_pub is not None and (last_clock is None or t > last_clock):
                self.publish_clock(t)
                last_clock = t
                counts[CLOCK] = counts.get(CLOCK, 0) + 1
            self.pubs[m.topic].publish(m.data)
            counts[m.topic] = counts.get(m.topic, 0) + 1
            since_ack += 1
            if a.rate == 0 and a.ack_every and since_ack >= a.ack_every:
                self.wait_acked()
                since_ack = 0


def _bag_start(bag) -> int:
    try:
        return int(baglib.info(bag)["start_ns"])
    except Exception:  # noqa: BLE001 - an unreadable bag has no start; iteration reports it
        return 0


def main(argv=None):
    argv = sys.argv if argv is None else argv
    args = parse_args(remove_ros_args(argv)[1:])
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    stop = install_stop_handlers()
    node = Player(args)
    counts: dict = {}
    report: dict = {}
    loops = 0
    t_start = time.monotonic()
    try:
        if args.wait_subscribers > 0 and not node.wait_subscribers(args.wait_subscribers):
            node.get_logger().warning("not every topic has a subscriber; playing anyway")
        while True:
            node.play_once(stop, counts, report)
            loops += 1
            if not args.loop or stop.is_set():
                break
        node.wait_acked()
    finally:
        elapsed = time.monotonic() - t_start
        out = {"bag": str(args.bag), "published": dict(sorted(counts.items())), "loops": loops,
               "wall_s": round(elapsed, 3), "complete": bool(report.get("complete", True))}
        if not out["complete"]:
            out["unreadable"] = {k: report.get(k) for k in (
                "chunks_bad", "unreadable_tail_bytes", "problem", "messages_recovered",
                "messages_expected", "messages_in_damaged_chunks")}
            node.get_logger().warning(f"bag is damaged; replayed what was readable: {out['unreadable']}")
        print(json.dumps(out), flush=True)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
