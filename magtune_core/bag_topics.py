"""The project's topics as recorded in bags (names as in ros2_ws/src/magtune_ros/common.py).

Used by the recorder (default topic set, typed so it can subscribe before the publishers
exist, with the durability they offer) and by ``magtune report`` (which topic is what).
No rclpy here.
"""
from __future__ import annotations

#: name -> (type, durability offered by the publisher: lockstep topics are transient-local)
PROJECT_TOPICS: dict[str, tuple[str, str]] = {
    "/clock": ("rosgraph_msgs/msg/Clock", "volatile"),
    "/sim/truth": ("nav_msgs/msg/Odometry", "transient_local"),
    "/sim/magnetic_field": ("sensor_msgs/msg/MagneticField", "transient_local"),
    "/sim/magnetic_torque": ("geometry_msgs/msg/WrenchStamped", "transient_local"),
    "/sim/disturbance_torque": ("geometry_msgs/msg/WrenchStamped", "transient_local"),
    "/sensors/magnetic_field": ("sensor_msgs/msg/MagneticField", "transient_local"),
    "/sensors/attitude": ("sensor_msgs/msg/Imu", "transient_local"),
    "/controller/dipole_command": ("geometry_msgs/msg/Vector3Stamped", "transient_local"),
    "/diagnostics": ("diagnostic_msgs/msg/DiagnosticArray", "volatile"),
}

TRUTH = "/sim/truth"                    # attitude (body w.r.t. orbital) and body rate, true
TRUE_FIELD = "/sim/magnetic_field"      # b in body axes [T], true
MAG = "/sensors/magnetic_field"         # b measured
ATTITUDE = "/sensors/attitude"          # attitude + rate measured (controller input)
DIPOLE = "/controller/dipole_command"   # m [A m^2]
CONTROLLER_INPUTS = (MAG, ATTITUDE)


def topic_specs() -> list[str]:
    """``/name:pkg/msg/Type`` list for the recorder's ``--topics``."""
    return [f"{n}:{t}" for n, (t, _) in PROJECT_TOPICS.items()]
