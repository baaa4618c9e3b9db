"""The project's ROS 2 interface: topic names, message types, durability, frames (no rclpy).

One table for the nodes (``magtune_ros`` publishes and subscribes the relative names, so
namespaces and remapping work), the recorder (default topic set, typed so it can subscribe
before the publishers exist, with the durability they offer) and the bag report.
"""
from __future__ import annotations

# Topic names as the nodes use them: relative, hence remappable and namespaceable.
TOPIC_TRUTH = "sim/truth"                     # nav_msgs/Odometry: attitude and rate, body w.r.t. orbital
TOPIC_INERTIAL_RATE = "sim/inertial_rate"     # geometry_msgs/Vector3Stamped: inertial body rate, body axes
TOPIC_TRUE_FIELD = "sim/magnetic_field"       # sensor_msgs/MagneticField: true b [T], body axes
TOPIC_MAG_TORQUE = "sim/magnetic_torque"      # geometry_msgs/WrenchStamped
TOPIC_DIST_TORQUE = "sim/disturbance_torque"  # geometry_msgs/WrenchStamped
TOPIC_ORBIT = "sim/orbit"                     # nav_msgs/Odometry: true r [m], v [m/s] in ECI (full environment)
TOPIC_TRUE_SUN = "sim/sun"                    # geometry_msgs/Vector3Stamped: geocentric Sun position [m], ECI (full env.)
TOPIC_TORQUER_FIELD = "sim/torquer_field"     # sensor_msgs/MagneticField: the torquers' field at the magnetometer [T]
TOPIC_MAG = "sensors/magnetic_field"          # sensor_msgs/MagneticField: measured b
TOPIC_ATTITUDE = "sensors/attitude"           # sensor_msgs/Imu: measured attitude + rate (controller input)
TOPIC_IMU = "sensors/imu"                     # sensor_msgs/Imu: gyro rate only (orientation_covariance[0] = -1)
TOPIC_SUN = "sensors/sun"                     # geometry_msgs/Vector3Stamped: measured unit Sun vector, body (when valid)
TOPIC_POSITION = "sensors/position"           # nav_msgs/Odometry: position fix r, v in ECI with covariance
TOPIC_ESTIMATE = "estimate/attitude"          # sensor_msgs/Imu: attitude_estimator's attitude + rate with covariance
TOPIC_DIPOLE = "controller/dipole_command"    # geometry_msgs/Vector3Stamped: m [A m^2]
TOPIC_MODE = "mode"                           # magtune_interfaces/Mode: flight mode and last transition's reason
SERVICE_SET_MODE = "set_mode"                 # magtune_interfaces/SetMode: commanded mode change (mode_manager)
TOPIC_CLOCK = "/clock"                        # rosgraph_msgs/Clock (absolute, as ROS requires)
TOPIC_DIAGNOSTICS = "/diagnostics"            # diagnostic_msgs/DiagnosticArray (absolute, by convention)
TOPIC_TF = "tf"                               # tf2_msgs/TFMessage: orbital -> body (+ eci -> orbital, full env.); /tf un-namespaced
TOPIC_MARKERS = "sim/markers"                 # visualization_msgs/MarkerArray: body box, field and dipole arrows

#: Frames (REP-103, right-handed): orbital = LVLH with X nadir (yaw), Y along-track (roll),
#: Z = X x Y = -orbit normal, opposite r x v (pitch), as in the paper's section 3; body =
#: spacecraft principal axes. ``sim/truth`` (nav_msgs/Odometry, frame orbital, child body)
#: follows REP-105: pose = body w.r.t. orbital, twist.angular = rate of the body w.r.t. the
#: orbital frame in body axes; the inertial rate (what a gyro measures, and the paper's w) is
#: on ``sim/inertial_rate``.
FRAME_ORBITAL = "orbital"
FRAME_BODY = "body"
#: Earth-centred inertial frame of the full environment (``magtune_core.env.orbit``: the
#: orbit's ECI axes, position in metres); parent of ``orbital`` on /tf.
FRAME_ECI = "eci"

# Names as recorded in bags of an un-namespaced run (absolute).
TRUTH = "/" + TOPIC_TRUTH
INERTIAL_RATE = "/" + TOPIC_INERTIAL_RATE
TRUE_FIELD = "/" + TOPIC_TRUE_FIELD
MAG = "/" + TOPIC_MAG
ATTITUDE = "/" + TOPIC_ATTITUDE
ORBIT = "/" + TOPIC_ORBIT
TRUE_SUN = "/" + TOPIC_TRUE_SUN
TORQUER_FIELD = "/" + TOPIC_TORQUER_FIELD
IMU = "/" + TOPIC_IMU
SUN = "/" + TOPIC_SUN
POSITION = "/" + TOPIC_POSITION
DIPOLE = "/" + TOPIC_DIPOLE
ESTIMATE = "/" + TOPIC_ESTIMATE
MODE = "/" + TOPIC_MODE
TF = "/" + TOPIC_TF
MARKERS = "/" + TOPIC_MARKERS
CONTROLLER_INPUTS = (MAG, ATTITUDE)

#: name -> (type, durability offered by the publisher: lockstep topics are transient-local)
PROJECT_TOPICS: dict[str, tuple[str, str]] = {
    TOPIC_CLOCK: ("rosgraph_msgs/msg/Clock", "volatile"),
    TRUTH: ("nav_msgs/msg/Odometry", "transient_local"),
    INERTIAL_RATE: ("geometry_msgs/msg/Vector3Stamped", "transient_local"),
    TRUE_FIELD: ("sensor_msgs/msg/MagneticField", "transient_local"),
    "/" + TOPIC_MAG_TORQUE: ("geometry_msgs/msg/WrenchStamped", "transient_local"),
    "/" + TOPIC_DIST_TORQUE: ("geometry_msgs/msg/WrenchStamped", "transient_local"),
    MAG: ("sensor_msgs/msg/MagneticField", "transient_local"),
    ATTITUDE: ("sensor_msgs/msg/Imu", "transient_local"),
    ORBIT: ("nav_msgs/msg/Odometry", "transient_local"),
    TRUE_SUN: ("geometry_msgs/msg/Vector3Stamped", "transient_local"),
    TORQUER_FIELD: ("sensor_msgs/msg/MagneticField", "transient_local"),
    IMU: ("sensor_msgs/msg/Imu", "transient_local"),
    SUN: ("geometry_msgs/msg/Vector3Stamped", "transient_local"),
    POSITION: ("nav_msgs/msg/Odometry", "transient_local"),
    DIPOLE: ("geometry_msgs/msg/Vector3Stamped", "transient_local"),
    ESTIMATE: ("sensor_msgs/msg/Imu", "transient_local"),
    MODE: ("magtune_interfaces/msg/Mode", "transient_local"),
    TOPIC_DIAGNOSTICS: ("diagnostic_msgs/msg/DiagnosticArray", "volatile"),
    TF: ("tf2_msgs/msg/TFMessage", "transient_local"),
    MARKERS: ("visualization_msgs/msg/MarkerArray", "transient_local"),
}


def topic_specs(namespaces=("",)) -> list[str]:
    """``/name:pkg/msg/Type`` list for the recorder's ``--topics``: the project's topics of each
    namespace (``/sat1/sim/truth``, ...). With namespaces other than the root, each satellite's
    clock is ``<ns>/clock`` (the SIL remaps ``/clock`` per satellite) and ``/diagnostics`` stays
    global."""
    out: list[str] = []
    for ns in namespaces:
        ns = ("/" + ns.strip("/")) if ns.strip("/") else ""
        for n, (t, _) in PROJECT_TOPICS.items():
            if n == TOPIC_DIAGNOSTICS:
                continue
            out.append(f"{ns}{n}:{t}")
    return out + [f"{TOPIC_DIAGNOSTICS}:{PROJECT_TOPICS[TOPIC_DIAGNOSTICS][0]}"]


def project_topic(name: str) -> tuple[str, str] | None:
    """(type, durability) of a project topic under any namespace (``/sat1/sim/truth`` is the
    project's ``/sim/truth``), else None. ``/diagnostics`` only at the root."""
    name = "/" + name.lstrip("/")
    if name in PROJECT_TOPICS:
        return PROJECT_TOPICS[name]
    for n, spec in PROJECT_TOPICS.items():
        if n != TOPIC_DIAGNOSTICS and name.endswith(n):
            return spec
    return None
