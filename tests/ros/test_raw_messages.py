"""The serialized-message readers of magtune_ros.raw (what the sensors, the estimator and the mode
manager take from their raw subscriptions): the same numbers as rclpy's own deserialization for every frame_id length (the CDR
alignment of the doubles after the header string), both byte orders, and None, never an exception,
for bytes that are not such a message."""
from __future__ import annotations

import struct

import numpy as np
import pytest

pytestmark = pytest.mark.ros


@pytest.fixture(scope="module")
def ros():
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import Imu, MagneticField

    from magtune_ros import raw  # rclpy: the built package

    return raw, serialize_message, deserialize_message, Imu, MagneticField


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _odometry(frame_id, child, rng):
    from nav_msgs.msg import Odometry

    m = Odometry()
    m.header.frame_id, m.child_frame_id = frame_id, child
    m.header.stamp.sec, m.header.stamp.nanosec = int(rng.integers(0, 2**31 - 1)), int(rng.integers(0, 10**9))
    p, v = m.pose.pose.position, m.twist.twist.linear
    p.x, p.y, p.z = (float(x) for x in rng.normal(size=3) * 7e6)
    v.x, v.y, v.z = (float(x) for x in rng.normal(size=3) * 7e3)
    o, a = m.pose.pose.orientation, m.twist.twist.angular
    o.w, o.x, o.y, o.z = (float(x) for x in rng.normal(size=4))
    m.pose.covariance = [float(x) for x in rng.normal(size=36)]
    a.x, a.y, a.z = (float(x) for x in rng.normal(size=3))
    m.twist.covariance = [float(x) for x in rng.normal(size=36)]
    return m


def _imu(Imu, frame_id, rng):
    m = Imu()
    m.header.frame_id = frame_id
    m.header.stamp.sec, m.header.stamp.nanosec = int(rng.integers(0, 2**31 - 1)), int(rng.integers(0, 10**9))
    q = rng.normal(size=4)
    m.orientation.w, m.orientation.x, m.orientation.y, m.orientation.z = (float(x) for x in q / np.linalg.norm(q))
    m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = (float(x) for x in rng.normal(size=3))
    m.orientation_covariance = [float(x) for x in rng.normal(size=9)]
    if rng.uniform() < 0.3:  # REP-145's "orientation not known"
        m.orientation_covariance[0] = -1.0
    m.angular_velocity_covariance = [float(x) for x in rng.normal(size=9)]
    m.linear_acceleration.x = 9.81
    return m


@pytest.mark.parametrize("frame_id", ["", "b", "body", "abcdefg", "abcdefgh", "orbital_frame_13"])
def test_raw_readers_equal_rclpy_deserialization(ros, frame_id):
    c, ser, deser, Imu, MagneticField = ros
    rng = np.random.default_rng(len(frame_id))
    for _ in range(20):
        data = ser(_imu(Imu, frame_id, rng))
        m = deser(data, Imu)
        o, w = m.orientation, m.angular_velocity
        known = m.orientation_covariance[0] != -1.0
        assert c.raw_imu(data) == (_ns(m.header.stamp), (o.w, o.x, o.y, o.z), (w.x, w.y, w.z), known)
        f = MagneticField()
        f.header = m.header
        f.magnetic_field.x, f.magnetic_field.y, f.magnetic_field.z = (float(x) for x in rng.normal(size=3) * 3e-5)
        f.magnetic_field_covariance = [float(x) for x in rng.normal(size=9)]
        data = ser(f)
        b = deser(data, MagneticField).magnetic_field
        assert c.raw_magnetic_field(data) == (_ns(m.header.stamp), (b.x, b.y, b.z))


@pytest.mark.parametrize("frame_id", ["", "eci", "body", "abcdefgh"])
@pytest.mark.parametrize("child", ["", "e", "eci", "abcdefg"])
def test_raw_odometry_and_vector3_stamped_equal_rclpy(ros, frame_id, child):
    from geometry_msgs.msg import Vector3Stamped
    from nav_msgs.msg import Odometry

    c, ser, deser = ros[:3]
    rng = np.random.default_rng(len(frame_id) * 10 + len(child))
    for _ in range(10):
        data = ser(_odometry(frame_id, child, rng))
        m = deser(data, Odometry)
        p, v = m.pose.pose.position, m.twist.twist.linear
        assert c.raw_odometry(data) == (_ns(m.header.stamp), (p.x, p.y, p.z), (v.x, v.y, v.z))
        o, a = m.pose.pose.orientation, m.twist.twist.angular  # sim/truth as the sensors node reads it
        assert c.raw_odometry_attitude(data) == (_ns(m.header.stamp), (o.w, o.x, o.y, o.z), (a.x, a.y, a.z))
        s = Vector3Stamped()
        s.header = m.header
        s.vector.x, s.vector.y, s.vector.z = (float(x) for x in rng.normal(size=3))
        data = ser(s)
        u = deser(data, Vector3Stamped).vector
        assert c.raw_vector3_stamped(data) == (_ns(m.header.stamp), (u.x, u.y, u.z))


def test_raw_reader_big_endian(ros):
    """A big-endian CDR MagneticField (encapsulation 0x0000), written by hand: read as such."""
    c = ros[0]
    frame = b"body\x00"
    body = struct.pack(">iII", 12, 345, len(frame)) + frame
    body += b"\x00" * (-len(body) % 8) + struct.pack(">3d", 1e-5, -2e-5, 3e-5) + struct.pack(">9d", *range(9))
    assert c.raw_magnetic_field(b"\x00\x00\x00\x00" + body) == (12_000_000_345, (1e-5, -2e-5, 3e-5))


def test_raw_readers_refuse_what_is_not_the_message(ros):
    c, ser, _, Imu, MagneticField = ros
    imu = ser(_imu(Imu, "body", np.random.default_rng(0)))
    mag = ser(MagneticField())
    for n in range(len(imu)):  # every truncation
        assert c.raw_imu(imu[:n]) is None
    for n in range(len(mag)):
        assert c.raw_magnetic_field(mag[:n]) is None
    from geometry_msgs.msg import Vector3Stamped

    odom, vec = ser(_odometry("eci", "eci", np.random.default_rng(1))), ser(Vector3Stamped())
    for n in range(len(odom)):
        assert c.raw_odometry(odom[:n]) is None and c.raw_odometry_attitude(odom[:n]) is None
    for n in range(len(vec)):
        assert c.raw_vector3_stamped(vec[:n]) is None
    assert c.raw_imu(b"\x00\x07" + imu[2:]) is None  # another encapsulation (XCDR2)
    huge = imu[:12] + struct.pack("<I", 2**31) + imu[16:]  # a frame_id longer than the message
    assert c.raw_imu(huge) is None and c.raw_magnetic_field(huge) is None and c.raw_odometry(huge) is None
    child = odom[:20] + struct.pack("<I", 2**31) + odom[24:]  # a huge child_frame_id
    assert c.raw_odometry(child) is None and c.raw_odometry_attitude(child) is None
