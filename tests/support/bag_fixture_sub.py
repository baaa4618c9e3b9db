"""Test subscriber process: collect what a player publishes and dump it as JSON.

``python tests/support/bag_fixture_sub.py OUT.json --expect N_TOTAL [--timeout S]`` subscribes (reliable,
depth 10000) to the topics of :mod:`bag_fixture_pub`, with ``use_sim_time``, prints
``subscriber ready`` once created, and writes ``{topic: [[stamp_ns, values...], ...],
"_clock_at_imu": [...]}`` when N_TOTAL data messages arrived (or at the timeout).
``_clock_at_imu`` is the node's sim clock when each /imu arrived (it follows the player's /clock).
"""
from __future__ import annotations

import argparse
import json
import sys
import time


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--expect", type=int, required=True)
    ap.add_argument("--timeout", type=float, default=60)
    a = ap.parse_args(argv)

    import rclpy
    from geometry_msgs.msg import Vector3Stamped
    from nav_msgs.msg import Odometry
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu, MagneticField

    rclpy.init()
    node = rclpy.create_node("bag_fixture_sub",
                             parameter_overrides=[Parameter("use_sim_time", value=True)])
    qos = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE)
    got: dict = {"/imu": [], "/magnetic_field": [], "/dipole_command": [], "/truth": [],
                 "_clock_at_imu": []}

    def ns(h):
        return h.stamp.sec * 1_000_000_000 + h.stamp.nanosec

    def on_imu(m):
        w = m.angular_velocity
        got["/imu"].append([ns(m.header), w.x, w.y, w.z])
        got["_clock_at_imu"].append(node.get_clock().now().nanoseconds)

    def on_mf(m):
        b = m.magnetic_field
        got["/magnetic_field"].append([ns(m.header), b.x, b.y, b.z])

    def on_dip(m):
        got["/dipole_command"].append([ns(m.header), m.vector.x, m.vector.y, m.vector.z])

    def on_truth(m):
        q = m.pose.pose.orientation
        got["/truth"].append([ns(m.header), q.w, q.x, q.y, q.z])

    node.create_subscription(Imu, "/imu", on_imu, qos)
    node.create_subscription(MagneticField, "/magnetic_field", on_mf, qos)
    node.create_subscription(Vector3Stamped, "/dipole_command", on_dip, qos)
    node.create_subscription(Odometry, "/truth", on_truth, qos)
    print("subscriber ready", flush=True)
    end = time.monotonic() + a.timeout
    total = 0
    while time.monotonic() < end and total < a.expect:
        rclpy.spin_once(node, timeout_sec=0.1)
        total = sum(len(v) for k, v in got.items() if k.startswith("/"))
    with open(a.out, "w") as f:
        json.dump(got, f)
    node.destroy_node()
    rclpy.shutdown()
    return 0 if total >= a.expect else 1


if __name__ == "__main__":
    sys.exit(main())
