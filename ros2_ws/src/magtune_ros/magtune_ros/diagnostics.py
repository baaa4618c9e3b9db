"""The nodes' counters on /diagnostics (diagnostic_msgs/DiagnosticArray), 1 Hz of steady time.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from .inputs import ns_to_stamp
from .qos import DIAG_QOS

#: Counters that report normal operation (the others raise the status to WARN): the sun sensor's
#: eclipse and field-of-view dropouts are what the sensor does, not faults.
INFO_COUNTERS = ("steps", "commands", "samples", "published", "sun_samples", "sun_eclipse", "sun_out_of_fov",
                 "estimates", "mag_accepted", "sun_accepted", "reinitialised")

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
        #: unit -> (level, message, stamp [ns]) of a detected fault that is still active
        self.faults: dict = {}
        self.timer = node.create_timer(period, self.publish, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def count(self, key: str, reason: str | None = None, n: int = 1):
        """Increment a counter; log the reason (throttled: first time, then every 100th)."""
        self.counts[key] = self.counts.get(key, 0) + n
        if reason is not None:
            c = self.counts[key]
            if c == 1 or c % 100 == 0:
                self.node.get_logger().warning(f"{key} (#{c}): {reason}")

    def publish(self):
        """Publish the counters and extra values as one DiagnosticStatus (the 1 Hz steady timer, and on demand); level ``status`` if set,
        else WARN when a fault counter (not in INFO_COUNTERS) is nonzero, else OK."""
        warn = any(v for k, v in self.counts.items() if k not in INFO_COUNTERS)
        level, message = self.status or (DiagnosticStatus.WARN if warn else DiagnosticStatus.OK, "counters")
        st = DiagnosticStatus(level=level, name=self.name, hardware_id="magtune_sil", message=message)
        st.values = [KeyValue(key=k, value=str(v)) for k, v in {**self.counts, **self.extra}.items()]
        msg = DiagnosticArray(status=[st] + [self._unit_status(u, lv, text) for u, (lv, text, _) in self.faults.items()])
        msg.header.stamp = ns_to_stamp(self.now_ns()) if self.now_ns else self.node.get_clock().now().to_msg()
        self.pub.publish(msg)

    def _unit_status(self, unit: str, level: int, text: str) -> DiagnosticStatus:
        return DiagnosticStatus(level=level, name=f"{self.name}/fdir", hardware_id=unit, message=f"{unit}: {text}")

    def unit_fault(self, unit: str, text: str, stamp_ns: int, level: int = DiagnosticStatus.WARN):
        """A detected fault of ``unit`` (e.g. "sun sensor"): published at once, stamped ``stamp_ns`` (sim time of
        the sample it was detected on), and with every later array until :meth:`unit_back`; logged once."""
        self.faults[unit] = (level, text, stamp_ns)
        self.node.get_logger().warning(f"{unit}: {text}")
        self._publish_now(self._unit_status(unit, level, text), stamp_ns)

    def unit_back(self, unit: str, text: str, stamp_ns: int):
        """``unit`` works again: an OK status naming it, published at once; no longer repeated."""
        if self.faults.pop(unit, None) is not None:
            self.node.get_logger().info(f"{unit}: {text}")
            self._publish_now(self._unit_status(unit, DiagnosticStatus.OK, text), stamp_ns)

    def _publish_now(self, status: DiagnosticStatus, stamp_ns: int):
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = ns_to_stamp(stamp_ns)
        self.pub.publish(msg)
