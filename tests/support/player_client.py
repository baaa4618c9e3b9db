"""Test client of the player's control services (rosbag2_interfaces types) over real DDS.

``python tests/support/player_client.py TOPIC N_TOTAL`` subscribes to TOPIC (nav_msgs/Odometry),
prints ``client ready``, then drives the player at ``/magtune_player``: is_paused, 1 s without
data while paused, play_next (exactly one message), set_rate (bad and good), get_rate,
seek outside the bag, resume; it waits for N_TOTAL messages and prints one JSON line with what
happened (the test asserts on it).
"""
from __future__ import annotations

import json
import sys
import time


def main(argv=None):
    topic, total = (argv or sys.argv[1:])[:2]
    total = int(total)
    import rclpy
    from builtin_interfaces.msg import Time
    from nav_msgs.msg import Odometry
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosbag2_interfaces import srv

    rclpy.init()
    node = rclpy.create_node("player_client")
    got = []
    node.create_subscription(Odometry, topic, lambda m: got.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec),
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    print("client ready", flush=True)

    def call(name, typ, **fields):
        cli = node.create_client(typ, f"/magtune_player/{name}")
        if not cli.wait_for_service(timeout_sec=60):
            raise RuntimeError(f"service {name} not available")
        req = typ.Request(**fields)
        fut = cli.call_async(req)
        rclpy.spin_until_future_complete(node, fut, timeout_sec=30)
        return fut.result()

    def spin_for(seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)

    out = {}
    out["paused_at_start"] = call("is_paused", srv.IsPaused).paused
    while node.count_publishers(topic) == 0:
        spin_for(0.1)
    spin_for(1.0)
    out["received_while_paused"] = len(got)
    out["play_next"] = call("play_next", srv.PlayNext).success
    spin_for(0.5)
    out["received_after_play_next"] = len(got)
    out["set_rate_negative"] = call("set_rate", srv.SetRate, rate=-1.0).success
    out["set_rate_20"] = call("set_rate", srv.SetRate, rate=20.0).success
    out["get_rate"] = call("get_rate", srv.GetRate).rate
    out["seek_outside"] = call("seek", srv.Seek, time=Time(sec=10**6)).success
    call("resume", srv.Resume)
    out["paused_after_resume"] = call("is_paused", srv.IsPaused).paused
    t0 = time.monotonic()
    end = t0 + 60
    while len(got) < total and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    out["resume_to_end_s"] = round(time.monotonic() - t0, 3)
    out["stamps"] = got
    print(json.dumps(out), flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
