"""Shared plumbing of the magtune nodes: QoS, stamps, validated parameters, diagnostics, main().

Physics and control live in ``magtune_core``; this module only adapts them to ROS 2.
"""
from __future__ import annotations

import math
import os
import sys
import time

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

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
#: /diagnostics: the usual diagnostic_aggregator QoS.
DIAG_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)

# Topic names (relative: remappable and namespaceable) and frames: one table, magtune_core.base.topics.
from magtune_core.base.topics import (  # noqa: E402,F401
    FRAME_BODY,
    FRAME_ECI,
    FRAME_ORBITAL,
    TOPIC_ATTITUDE,
    TOPIC_DIAGNOSTICS,
    TOPIC_DIPOLE,
    TOPIC_DIST_TORQUE,
    TOPIC_INERTIAL_RATE,
    TOPIC_MAG,
    TOPIC_MAG_TORQUE,
    TOPIC_MARKERS,
    TOPIC_TF,
    TOPIC_TRUE_FIELD,
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
_TYPES = {
    bool: ParameterType.PARAMETER_BOOL,
    int: ParameterType.PARAMETER_INTEGER,
    float: ParameterType.PARAMETER_DOUBLE,
    str: ParameterType.PARAMETER_STRING,
    "float[]": ParameterType.PARAMETER_DOUBLE_ARRAY,
    "str[]": ParameterType.PARAMETER_STRING_ARRAY,
}
_TYPE_NAMES = {
    ParameterType.PARAMETER_BOOL: "a boolean",
    ParameterType.PARAMETER_INTEGER: "an integer",
    ParameterType.PARAMETER_DOUBLE: "a floating-point number (write 1.0, not 1)",
    ParameterType.PARAMETER_STRING: "a string",
    ParameterType.PARAMETER_DOUBLE_ARRAY: "a list of floating-point numbers (write 1.0, not 1)",
    ParameterType.PARAMETER_STRING_ARRAY: "a list of strings",
}


def declare(node: Node, name: str, default, description: str, ptype=None, *, size=None,
            positive=False, nonnegative=False, choices=None, read_only=True, required=True):
    """Declare a typed parameter with a description and validate its value (ParamError if bad)."""
    ptype = ptype or type(default)
    if default is None and ptype is None:
        raise TypeError("declare: give ptype when default is None")
    tcode = _TYPES[ptype]
    desc = ParameterDescriptor(name=name, type=tcode, description=description, read_only=read_only)
    try:
        if default is None or (isinstance(default, list) and not default):
            # no default (an empty list would be typed BYTE_ARRAY): must come from a parameter file
            from rclpy.parameter import Parameter
            ptypes = {ParameterType.PARAMETER_DOUBLE_ARRAY: Parameter.Type.DOUBLE_ARRAY,
                      ParameterType.PARAMETER_STRING_ARRAY: Parameter.Type.STRING_ARRAY,
                      ParameterType.PARAMETER_DOUBLE: Parameter.Type.DOUBLE,
                      ParameterType.PARAMETER_INTEGER: Parameter.Type.INTEGER,
                      ParameterType.PARAMETER_BOOL: Parameter.Type.BOOL,
                      ParameterType.PARAMETER_STRING: Parameter.Type.STRING}  # every schema kind
            node.declare_parameter(name, ptypes[tcode], desc)
            value = node.get_parameter_or(name, None).value
            if value is None and not required:
                return []
            if value is None:
                raise ParamError(name, "missing" + (f" (expected a list of {size} numbers)" if size else ""))
        else:
            value = node.declare_parameter(name, default, desc).value
    except rclpy.exceptions.InvalidParameterTypeException:
        raise ParamError(name, f"expected {_TYPE_NAMES[tcode]}") from None
    except rclpy.exceptions.ParameterException as exc:
        raise ParamError(name, str(exc)) from None
    if tcode == ParameterType.PARAMETER_DOUBLE_ARRAY:
        arr = np.asarray(list(value), dtype=float)
        if size is not None and arr.size != size:
            raise ParamError(name, f"expected {size} numbers, got {arr.size}")
        if not np.all(np.isfinite(arr)):
            raise ParamError(name, "expected finite numbers, got NaN/Inf")
        if positive and np.any(arr <= 0):
            raise ParamError(name, f"expected positive numbers, got {arr.tolist()}")
        if nonnegative and np.any(arr < 0):
            raise ParamError(name, f"expected non-negative numbers, got {arr.tolist()}")
        return arr
    if tcode in (ParameterType.PARAMETER_DOUBLE, ParameterType.PARAMETER_INTEGER):
        if tcode == ParameterType.PARAMETER_DOUBLE and not math.isfinite(value):
            raise ParamError(name, f"expected a finite number, got {value}")
        if positive and value <= 0:
            raise ParamError(name, f"expected a positive number, got {value}")
        if nonnegative and value < 0:
            raise ParamError(name, f"expected a non-negative number, got {value}")
    if choices is not None and value not in choices:
        raise ParamError(name, f"expected one of {', '.join(map(str, choices))}, got {value!r}")
    return value


#: magtune_core.base.schema field kinds -> the ``ptype`` of :func:`declare`.
_SCHEMA_PTYPES = {"float": float, "int": int, "bool": bool, "str": str, "float[]": "float[]"}


def declare_schema(node: Node, fields, where: str | None = None) -> dict:
    """Declare one parameter per schema field (type, description, default) and return the raw
    values, for the schema's own ``from_mapping`` to validate (same checks as the CLI's).

    Required fields have no default: a parameter file must set them.
    """
    values = {}
    for f in fields:
        default = None if f.required else (list(f.default) if isinstance(f.default, tuple) else f.default)
        # only the ROS type is checked here; values are validated by the schema (same errors as the CLI)
        v = declare(node, f.name, default, f.description, _SCHEMA_PTYPES[f.kind], required=False)
        if f.default is None and (v is None or (isinstance(v, list) and not v)):
            continue  # optional without default (e.g. orbit_period, derived by the schema when absent)
        if not (f.required and (v is None or (isinstance(v, list) and not v))):
            values[f.name] = list(v) if f.kind == "float[]" else v
    return values


def from_schema(node: Node, cls, **kw):
    """``cls.from_mapping`` of the node's declared ``cls.FIELDS``; a ConfigError becomes ParamError."""
    from magtune_core.base.errors import ConfigError

    values = declare_schema(node, cls.FIELDS)
    try:
        return cls.from_mapping(values, f"node '{node.get_name()}'", **kw)
    except ConfigError as exc:
        raise ParamError(exc.field or "?", exc.expected) from None


def declare_spacecraft(node: Node):
    """Spacecraft/orbit parameters (``config/spacecraft.yaml``): the schema SpacecraftParams.FIELDS."""
    from magtune_core.design.params import SpacecraftParams

    return from_schema(node, SpacecraftParams)


def declare_overrides(node: Node, exclude=()):
    """Declare (read-only) every remaining parameter of the parameter files, e.g. gain provenance."""
    for name, param in getattr(node, "_parameter_overrides", {}).items():
        if name in exclude or node.has_parameter(name):
            continue
        node.declare_parameter(name, param.value, ParameterDescriptor(
            name=name, description="provenance (not used by the node)", read_only=True, dynamic_typing=True))


# ---------------------------------------------------------------- diagnostics
class Diagnostics:
    """Counters published on /diagnostics (diagnostic_msgs/DiagnosticArray) every ``period`` wall s."""

    def __init__(self, node: Node, counters, period: float = 1.0):
        self.node = node
        self.counts = {k: 0 for k in counters}
        self.extra: dict = {}
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
        warn = any(v for k, v in self.counts.items() if k not in ("steps", "commands", "samples", "published"))
        st = DiagnosticStatus(level=DiagnosticStatus.WARN if warn else DiagnosticStatus.OK, name=self.name,
                              hardware_id="magtune_sil", message="counters")
        st.values = [KeyValue(key=k, value=str(v)) for k, v in {**self.counts, **self.extra}.items()]
        msg = DiagnosticArray(status=[st])
        msg.header.stamp = self.node.get_clock().now().to_msg()
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


def run(node_cls, args=None) -> int:
    """Create the node, spin until it reports completion (``node.done``) or shutdown, clean up.

    A ParamError (or an rcl parameter-file error) prints one line and returns 2.
    """
    prog = node_cls.NODE_NAME
    argv = list(sys.argv if args is None else args)
    for i, a in enumerate(argv[:-1]):  # check parameter files first: one clear line instead of rcl's
        if a == "--params-file":
            from magtune_core.base.errors import ConfigError
            from magtune_core.base.paramfile import check_ros_params
            try:
                check_ros_params(argv[i + 1])
            except ConfigError as exc:
                print(f"{prog}: {exc}", file=sys.stderr)
                return 2
    try:
        rclpy.init(args=args)
    except Exception as exc:  # malformed --params-file etc.
        print(f"{prog}: cannot start: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    node = None
    code = 0
    try:
        node = node_cls()
        executor = make_executor()
        executor.add_node(node)
        prof = os.environ.get("MAGTUNE_PROFILE")  # directory: dump a cProfile of the spin per node
        if prof:
            import cProfile
            profiler = cProfile.Profile()
            profiler.enable()
        try:
            while rclpy.ok() and not node.done.done():
                executor.spin_until_future_complete(node.done, timeout_sec=1.0)
        finally:
            if prof:
                profiler.disable()
                profiler.dump_stats(os.path.join(prof, f"{prog}.prof"))
        code = int(node.done.result() or 0) if node.done.done() else 0
    except ParamError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 0
    finally:
        if node is not None:
            try:
                node.finish()
            except Exception as exc:  # noqa: BLE001 - best effort at shutdown
                print(f"{prog}: error while finishing: {exc}", file=sys.stderr)
            node.destroy_node()
        rclpy.try_shutdown()
    return code


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
    ``max_age`` relative to the node's (simulated) clock, or more than ``max_age`` ahead of it."""

    def __init__(self, node: Node, max_age_ns: int, n: int = 2):
        self.node = node
        self.max_age_ns = int(max_age_ns)
        self.last_ns = [-1] * n

    def check(self, slot: int, ns: int):
        """Return None if acceptable, else (counter, reason)."""
        if ns <= self.last_ns[slot]:
            kind = "duplicate" if ns == self.last_ns[slot] else "from the past"
            return "rejected_stamp", f"stamp {ns * 1e-9:.3f} s {kind} (last accepted {self.last_ns[slot] * 1e-9:.3f} s)"
        now = self.node.get_clock().now().nanoseconds
        if now - ns > self.max_age_ns:
            return "stale_inputs", f"stamp {ns * 1e-9:.3f} s older than {self.max_age_ns * 1e-9:g} s (now {now * 1e-9:.3f} s)"
        if ns - now > self.max_age_ns:
            return "rejected_stamp", (f"stamp {ns * 1e-9:.3f} s in the future by more than "
                                      f"{self.max_age_ns * 1e-9:g} s (now {now * 1e-9:.3f} s)")
        self.last_ns[slot] = ns
        return None
