"""Shared plumbing of the magtune nodes: QoS, stamps, parameters from the schemas, diagnostics, run().

Physics and control live in ``magtune_core``; this module only adapts them to ROS 2.
"""
from __future__ import annotations

import array
import math
import os
import signal
import struct
import sys
import threading
import time

import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from rclpy.utilities import remove_ros_args

from magtune_core.base.errors import ConfigError
from magtune_core.base.paramfile import check_ros_params
from magtune_core.base.schema import Field, parse
from magtune_core.design.node_params import AUTOSTART

#: Lockstep data topics (truth, field, sensors, dipole command, torques): reliable, and
#: transient-local so a subscriber matched after the first publication (DDS discovery is
#: asynchronous between the three processes) still receives it; depth 1000 (about 17 minutes of
#: sim time at Ts = 1 s, a few seconds of wall time at full SIL speed) so a recorder starved of
#: CPU on a loaded machine catches up instead of losing bursts (seen with depth 100 at load 5).
LOCKSTEP_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: /clock: reliable publisher (compatible with rclpy's best-effort TimeSource subscriber);
#: depth 1000 as the lockstep topics, for a reliable recorder that falls behind (with 100, a
#: recorder starved at load 4.7 lost up to 265 /clock samples of a 5-orbit run; issue #10).
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
#: mode: reliable and transient-local with depth 10, so a late subscriber (controller activated
#: after the manager published, a recorder) gets the current mode and the last transitions.
MODE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: /diagnostics: the usual diagnostic_aggregator QoS.
DIAG_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)

# Topic names (relative: remappable and namespaceable) and frames: one table, magtune_core.base.topics.
from magtune_core.base.topics import (  # noqa: E402,F401
    FRAME_BODY,
    FRAME_ECI,
    FRAME_ORBITAL,
    SERVICE_SET_MODE,
    TOPIC_ATTITUDE,
    TOPIC_DIAGNOSTICS,
    TOPIC_DIPOLE,
    TOPIC_DIST_TORQUE,
    TOPIC_ESTIMATE,
    TOPIC_IMU,
    TOPIC_INERTIAL_RATE,
    TOPIC_MAG,
    TOPIC_MAG_TORQUE,
    TOPIC_MARKERS,
    TOPIC_MODE,
    TOPIC_ORBIT,
    TOPIC_POSITION,
    TOPIC_SUN,
    TOPIC_TF,
    TOPIC_TORQUER_FIELD,
    TOPIC_TRUE_FIELD,
    TOPIC_TRUE_SUN,
    TOPIC_TRUTH,
)


class ParamError(ValueError):
    """Invalid node parameter: the node prints one line naming it and exits with status 2."""

    def __init__(self, name: str, expected: str):
        self.name = name
        super().__init__(f"parameter '{name}': {expected}")


# ---------------------------------------------------------------- stamps
def ns_to_stamp(ns: int) -> Time:
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def stamp_to_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def sec_to_ns(t: float) -> int:
    return int(round(t * 1e9))


def finite(*values) -> bool:
    return all(math.isfinite(v) for v in values)


# ---------------------------------------------------------------- parameters
#: magtune_core.base.schema field kinds -> ROS 2 parameter types.
_ROS_TYPES = {
    "bool": Parameter.Type.BOOL,
    "int": Parameter.Type.INTEGER,
    "float": Parameter.Type.DOUBLE,
    "str": Parameter.Type.STRING,
    "float[]": Parameter.Type.DOUBLE_ARRAY,
    "str[]": Parameter.Type.STRING_ARRAY,
}
_TYPE_NAMES = {
    "bool": "a boolean",
    "int": "an integer",
    "float": "a floating-point number (write 1.0, not 1)",
    "str": "a string",
    "float[]": "a list of floating-point numbers (write 1.0, not 1)",
    "str[]": "a list of strings",
}


def declare_field(node: Node, f: Field):
    """Declare the schema field ``f`` as a read-only ROS parameter (type, description and
    default from the schema); return the value set, or None when unset and without default.
    Only the ROS type is checked here (ParamError); the value is the schema's to validate."""
    desc = ParameterDescriptor(name=f.name, type=_ROS_TYPES[f.kind].value, read_only=True,
                               description=f.description + (f" [{f.unit}]" if f.unit and f.unit not in f.description
                                                            else ""))
    default = None if f.required else (list(f.default) if isinstance(f.default, tuple) else f.default)
    if node.has_parameter(f.name):  # a managed node configured again (after cleanup): read it back
        value = node.get_parameter(f.name).value
        return list(value) if isinstance(value, (list, tuple, array.array)) or hasattr(value, "tolist") else value
    try:
        if default is None or default == []:
            # no default (an empty list would be typed BYTE_ARRAY): typed, set by a parameter file or not at all
            node.declare_parameter(f.name, _ROS_TYPES[f.kind], desc)
            value = node.get_parameter_or(f.name, None).value
        else:
            value = node.declare_parameter(f.name, default, desc).value
    except rclpy.exceptions.InvalidParameterTypeException:
        raise ParamError(f.name, f"expected {_TYPE_NAMES[f.kind]}") from None
    except rclpy.exceptions.ParameterException as exc:
        raise ParamError(f.name, str(exc)) from None
    return list(value) if isinstance(value, (list, tuple, array.array)) or hasattr(value, "tolist") else value


def declare_fields(node: Node, fields) -> dict:
    """Declare every field of a schema; return the values set (unset fields left out)."""
    values = {}
    for f in fields:
        v = declare_field(node, f)
        if v is not None and not (v == [] and (f.required or not f.default)):
            values[f.name] = v
    return values


def _param_error(exc: ConfigError) -> ParamError:
    return ParamError(exc.field or "?", exc.expected)


def parse_fields(node: Node, fields) -> dict:
    """Declare a schema's parameters and validate them once (:func:`magtune_core.base.schema.parse`:
    the CLI's checks and messages); a ConfigError becomes ParamError (one line, exit status 2)."""
    try:
        return parse(declare_fields(node, fields), fields, f"node '{node.get_name()}'")
    except ConfigError as exc:
        raise _param_error(exc) from None


def from_schema(node: Node, cls, **kw):
    """``cls.from_mapping`` (which validates) of the node's declared ``cls.FIELDS``; a ConfigError becomes ParamError."""
    values = declare_fields(node, cls.FIELDS)
    try:
        return cls.from_mapping(values, f"node '{node.get_name()}'", **kw)
    except ConfigError as exc:
        raise _param_error(exc) from None


def check(rule, values: dict, node: Node) -> None:
    """Apply a schema's rule across fields (e.g. ``design.node_params.check_simulator``) as ParamError."""
    try:
        rule(values, f"node '{node.get_name()}'")
    except ConfigError as exc:
        raise _param_error(exc) from None


def declare_overrides(node: Node, exclude=()):
    """Declare (read-only) every remaining parameter of the parameter files, e.g. gain provenance."""
    for name, param in getattr(node, "_parameter_overrides", {}).items():
        if name in exclude or node.has_parameter(name):
            continue
        node.declare_parameter(name, param.value, ParameterDescriptor(
            name=name, description="provenance (not used by the node)", read_only=True, dynamic_typing=True))


# ---------------------------------------------------------------- diagnostics
#: Counters that report normal operation (the others raise the status to WARN): the sun sensor's
#: eclipse and field-of-view dropouts are what the sensor does, not faults.
INFO_COUNTERS = ("steps", "commands", "samples", "published", "sun_samples", "sun_eclipse", "sun_out_of_fov",
                 "estimates", "mag_accepted", "sun_accepted")

class Diagnostics:
    """Counters published on /diagnostics (diagnostic_msgs/DiagnosticArray) every ``period`` wall s."""

    def __init__(self, node: Node, counters, period: float = 1.0, now_ns=None):
        self.node = node
        #: the header stamp's source [ns] (default the node's clock)
        self.now_ns = now_ns
        self.counts = {k: 0 for k in counters}
        self.extra: dict = {}
        #: (level, message) overriding the counters' status, e.g. a managed node's failed configure
        self.status: tuple | None = None
        self.pub = node.create_publisher(DiagnosticArray, "/diagnostics", DIAG_QOS)
        self.name = f"magtune/{node.get_name()}"
        self._last_reason: dict = {}
        self.timer = node.create_timer(period, self.publish, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def count(self, key: str, reason: str | None = None, n: int = 1):
        """Increment a counter; log the reason (throttled: first time, then every 100th)."""
        self.counts[key] = self.counts.get(key, 0) + n
        if reason is not None:
            c = self.counts[key]
            if c == 1 or c % 100 == 0:
                self.node.get_logger().warning(f"{key} (#{c}): {reason}")

    def publish(self):
        warn = any(v for k, v in self.counts.items() if k not in INFO_COUNTERS)
        level, message = self.status or (DiagnosticStatus.WARN if warn else DiagnosticStatus.OK, "counters")
        st = DiagnosticStatus(level=level, name=self.name, hardware_id="magtune_sil", message=message)
        st.values = [KeyValue(key=k, value=str(v)) for k, v in {**self.counts, **self.extra}.items()]
        msg = DiagnosticArray(status=[st])
        msg.header.stamp = ns_to_stamp(self.now_ns()) if self.now_ns else self.node.get_clock().now().to_msg()
        self.pub.publish(msg)


# ---------------------------------------------------------------- main
def make_executor():
    """EventsExecutor (C++, lowest per-callback overhead) unless MAGTUNE_EXECUTOR=single."""
    if os.environ.get("MAGTUNE_EXECUTOR", "events") != "single":
        try:
            from rclpy.experimental import EventsExecutor
            return EventsExecutor()
        except Exception:  # pragma: no cover - older rclpy
            pass
    return SingleThreadedExecutor()


#: Signals that stop a node cleanly: Ctrl-C, ``kill``, closed terminal.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def install_stop_handlers() -> threading.Event:
    """SIGINT/SIGTERM/SIGHUP set the returned event: the node's spin loop ends and it finishes
    cleanly (a recorder closes its bag, a simulator keeps what it wrote)."""
    stop = threading.Event()

    def handler(signum, frame):  # noqa: ARG001
        stop.set()

    for sig in STOP_SIGNALS:
        signal.signal(sig, handler)
    return stop


def spin_until_done(node: Node, executor, stop: threading.Event) -> int:
    """Spin until the node reports completion (``node.done``, its exit status) or a stop signal."""
    while rclpy.ok() and not stop.is_set() and not node.done.done():
        executor.spin_until_future_complete(node.done, timeout_sec=0.1)
    return int(node.done.result() or 0) if node.done.done() else 0


def _check_parameter_files(prog: str, argv: list[str]) -> bool:
    """Check each ``--params-file`` first: one clear line instead of rcl's parser message."""
    for i, a in enumerate(argv[:-1]):
        if a == "--params-file":
            try:
                check_ros_params(argv[i + 1])
            except ConfigError as exc:
                print(f"{prog}: {exc}", file=sys.stderr)
                return False
    return True


def run(node_cls, args=None) -> int:
    """Start a magtune node and return its exit status: the one main of every node.

    Parameter files are checked first; ``node_cls.parse_options(argv)`` (if the node has
    command-line options, as ``ros2 bag`` does) parses the arguments that are not ROS
    arguments; then rclpy starts, the node is built (``node_cls(options)`` or ``node_cls()``),
    added to ``node_cls.EXECUTOR()`` (default :func:`make_executor`) and spun by
    ``node.spin(executor, stop)`` if it has one, else until ``node.done``. SIGINT,
    SIGTERM and SIGHUP end the spin; ``node.finish()`` then runs and rclpy shuts down. A bad
    parameter or option (ParamError, ConfigError, or one of ``node_cls.START_ERRORS``) prints
    one line naming it and returns 2.
    """
    prog = node_cls.NODE_NAME
    argv = list(sys.argv if args is None else args)
    if not _check_parameter_files(prog, argv):
        return 2
    start_errors = (ParamError, ConfigError, *getattr(node_cls, "START_ERRORS", ()))
    parse_options = getattr(node_cls, "parse_options", None)
    try:
        options = parse_options(remove_ros_args(argv)[1:]) if parse_options else None
    except start_errors as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    try:
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # malformed --params-file etc.
        print(f"{prog}: cannot start: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    stop = install_stop_handlers()
    node = executor = None
    code = 0
    try:
        node = node_cls(options) if parse_options else node_cls()
        executor = (getattr(node_cls, "EXECUTOR", None) or make_executor)()
        executor.add_node(node)
        if isinstance(node, ManagedNode) and not node.autostart():
            print(f"{prog}: {node.config_error}", file=sys.stderr)
            return 2
        code = _spin_profiled(prog, node, executor, stop)
    except start_errors as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 0
    finally:
        _shutdown(prog, node, executor)
    return code


# ---------------------------------------------------------------- managed (lifecycle) nodes
class ManagedNode(LifecycleNode):
    """A magtune flight node with a life (``rclpy.lifecycle``): configure, activate, deactivate,
    cleanup, shutdown, driven through ``~/change_state`` (lifecycle_msgs) by the mode manager.

    Subclasses implement ``configure()`` (declare and validate the parameters, build the law:
    ParamError/ConfigError -> the transition fails, the node stays *unconfigured*, the one-line
    reason is logged, kept in ``config_error`` and published as an ERROR status on /diagnostics,
    where the manager reads it), ``activate()`` (create the data subscriptions and publishers) and
    ``deactivate()`` (destroy them). Data entities live only while *active* so a lockstep peer
    (the simulator waits for its subscribers) sees the node only once it takes and sends data.
    /diagnostics (the node's heartbeat, 1 Hz steady time, key ``state``) runs in every state.

    With parameter ``autostart`` true (default: a node started alone, or ``magtune sil`` without
    ``--modes``) :func:`run` configures and activates the node itself: a bad parameter prints the
    one line and exits 2 as a plain node does.
    """

    def __init__(self, name: str, counters):
        super().__init__(name)
        self.done = Future()
        self.config_error: str | None = None
        self.autostart_on = declare_field(self, AUTOSTART)
        self.diag = Diagnostics(self, counters)
        self.diag.extra["state"] = "unconfigured"
        self.diag.extra["namespace"] = self.get_namespace()  # /diagnostics is shared by every satellite
        self._entities: list = []

    # the transitions, as rclpy calls them
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self.configure()
        except (ParamError, ConfigError) as exc:
            self.config_error = str(exc)
            self.diag.status = (DiagnosticStatus.ERROR, f"configure failed: {exc}")
            self.diag.publish()
            if not self.autostart_on:  # alone, run() prints the one line
                self.get_logger().error(f"configure failed: {exc}")
            return TransitionCallbackReturn.FAILURE
        self.config_error, self.diag.status = None, None
        return self._entered("inactive")

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.activate()
        return self._entered("active")

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._destroy_entities()
        return self._entered("inactive")

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._destroy_entities()
        return self._entered("unconfigured")

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Finalized: the process ends (status 0), as a lifecycle node's owner would end it."""
        self._destroy_entities()
        if not self.done.done():
            self.done.set_result(0)
        return self._entered("finalized")

    def _entered(self, label: str) -> TransitionCallbackReturn:
        self.diag.extra["state"] = label
        return TransitionCallbackReturn.SUCCESS

    # entity bookkeeping of activate()
    def data_publisher(self, *args):
        """A publisher that exists while the node is active."""
        pub = self.create_publisher(*args)
        self._entities.append(pub)
        return pub

    def data_subscription(self, *args, **kw):
        """A subscription that exists while the node is active (``raw=True``: the callback gets the bytes)."""
        sub = self.create_subscription(*args, **kw)
        self._entities.append(sub)
        return sub

    def _destroy_entities(self):
        for e in self._entities:
            (self.destroy_publisher if hasattr(e, "publish") else self.destroy_subscription)(e)
        self._entities = []

    def autostart(self) -> bool:
        """With ``autostart``: configure then activate; False (reason in ``config_error``) if configure failed."""
        if not self.autostart_on:
            return True
        if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
            return False
        self.trigger_activate()
        return True

    # what subclasses fill in
    def finish(self):
        """At shutdown (``run``): the last diagnostics, so /diagnostics ends with the final counters."""
        if self.context.ok():
            self.diag.publish()

    def configure(self):  # pragma: no cover - abstract
        raise NotImplementedError

    def activate(self):  # pragma: no cover - abstract
        raise NotImplementedError


def _spin_profiled(prog: str, node: Node, executor, stop: threading.Event) -> int:
    """The node's spin; with MAGTUNE_PROFILE=DIR a cProfile of it is dumped to DIR/<prog>.prof."""
    prof = os.environ.get("MAGTUNE_PROFILE")
    profiler = None
    if prof:
        import cProfile
        profiler = cProfile.Profile()
        profiler.enable()
    try:
        spin = getattr(node, "spin", None)
        return int(spin(executor, stop) or 0) if spin else spin_until_done(node, executor, stop)
    finally:
        if profiler is not None:
            profiler.disable()
            profiler.dump_stats(os.path.join(prof, f"{prog}.prof"))


def _shutdown(prog: str, node, executor) -> None:
    if node is not None:
        try:
            node.finish()
        except Exception as exc:  # noqa: BLE001 - best effort at shutdown
            print(f"{prog}: error while finishing: {exc}", file=sys.stderr)
    if executor is not None:
        executor.shutdown()
    if node is not None:
        node.destroy_node()
    rclpy.try_shutdown()


def now_wall() -> float:
    return time.perf_counter()


# ---------------------------------------------------------------- input checks
class PairSync:
    """Matches ``n`` input topics (default 2) by identical header stamps.

    Each slot keeps its last ``depth`` messages by stamp, so a set completes even when another
    topic already delivered the next step (free-running at a high real-time factor, or a
    loaded machine); a completed stamp drops itself and everything older in every slot.
    """

    def __init__(self, n: int = 2, depth: int = 16):
        self.slots: list[dict] = [{} for _ in range(n)]  # stamp ns -> msg, insertion (= stamp) order
        self.depth = depth

    def add(self, slot: int, ns: int, msg):
        """Store ``msg``; return (msg0, msg1, ...) when every slot holds stamp ``ns``, else None."""
        mine = self.slots[slot]
        mine[ns] = msg
        if len(mine) > self.depth:
            del mine[next(iter(mine))]
        if all(ns in x for x in self.slots):
            out = tuple(x[ns] for x in self.slots)
            for x in self.slots:
                for k in [k for k in x if k <= ns]:
                    del x[k]
            return out
        return None


class StampGate:
    """Rejects inputs whose stamps are not newer than the last accepted one, older than
    ``max_age`` relative to the node's (simulated) clock, or more than ``max_age`` ahead of it
    (``max_age_ns`` None: the stamps' order only, no clock read).

    A sim clock still at 0 has not received /clock yet (rclpy's use_sim_time starts there): only
    the order is checked then. The lockstep data readers can match the simulator before the
    best-effort /clock reader does; a controller at 0 s was seen rejecting the sample of t = 3 s
    as "in the future", so that step went unanswered and the seeded run differed from its twin.
    """

    def __init__(self, node: Node, max_age_ns: int | None, n: int = 2):
        self.node = node
        self.max_age_ns = None if max_age_ns is None else int(max_age_ns)
        self.last_ns = [-1] * n

    def check(self, slot: int, ns: int):
        """Return None if acceptable, else (counter, reason)."""
        if ns <= self.last_ns[slot]:
            kind = "duplicate" if ns == self.last_ns[slot] else "from the past"
            return "rejected_stamp", f"stamp {ns * 1e-9:.3f} s {kind} (last accepted {self.last_ns[slot] * 1e-9:.3f} s)"
        if self.max_age_ns is None:
            self.last_ns[slot] = ns
            return None
        now = self.node.get_clock().now().nanoseconds
        if now == 0:  # no /clock yet
            self.last_ns[slot] = ns
            return None
        if now - ns > self.max_age_ns:
            return "stale_inputs", f"stamp {ns * 1e-9:.3f} s older than {self.max_age_ns * 1e-9:g} s (now {now * 1e-9:.3f} s)"
        if ns - now > self.max_age_ns:
            return "rejected_stamp", (f"stamp {ns * 1e-9:.3f} s in the future by more than "
                                      f"{self.max_age_ns * 1e-9:g} s (now {now * 1e-9:.3f} s)")
        self.last_ns[slot] = ns
        return None


# ---------------------------------------------------------------- serialized (raw) messages
#: CDR encapsulation (XCDR1, the rmw's for ROS 2 types) -> struct byte order.
_CDR_ORDER = {b"\x00\x01": "<", b"\x00\x00": ">"}
_HEADER = {o: struct.Struct(o + "iII") for o in "<>"}  # stamp sec, nanosec, frame_id length (with its NUL)
#: sensor_msgs/Imu after the header: orientation x y z w, 9 covariances (skipped), angular_velocity x y z
_IMU = {o: struct.Struct(o + "4d72x3d") for o in "<>"}
_IMU_SIZE = 32 + 72 + 24 + 72 + 24 + 72  # orientation .. linear_acceleration_covariance [bytes]
#: sensor_msgs/MagneticField after the header: magnetic_field x y z, 9 covariances
_VEC3 = {o: struct.Struct(o + "3d") for o in "<>"}
_UINT = {o: struct.Struct(o + "I") for o in "<>"}
#: nav_msgs/Odometry after child_frame_id: pose position x y z, orientation and 36 covariances (skipped),
#: twist linear x y z
_ODOM = {o: struct.Struct(o + "3d32x288x3d") for o in "<>"}
_ODOM_SIZE = 24 + 32 + 288 + 24 + 24 + 288  # pose .. twist covariance [bytes]


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
    """(stamp [ns], (qw, qx, qy, qz), (wx, wy, wz)) of a serialized sensor_msgs/Imu (a ``raw=True``
    subscription's bytes), or None if malformed: the two fields without building the message."""
    h = _raw_header(data)
    if h is None or len(data) < h[2] + _IMU_SIZE:
        return None
    order, ns, at = h
    x, y, z, w, wx, wy, wz = _IMU[order].unpack_from(data, at)
    return ns, (w, x, y, z), (wx, wy, wz)


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
