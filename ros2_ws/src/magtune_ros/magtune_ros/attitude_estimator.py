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
from magtune_core.design.sensors import Gyro, Magnetometer, SensorSuite, SunSensor, illuminated

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
                                          "rejected_stamp", "stale_inputs"])
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

    def activate(self):
        """A fresh filter (an activation restarts from the coarse fix), then the topics."""
        v = self.values
        self.stream = MekfStream(self.suite, bias_std=v["initial_bias_std"], gate_probability=v["gate_probability"],
                                 init_angle=v["init_angle"])
        self.ts_ns = c.sec_to_ns(self.suite.ts)
        self.gate = c.StampGate(self, 2 * self.ts_ns, n=4)
        self.sync = c.PairSync(3 if self.full else 2)  # imu, mag (, position): same stamp t_k
        self.suns: dict = {}
        self.last_ns, self.w_prev, self.pending = -1, None, None
        self.pub = self.data_publisher(Imu, TOPIC_ESTIMATE, c.LOCKSTEP_QOS)
        self.data_subscription(Imu, c.TOPIC_IMU, self.on_imu, c.LOCKSTEP_QOS)
        self.data_subscription(MagneticField, c.TOPIC_MAG, self.on_mag, c.LOCKSTEP_QOS)
        if self.full:
            self.data_subscription(Vector3Stamped, c.TOPIC_SUN, self.on_sun, c.LOCKSTEP_QOS)
            self.data_subscription(Odometry, c.TOPIC_POSITION, self.on_position, c.LOCKSTEP_QOS)

    # ---------------------------------------------------------------- inputs
    def on_imu(self, msg: Imu):
        w = msg.angular_velocity
        if not c.finite(w.x, w.y, w.z):
            return self.diag.count("rejected_nonfinite", "non-finite gyro rate")
        self._input(0, msg)

    def on_mag(self, msg: MagneticField):
        b = msg.magnetic_field
        if not c.finite(b.x, b.y, b.z) or b.x == b.y == b.z == 0.0:
            return self.diag.count("rejected_nonfinite", "non-finite or zero magnetic field")
        self._input(1, msg)

    def on_position(self, msg: Odometry):
        p, v = msg.pose.pose.position, msg.twist.twist.linear
        if not c.finite(p.x, p.y, p.z, v.x, v.y, v.z) or p.x == p.y == p.z == 0.0:
            return self.diag.count("rejected_nonfinite", "non-finite or zero position fix")
        self._input(2, msg)

    def on_sun(self, msg: Vector3Stamped):
        u = msg.vector
        n = math.sqrt(u.x * u.x + u.y * u.y + u.z * u.z) if c.finite(u.x, u.y, u.z) else 0.0
        if not abs(n - 1.0) < 1e-3:
            return self.diag.count("rejected_nonfinite", "sun vector not finite and unit")
        ns = c.stamp_to_ns(msg.header.stamp)
        if ns <= self.last_ns:
            return self.diag.count("sun_late", f"sun sample of {ns * 1e-9:.3f} s after that step was estimated")
        self.suns[ns] = np.array([u.x, u.y, u.z])
        while len(self.suns) > 16:
            del self.suns[next(iter(self.suns))]
        if self.pending is not None and self.pending[0] == ns:
            self._process(*self.pending[:2])

    def _input(self, slot, msg):
        ns = c.stamp_to_ns(msg.header.stamp)
        bad = self.gate.check(slot, ns)
        if bad:
            return self.diag.count(*bad)
        group = self.sync.add(slot, ns, msg)
        if group is None:
            return
        if self.pending is not None:  # a newer sample is complete: the pending one goes on without its sun
            self.diag.count("sun_missing", "no sun sample for a step predicted lit")
            self._process(*self.pending[:2])
        if not self.full or ns in self.suns or not self._lit(ns, group[2]):
            return self._process(ns, group)
        self.pending = (ns, group, c.now_wall())

    def _lit(self, ns, pos: Odometry) -> bool:
        p = pos.pose.pose.position
        return bool(illuminated(np.array([p.x, p.y, p.z]), self.models.sun_eci(self._t(ns))))

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
        imu, mag = group[0], group[1]
        t = self._t(ns)
        w, b = imu.angular_velocity, mag.magnetic_field
        r = v = None
        if self.full:
            pp, pv = group[2].pose.pose.position, group[2].twist.twist.linear
            r, v = np.array([pp.x, pp.y, pp.z]), np.array([pv.x, pv.y, pv.z])
        sun = self.suns.pop(ns, None)
        for k in [k for k in self.suns if k < ns]:
            del self.suns[k]
        s_ref = self.models.sun(t, r) if sun is not None else None
        out = self.stream.step(self.w_prev, [b.x, b.y, b.z], self.models.field(t, r), sun, s_ref)
        self.w_prev = np.array([w.x, w.y, w.z])
        self.diag.count("samples")
        if out.state is None:  # before the coarse fix: "no orientation" (the controller commands zero)
            return self.publish_none(ns)
        if out.started:
            self.diag.extra["fixed_at"] = f"{t:.3f}"
        self.diag.count("mag_accepted" if out.mag_accepted else "mag_rejected",
                        None if out.mag_accepted else f"magnetometer innovation gated (NIS {out.nis_mag:.3g})")
        self.diag.extra["nis_mag"] = f"{out.nis_mag:.4g}"
        if out.sun_accepted is not None:
            self.diag.count("sun_accepted" if out.sun_accepted else "sun_rejected",
                            None if out.sun_accepted else f"sun innovation gated (NIS {out.nis_sun:.3g})")
            self.diag.extra["nis_sun"] = f"{out.nis_sun:.4g}"
        self.publish(ns, t, out.state, r, v)

    def publish(self, ns, t, state, r, v):
        m = self.msg
        m.header.stamp = c.ns_to_stamp(ns)
        q = self.models.to_orbital(state.q, t, r, v)
        o = m.orientation
        o.w, o.x, o.y, o.z = (float(x) for x in q)
        m.orientation_covariance = [float(x) for x in state.P[:3, :3].ravel()]
        rate = self.w_prev - state.b
        av = m.angular_velocity
        av.x, av.y, av.z = (float(x) for x in rate)
        m.angular_velocity_covariance = [float(x) for x in (state.P[3:, 3:] + self.suite.gyro.white_std(self.suite.ts) ** 2
                                                             * np.eye(3)).ravel()]
        self.diag.count("estimates")
        self.pub.publish(m)

    def publish_none(self, ns):
        """The sample's message without an estimate: orientation_covariance[0] = -1 (REP-145's
        "not known"), so the lockstep goes on and the controller holds the torquers off."""
        m = self.msg
        m.header.stamp = c.ns_to_stamp(ns)
        m.orientation.w, m.orientation.x, m.orientation.y, m.orientation.z = 1.0, 0.0, 0.0, 0.0
        m.orientation_covariance = [-1.0] + [0.0] * 8
        w = self.w_prev
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = (float(x) for x in w)
        m.angular_velocity_covariance = [-1.0] + [0.0] * 8
        self.pub.publish(m)

    def finish(self):
        if self.context.ok():
            self.diag.publish()


def main(args=None):
    return c.run(AttitudeEstimator, args)


if __name__ == "__main__":
    raise SystemExit(main())
