"""Test publisher process: N steps of deterministic messages of several standard types over DDS.

Run as ``python tests/support/bag_fixture_pub.py N [--rate HZ] [--depth D] [--prefix /t]``. Step i
(sim time ``t_i = i * DT``) publishes, in this order: ``/clock`` = t_i, ``/imu``
(sensor_msgs/Imu), ``/magnetic_field`` (sensor_msgs/MagneticField), ``/dipole_command``
(geometry_msgs/Vector3Stamped), ``/truth`` (nav_msgs/Odometry); every 10th step a
``/diagnostics`` (diagnostic_msgs/DiagnosticArray). Values are functions of i only (see
:func:`expected`), so a test can check decoded values exactly. The process waits until every
publisher has a matched subscription, publishes with reliable QoS, waits for all acks, exits.
"""
from __future__ import annotations

import argparse
import sys
import time

DT_NS = 100_000_000  # 0.1 s of sim time per step
TOPICS = {
    "/clock": "rosgraph_msgs/msg/Clock",
    "/imu": "sensor_msgs/msg/Imu",
    "/magnetic_field": "sensor_msgs/msg/MagneticField",
    "/dipole_command": "geometry_msgs/msg/Vector3Stamped",
    "/truth": "nav_msgs/msg/Odometry",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}


def expected(i: int) -> dict:
    """The values step i carries (exactly representable in float64)."""
    return {"t_ns": (i + 1) * DT_NS, "w": (i * 0.001, -i * 0.002, 0.5),
            "b": (1e-6 * i, 2e-6, -3e-6), "m": (0.25 * i, -0.5, 1.0),
            "q": (1.0, 0.0, 0.0, 0.0), "diag": f"step {i}"}


def counts(n: int) -> dict:
    """Messages per topic for n steps."""
    c = {t: n for t in TOPICS}
    c["/diagnostics"] = (n + 9) // 10
    return c


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("n", type=int)
    ap.add_argument("--rate", type=float, default=0.0, help="steps per wall second (0: max)")
    ap.add_argument("--depth", type=int, default=1000)
    ap.add_argument("--prefix", default="")
    ap.add_argument("--blob", type=int, default=0,
                    help="also publish /blob (std_msgs/UInt8MultiArray) of this many bytes per step")
    a = ap.parse_args(argv)

    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from geometry_msgs.msg import Vector3Stamped
    from nav_msgs.msg import Odometry
    from rclpy.duration import Duration
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu, MagneticField

    rclpy.init()
    node = rclpy.create_node("bag_fixture_pub")
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=a.depth,
                     reliability=ReliabilityPolicy.RELIABLE)
    cls = {"/clock": Clock, "/imu": Imu, "/magnetic_field": MagneticField,
           "/dipole_command": Vector3Stamped, "/truth": Odometry, "/diagnostics": DiagnosticArray}
    if a.blob:
        from std_msgs.msg import UInt8MultiArray
        cls["/blob"] = UInt8MultiArray
        blob = UInt8MultiArray()
    pubs = {t: node.create_publisher(c, a.prefix + t, qos) for t, c in cls.items()}
    deadline = time.monotonic() + 20
    while any(p.get_subscription_count() == 0 for p in pubs.values()):
        if time.monotonic() > deadline:
            print("no subscriber matched", file=sys.stderr)
            return 2
        time.sleep(0.02)
    time.sleep(0.2)  # let the matching settle on both sides
    print("publishing", flush=True)
    t_wall = time.monotonic()
    for i in range(a.n):
        e = expected(i)
        sec, nsec = divmod(e["t_ns"], 1_000_000_000)
        c = Clock(); c.clock.sec, c.clock.nanosec = sec, nsec
        pubs["/clock"].publish(c)
        imu = Imu(); imu.header.stamp = c.clock; imu.header.frame_id = "body"
        imu.orientation.w, imu.orientation.x, imu.orientation.y, imu.orientation.z = e["q"]
        imu.angular_velocity.x, imu.angular_velocity.y, imu.angular_velocity.z = e["w"]
        pubs["/imu"].publish(imu)
        mf = MagneticField(); mf.header.stamp = c.clock; mf.header.frame_id = "body"
        mf.magnetic_field.x, mf.magnetic_field.y, mf.magnetic_field.z = e["b"]
        pubs["/magnetic_field"].publish(mf)
        v = Vector3Stamped(); v.header.stamp = c.clock; v.header.frame_id = "body"
        v.vector.x, v.vector.y, v.vector.z = e["m"]
        pubs["/dipole_command"].publish(v)
        od = Odometry(); od.header.stamp = c.clock; od.header.frame_id = "orbital"
        od.child_frame_id = "body"
        q = od.pose.pose.orientation
        q.w, q.x, q.y, q.z = e["q"]
        od.twist.twist.angular.x, od.twist.twist.angular.y, od.twist.twist.angular.z = e["w"]
        pubs["/truth"].publish(od)
        if i % 10 == 0:
            d = DiagnosticArray(); d.header.stamp = c.clock
            d.status.append(DiagnosticStatus(name="fixture", message=e["diag"]))
            pubs["/diagnostics"].publish(d)
        if a.blob:
            blob.data = bytes([i % 256]) * a.blob
            pubs["/blob"].publish(blob)
        if a.rate > 0:
            time.sleep(max(0.0, t_wall + (i + 1) / a.rate - time.monotonic()))
    for p in pubs.values():
        p.wait_for_all_acked(Duration(seconds=30))
    print(f"published {a.n} steps in {time.monotonic() - t_wall:.3f} s", flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
