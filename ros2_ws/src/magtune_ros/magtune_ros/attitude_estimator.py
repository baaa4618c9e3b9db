"""Attitude estimator node, managed (lifecycle): raw sensors in, attitude and rate estimate out.

The MEKF of magtune_core.design.mekf fed one sample at a time by
magtune_core.design.estimator.MekfStream (coarse fix, propagation with the previous gyro sample,
gated magnetometer and sun updates) against the on-board models of
magtune_core.design.estimator.OnboardModels: the node only moves messages (docs/estimation.md).
configure validates ESTIMATOR_FIELDS (design/node_params.py) and the spacecraft file and builds
the filter; activate creates the topics below (magtune_ros.common.ManagedNode).

Subscribes (LOCKSTEP_QOS):
  sensors/imu             sensor_msgs/Imu            gyro rate [rad/s], body axes
  sensors/magnetic_field  sensor_msgs/MagneticField  measured field [T], body axes
  sensors/sun             geometry_msgs/Vector3Stamped measured unit Sun vector (only when valid)
  sensors/position        nav_msgs/Odometry          position fix r [m], v [m/s], ECI (environment 'full')
                          (each taken raw: the serialized bytes, the fields read in place)
  /clock                  rosgraph_msgs/Clock        (use_sim_time)
Publishes:
  estimate/attitude       sensor_msgs/Imu, frame 'body', stamp = the sample's: orientation = estimated
                          attitude of the body w.r.t. the *orbital* axes (as sensors/attitude, so the
                          controller reads either), orientation_covariance = the MEKF's attitude block
                          [rad^2, body axes]; angular_velocity = gyro minus estimated bias [rad/s] with
                          covariance (sigma_v^2 / ts + bias variance); linear_acceleration_covariance[0] = -1
  /diagnostics            counters: samples, estimates, mag_accepted, mag_rejected, sun_accepted,
                          sun_rejected, sun_missing, sun_late, rejected_nonfinite, rejected_stamp,
                          stale_inputs; values nis_mag, nis_sun (last), state, fixed_at
A sample t_k is processed when its gyro, magnetometer (and, full environment, position fix)
messages are in: with its sun message if that arrived, without one if the on-board model puts the
satellite in the Earth's shadow, else after waiting ``sun_wait`` wall seconds (sun_missing); a sun
message of an already processed stamp is dropped (sun_late). Before the coarse fix each sample's message has
orientation_covariance[0] = -1 (unknown; the
controller commands zero dipole).

The node is on the lockstep's critical path (sensors -> estimator -> controller), so it takes its
inputs serialized (raw) and reads only the fields it uses (common.raw_imu, raw_magnetic_field,
raw_vector3_stamped, raw_odometry), runs the filter compiled (MekfStream(compiled=True), the same
equations as the core's Python filter within 1e-10 rad) and fills a preallocated message.
"""
from __future__ import annotations

import math

import numpy as np
from geometry_msgs.msg import Vector3Stamped
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from sensor_msgs.msg import Imu, MagneticField

from magtune_core.design.estimator import MekfStream, OnboardModels
from magtune_core.design.node_params import ESTIMATOR_FIELDS
from magtune_core.design.params import SpacecraftParams
from magtune_core.design.sensors import Gyro, Magnetometer, SensorSuite, SunSensor

from . import common as c

#: The estimate's topic (relative): ``magtune sil --attitude estimator`` remaps the controller's
#: sensors/attitude to it.
TOPIC_ESTIMATE = c.TOPIC_ESTIMATE


def suite_from(v: dict) -> SensorSuite:
    """The filter's sensor model from the parsed ESTIMATOR_FIELDS (what MekfStream reads)."""
    return SensorSuite(float(v["ts"]), Magnetometer(float(v["mag_noise_std"])),
                       Gyro(float(v["gyro_arw"]), float(v["gyro_rrw"])), 0.0, SunSensor(float(v["sun_noise_std"])))


def models_from(v: dict, p: SpacecraftParams) -> OnboardModels:
    """The on-board models of the parsed parameters and the spacecraft file."""
    if v["environment"] == "full":
        return OnboardModels("full", p.orbit_config().jd0, int(v["igrf_degree"]))
    return OnboardModels("paper", p.orbit_config().jd0, paper_field=p.field(), orbit_rate=p.orbit_rate)


class AttitudeEstimator(c.ManagedNode):
    NODE_NAME = "attitude_estimator"

    def __init__(self):
        super().__init__(self.NODE_NAME, ["samples", "estimates", "mag_accepted", "mag_rejected", "sun_accepted",
                                          "sun_rejected", "sun_missing", "sun_late", "rejected_nonfinite",
                                          "rejected_malformed", "rejected_stamp", "stale_inputs"])
        self.pending = None
        self.create_timer(0.05, self.check_pending, clock=Clock(clock_type=ClockType.STEADY_TIME))

    # ---------------------------------------------------------------- lifecycle
    def configure(self):
        """Validate the parameters and the spacecraft file; build the filter and the on-board models."""
        v = c.parse_fields(self, ESTIMATOR_FIELDS)
        p = c.from_schema(self, SpacecraftParams)
        c.declare_overrides(self)
        self.values, self.full = v, v["environment"] == "full"
        self.suite, self.models = suite_from(v), models_from(v, p)
        self.msg = Imu()
        self.msg.header.frame_id = c.FRAME_BODY
        self.msg.linear_acceleration_covariance[0] = -1.0
        self.rate_var = self.suite.gyro.white_std(self.suite.ts) ** 2 * np.eye(3)  # the gyro's white part
        self.unknown = np.array([-1.0] + [0.0] * 8)  # REP-145's "not known" covariance

    def activate(self):
        """A fresh filter (an activation restarts from the coarse fix), then the topics."""
        v = self.values
        self.stream = MekfStream(self.suite, bias_std=v["initial_bias_std"], gate_probability=v["gate_probability"],
                                 init_angle=v["init_angle"], mag_bias_std=v["initial_mag_bias_std"],
                                 mag_bias_rw=v["mag_bias_rw"], compiled=True)
        self.ts_ns = c.sec_to_ns(self.suite.ts)
        self.gate = c.StampGate(self, 2 * self.ts_ns, n=4)
        self.sync = c.PairSync(3 if self.full else 2)  # imu, mag (, position): same stamp t_k
        self.suns: dict = {}
        self.last_ns, self.w_prev, self.pending = -1, None, None
        self.pub = self.data_publisher(Imu, TOPIC_ESTIMATE, c.LOCKSTEP_QOS)
        self.data_subscription(Imu, c.TOPIC_IMU, self.on_imu, c.LOCKSTEP_QOS, raw=True)
        self.data_subscription(MagneticField, c.TOPIC_MAG, self.on_mag, c.LOCKSTEP_QOS, raw=True)
        if self.full:
            self.data_subscription(Vector3Stamped, c.TOPIC_SUN, self.on_sun, c.LOCKSTEP_QOS, raw=True)
            self.data_subscription(Odometry, c.TOPIC_POSITION, self.on_position, c.LOCKSTEP_QOS, raw=True)

    # ---------------------------------------------------------------- inputs (serialized messages)
    def on_imu(self, data: bytes):
        f = c.raw_imu(data)
        if f is None:
            return self.diag.count("rejected_malformed", "malformed sensors/imu message")
        if not c.finite(*f[2]):
            return self.diag.count("rejected_nonfinite", "non-finite gyro rate")
        self._input(0, f[0], f[2])

    def on_mag(self, data: bytes):
        f = c.raw_magnetic_field(data)
        if f is None:
            return self.diag.count("rejected_malformed", "malformed sensors/magnetic_field message")
        b = f[1]
        if not c.finite(*b) or b[0] == b[1] == b[2] == 0.0:
            return self.diag.count("rejected_nonfinite", "non-finite or zero magnetic field")
        self._input(1, f[0], b)

    def on_position(self, data: bytes):
        f = c.raw_odometry(data)
        if f is None:
            return self.diag.count("rejected_malformed", "malformed sensors/position message")
        p, v = f[1], f[2]
        if not c.finite(*p, *v) or p[0] == p[1] == p[2] == 0.0:
            return self.diag.count("rejected_nonfinite", "non-finite or zero position fix")
        self._input(2, f[0], (np.array(p), np.array(v)))

    def on_sun(self, data: bytes):
        f = c.raw_vector3_stamped(data)
        if f is None:
            return self.diag.count("rejected_malformed", "malformed sensors/sun message")
        ns, (x, y, z) = f
        n = math.sqrt(x * x + y * y + z * z) if c.finite(x, y, z) else 0.0
        if not abs(n - 1.0) < 1e-3:
            return self.diag.count("rejected_nonfinite", "sun vector not finite and unit")
        if ns <= self.last_ns:
            return self.diag.count("sun_late", f"sun sample of {ns * 1e-9:.3f} s after that step was estimated")
        self.suns[ns] = np.array([x, y, z])
        while len(self.suns) > 16:
            del self.suns[next(iter(self.suns))]
        if self.pending is not None and self.pending[0] == ns:
            self._process(*self.pending[:2])

    def _input(self, slot, ns, value):
        bad = self.gate.check(slot, ns)
        if bad:
            return self.diag.count(*bad)
        group = self.sync.add(slot, ns, value)
        if group is None:
            return
        if self.pending is not None:  # a newer sample is complete: the pending one goes on without its sun
            self.diag.count("sun_missing", "no sun sample for a step predicted lit")
            self._process(*self.pending[:2])
        if not self.full or ns in self.suns or not self.models.lit(self._t(ns), group[2][0]):
            return self._process(ns, group)
        self.pending = (ns, group, c.now_wall())

    def check_pending(self):
        if self.pending is not None and c.now_wall() - self.pending[2] > self.values["sun_wait"]:
            self.diag.count("sun_missing", "no sun sample for a step predicted lit")
            self._process(*self.pending[:2])

    def _t(self, ns: int) -> float:
        return (ns - self.values["time_origin_ns"]) * 1e-9

    # ---------------------------------------------------------------- the step
    def _process(self, ns, group):
        """One MEKF step of sample ``ns`` (design.estimator.MekfStream.step) and its estimate."""
        self.pending = None
        self.last_ns = ns
        w, b = group[0], group[1]
        t = self._t(ns)
        r, v = group[2] if self.full else (None, None)
        sun = self.suns.pop(ns, None)
        for k in [k for k in self.suns if k < ns]:
            del self.suns[k]
        s_ref = self.models.sun(t, r) if sun is not None else None
        out = self.stream.step(self.w_prev, b, self.models.field(t, r), sun, s_ref)
        self.w_prev = np.array(w)
        self.diag.count("samples")
        if out.state is None:  # before the coarse fix: "no orientation" (the controller commands zero)
            return self.publish_none(ns)
        if out.started:
            self.diag.extra["fixed_at"] = f"{t:.3f}"
        if out.mag_accepted:
            self.diag.count("mag_accepted")
        else:
            self.diag.count("mag_rejected", f"magnetometer innovation gated (NIS {out.nis_mag:.3g})")
        self.diag.extra["nis_mag"] = f"{out.nis_mag:.4g}"
        if out.sun_accepted is not None:
            if out.sun_accepted:
                self.diag.count("sun_accepted")
            else:
                self.diag.count("sun_rejected", f"sun innovation gated (NIS {out.nis_sun:.3g})")
            self.diag.extra["nis_sun"] = f"{out.nis_sun:.4g}"
        self.publish(ns, t, out.state, r, v)

    def publish(self, ns, t, state, r, v):
        m = self.msg
        m.header.stamp = c.ns_to_stamp(ns)
        q = self.models.to_orbital(state.q, t, r, v)
        o = m.orientation
        o.w, o.x, o.y, o.z = float(q[0]), float(q[1]), float(q[2]), float(q[3])
        P = state.P
        m.orientation_covariance = P[:3, :3].ravel()  # a float64 (9,) copy: rclpy takes it as is
        av = m.angular_velocity
        w, bias = self.w_prev, state.b
        av.x, av.y, av.z = float(w[0] - bias[0]), float(w[1] - bias[1]), float(w[2] - bias[2])
        m.angular_velocity_covariance = (P[3:6, 3:6] + self.rate_var).ravel()  # the gyro-bias block of the 9
        self.diag.count("estimates")
        self.pub.publish(m)

    def publish_none(self, ns):
        """The sample's message without an estimate: orientation_covariance[0] = -1 (REP-145's
        "not known"), so the lockstep goes on and the controller holds the torquers off."""
        m = self.msg
        m.header.stamp = c.ns_to_stamp(ns)
        m.orientation.w, m.orientation.x, m.orientation.y, m.orientation.z = 1.0, 0.0, 0.0, 0.0
        m.orientation_covariance = self.unknown.copy()
        w = self.w_prev
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = (float(x) for x in w)
        m.angular_velocity_covariance = self.unknown.copy()
        self.pub.publish(m)


def main(args=None):
    return c.run(AttitudeEstimator, args)


if __name__ == "__main__":
    raise SystemExit(main())
