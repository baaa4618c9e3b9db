"""Readers of serialized (raw) messages: the few fields a hot callback needs, without building the message.

The attitude estimator and the mode manager subscribe with ``raw=True`` (bench/README.md: the
manager's CPU per step 0.62-0.94 -> 0.42 ms); every reader returns None, never raises, for bytes that
are not such a message, and equals rclpy's own deserialization (tests/ros/test_raw_messages.py).
"""
from __future__ import annotations

import struct

#: CDR encapsulation (XCDR1, the rmw's for ROS 2 types) -> struct byte order.
_CDR_ORDER = {b"\x00\x01": "<", b"\x00\x00": ">"}
_HEADER = {o: struct.Struct(o + "iII") for o in "<>"}  # stamp sec, nanosec, frame_id length (with its NUL)
#: sensor_msgs/Imu after the header: orientation x y z w, the first of 9 covariances (the rest skipped),
#: angular_velocity x y z
_IMU = {o: struct.Struct(o + "4dd64x3d") for o in "<>"}
_IMU_SIZE = 32 + 72 + 24 + 72 + 24 + 72  # orientation .. linear_acceleration_covariance [bytes]
#: sensor_msgs/MagneticField after the header: magnetic_field x y z, 9 covariances
_VEC3 = {o: struct.Struct(o + "3d") for o in "<>"}
_UINT = {o: struct.Struct(o + "I") for o in "<>"}
#: nav_msgs/Odometry after child_frame_id: pose position x y z, orientation and 36 covariances (skipped),
#: twist linear x y z
_ODOM = {o: struct.Struct(o + "3d32x288x3d") for o in "<>"}
_ODOM_SIZE = 24 + 32 + 288 + 24 + 24 + 288  # pose .. twist covariance [bytes]
#: nav_msgs/Odometry after child_frame_id: position skipped, orientation x y z w, 36 covariances and twist linear
#: skipped, twist angular x y z
_ODOM_ATT = {o: struct.Struct(o + "24x4d288x24x3d") for o in "<>"}


def _raw_header(data: bytes, strings: int = 0):
    """(byte order, stamp [ns], offset of the first double after the header and ``strings`` more
    strings) of a serialized std_msgs/Header-led message, or None if the bytes are not one."""
    order = _CDR_ORDER.get(bytes(data[:2]))
    if order is None or len(data) < 16:
        return None
    sec, nsec, n = _HEADER[order].unpack_from(data, 4)
    body = 12 + n  # the frame_id's end, relative to the CDR body at byte 4
    for _ in range(strings):  # e.g. Odometry's child_frame_id: a uint32 length aligned to 4, then the bytes
        body = (body + 3) & ~3
        if len(data) < 4 + body + 4:
            return None
        body += 4 + _UINT[order].unpack_from(data, 4 + body)[0]
    return order, sec * 1_000_000_000 + nsec, 4 + ((body + 7) & ~7)  # doubles align to 8 in the body


def raw_imu(data: bytes):
    """(stamp [ns], (qw, qx, qy, qz), (wx, wy, wz), known) of a serialized sensor_msgs/Imu (a
    ``raw=True`` subscription's bytes), or None if malformed: the two fields without building the
    message, and whether the orientation is known (orientation_covariance[0] != -1, REP-145)."""
    h = _raw_header(data)
    if h is None or len(data) < h[2] + _IMU_SIZE:
        return None
    order, ns, at = h
    x, y, z, w, c0, wx, wy, wz = _IMU[order].unpack_from(data, at)
    return ns, (w, x, y, z), (wx, wy, wz), c0 != -1.0


def raw_magnetic_field(data: bytes):
    """(stamp [ns], (bx, by, bz)) of a serialized sensor_msgs/MagneticField, or None if malformed."""
    h = _raw_header(data)
    if h is None or len(data) < h[2] + 24 + 72:
        return None
    order, ns, at = h
    return ns, _VEC3[order].unpack_from(data, at)


def raw_vector3_stamped(data: bytes):
    """(stamp [ns], (x, y, z)) of a serialized geometry_msgs/Vector3Stamped, or None if malformed."""
    h = _raw_header(data)
    if h is None or len(data) < h[2] + 24:
        return None
    order, ns, at = h
    return ns, _VEC3[order].unpack_from(data, at)


def raw_odometry(data: bytes):
    """(stamp [ns], pose position (x, y, z), twist linear (x, y, z)) of a serialized
    nav_msgs/Odometry, or None if malformed."""
    h = _raw_header(data, strings=1)
    if h is None or len(data) < h[2] + _ODOM_SIZE:
        return None
    order, ns, at = h
    px, py, pz, vx, vy, vz = _ODOM[order].unpack_from(data, at)
    return ns, (px, py, pz), (vx, vy, vz)


def raw_odometry_attitude(data: bytes):
    """(stamp [ns], pose orientation (qw, qx, qy, qz), twist angular (x, y, z)) of a serialized
    nav_msgs/Odometry (sim/truth: attitude and relative rate), or None if malformed."""
    h = _raw_header(data, strings=1)
    if h is None or len(data) < h[2] + _ODOM_SIZE:
        return None
    order, ns, at = h
    x, y, z, w, ax, ay, az = _ODOM_ATT[order].unpack_from(data, at)
    return ns, (w, x, y, z), (ax, ay, az)
