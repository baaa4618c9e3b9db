"""Attitude estimator node, managed (lifecycle): raw sensors in, attitude and rate estimate out.

The MEKF of magtune_core.onboard.mekf fed one sample at a time by
magtune_core.onboard.estimator.MekfStream (coarse fix, propagation with the previous gyro sample,
gated magnetometer and sun updates) against the on-board models of
magtune_core.onboard.estimator.OnboardModels: the node only moves messages (docs/estimation.md).
configure validates ESTIMATOR_FIELDS (onboard/params.py) and the spacecraft file and builds
the filter; activate creates the topics below (magtune_ros.lifecycle.ManagedNode).

Subscribes (LOCKSTEP_QOS):
  sensors/imu             sensor_msgs/Imu            gyro rate [rad/s], body axes
  sensors/magnetic_field  sensor_msgs/MagneticField  measured field [T], body axes
  sensors/sun             geometry_msgs/Vector3Stamped measured unit Sun vector (only when valid)
  sensors/position        nav_msgs/Odometry          position fix r [m], v [m/s], ECI (environment 'full')
                          (each taken raw: the serialized bytes, the fields read in place)
  mode                    magtune_interfaces/Mode    the mode manager's (MODE_QOS): the sensor watch runs in POINTING,
                                                     the torquer watch in POINTING and an ACQUISITION after it
  controller/dipole_command geometry_msgs/Vector3Stamped the commanded dipole [A m^2] (raw; the torquer watch's input)
  /clock                  rosgraph_msgs/Clock        (use_sim_time)
Publishes:
  estimate/attitude       sensor_msgs/Imu, frame 'body', stamp = the sample's: orientation = estimated
                          attitude of the body w.r.t. the *orbital* axes (as sensors/attitude, so the
                          controller reads either), orientation_covariance = the MEKF's attitude block
                          [rad^2, body axes]; angular_velocity = gyro minus estimated bias [rad/s] with
                          covariance (sigma_v^2 / ts + bias variance); linear_acceleration_covariance[0] = -1
  /diagnostics            counters: samples, estimates, mag_accepted, mag_rejected, sun_accepted,
                          sun_rejected, sun_missing, sun_late, mag_missing, mag_late, reinitialised, dipole_missing,
                          rejected_nonfinite, rejected_malformed, rejected_stamp, stale_inputs; values nis_mag, nis_sun (last), state, fixed_at
A sample t_k is processed when its gyro, magnetometer (and, full environment, position fix)
messages are in: with its sun message if that arrived, without one if the on-board model puts the
satellite in the Earth's shadow, else after waiting ``sun_wait`` wall seconds (sun_missing); a sun
message of an already processed stamp is dropped (sun_late). A sample whose gyro sample came without its
magnetometer sample (a dropout, or a field rejected as non-finite) is estimated at once on the gyro alone
(and the sun when it comes; mag_missing): attitude_sensors publishes a step's field before its gyro sample,
so once the gyro sample of t_k is in, the field of t_k is not coming (the controller's no_field rule, which
holds after a first complete sample); a field of an already estimated stamp is dropped (mag_late). So the
estimate goes on through a magnetometer gap, the lockstep misses no step, and the mode manager sees the
magnetometer stream lag the estimate's (its staleness rule). Sun sensor loss (onboard.fdir.SunSensorWatch,
``sun_loss_samples`` predicted-lit samples in a row without one): WARN "sun sensor" on /diagnostics at
that sample, and steps no longer wait for it until a sun sample comes again (OK "sun sensor"). The sensor
watch (magnetometer, gyro) and the torquer watch (``torquer_watch``: each sample with the dipole commanded one
period before it, inputs.CommandLag, times the duty cycle's on fraction (TORQUER_FIELDS, the controller's and
simulator's values); ERROR "torquer x|y|z", report only) run on the estimate (docs/modes.md).
Before the coarse fix each sample's message has
orientation_covariance[0] = -1 (unknown; the controller commands zero dipole outside DETUMBLE). With
``validity_gate`` (the full stack, ``magtune sil --modes --attitude estimator``) so does every estimate
that magtune_core.onboard.validity.ValidityMonitor does not call valid (diagnostics values valid,
nis_average): the mode manager reads it as "attitude not known" (docs/modes.md).

The node is on the lockstep's critical path (sensors -> estimator -> controller), so it takes its
inputs serialized (raw) and reads only the fields it uses (raw.raw_imu, raw_magnetic_field,
raw_vector3_stamped, raw_odometry), runs the filter compiled (MekfStream(compiled=True), the same
equations as the core's Python filter within 1e-10 rad) and fills a preallocated message.
"""
from __future__ import annotations

import math

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import Vector3Stamped
from magtune_interfaces.msg import Mode
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from sensor_msgs.msg import Imu, MagneticField

from magtune_core.base.topics import (
    FRAME_BODY,
    TOPIC_DIPOLE,
    TOPIC_ESTIMATE,
    TOPIC_IMU,
    TOPIC_MAG,
    TOPIC_MODE,
    TOPIC_POSITION,
    TOPIC_SUN,
)
from magtune_core.design.params import SpacecraftParams
from magtune_core.onboard.estimator import FilterModel, MekfStream, OnboardModels
from magtune_core.onboard.fdir import BACK, LOST, SunSensorWatch
from magtune_core.onboard.modes import MODES, POINTING
from magtune_core.onboard.params import ESTIMATOR_FIELDS, TORQUER_FIELDS
from magtune_core.onboard.sensor_watch import FAILED, GYRO, SensorWatch, SensorWatchParams
from magtune_core.onboard.torquer_watch import TorquerWatch, TorquerWatchParams, watch_mode
from magtune_core.onboard.torquers import Torquers
from magtune_core.onboard.validity import ValidityMonitor

from .inputs import CommandLag, PairSync, StampGate, finite, now_wall, ns_to_stamp, sec_to_ns
from .lifecycle import ManagedNode
from .main import run
from .params import check_ts, declare_overrides, from_schema, parse_fields
from .qos import LOCKSTEP_QOS, MODE_QOS
from .raw import raw_imu, raw_magnetic_field, raw_odometry, raw_vector3_stamped

#: The estimate's topic (relative): ``magtune sil --attitude estimator`` remaps the controller's
#: sensors/attitude to it.
TOPIC_ESTIMATE = TOPIC_ESTIMATE


def models_from(v: dict, p: SpacecraftParams) -> OnboardModels:
    """The on-board models of the parsed parameters and the spacecraft file."""
    if v["environment"] == "full":
        return OnboardModels("full", p.orbit_config().jd0, int(v["igrf_degree"]))
    return OnboardModels("paper", p.orbit_config().jd0, paper_field=p.field(), orbit_rate=p.orbit_rate)


class AttitudeEstimator(ManagedNode):
    """The attitude_estimator node, managed (lifecycle): the MEKF on sensors/imu, sensors/magnetic_field (full: sensors/sun,
    sensors/position), estimate/attitude out; configure builds the filter, activate creates the topics."""
    NODE_NAME = "attitude_estimator"

    def __init__(self):
        super().__init__(self.NODE_NAME, ["samples", "estimates", "mag_accepted", "mag_rejected", "sun_accepted",
                                          "sun_rejected", "sun_missing", "sun_late", "mag_missing", "mag_late",
                                          "reinitialised", "dipole_missing", "rejected_nonfinite",
                                          "rejected_malformed", "rejected_stamp", "stale_inputs"])
        self.pending = None
        self.create_timer(0.05, self.check_pending, clock=Clock(clock_type=ClockType.STEADY_TIME))

    # ---------------------------------------------------------------- lifecycle
    def configure(self):
        """Validate the parameters and the spacecraft file; build the filter and the on-board models."""
        v = parse_fields(self, ESTIMATOR_FIELDS)
        p = from_schema(self, SpacecraftParams)
        check_ts(v["ts"], p)
        declare_overrides(self)
        self.values, self.full = v, v["environment"] == "full"
        self.model, self.models = FilterModel.from_values(v), models_from(v, p)
        on = Torquers.from_values(parse_fields(self, TORQUER_FIELDS)).on_fraction(self.model.ts)  # a duty cycle
        self.torquer_params = TorquerWatchParams.of_filter(self.model, p.inertia, p.wheel_momentum, p.orbit_rate,
                                                           on_fraction=on)
        self.msg = Imu()
        self.msg.header.frame_id = FRAME_BODY
        self.msg.linear_acceleration_covariance[0] = -1.0
        self.rate_var = self.model.gyro_white_std() ** 2 * np.eye(3)  # the gyro's white part
        self.unknown = np.array([-1.0] + [0.0] * 8)  # REP-145's "not known" covariance

    def activate(self):
        """A fresh filter (an activation restarts from the coarse fix), then the topics."""
        v = self.values
        self.stream = MekfStream(self.model, bias_std=v["initial_bias_std"], gate_probability=v["gate_probability"],
                                 init_angle=v["init_angle"], mag_bias_std=v["initial_mag_bias_std"],
                                 mag_bias_rw=v["mag_bias_rw"], compiled=True)
        self.validity = ValidityMonitor.from_values(v, self.model.ts, self.stream.gate_mag) \
            if v["validity_gate"] else None
        self.ts_ns = sec_to_ns(self.model.ts)
        self.gate = StampGate(self, 2 * self.ts_ns, n=4)
        self.sync = PairSync(3 if self.full else 2)  # imu, mag (, position): same stamp t_k
        self.suns: dict = {}
        self.sun_watch = SunSensorWatch(int(v["sun_loss_samples"]))
        self.sensor_watch = SensorWatch(SensorWatchParams.of_stream(self.stream)) if v["sensor_watch"] else None
        self.torquer_watch = TorquerWatch(self.torquer_params) if v["torquer_watch"] else None
        self.torquer_armed = False  # torquer_watch.watch_mode: armed in POINTING
        self.commands = CommandLag(self.ts_ns)  # each sample with the dipole commanded one period before
        self.last_ns, self.w_prev, self.pending, self.paired = -1, None, None, False
        self.mode = None  # the mode manager's mode (None: no manager; the sensor watch then runs in every state)
        self.data_subscription(Mode, TOPIC_MODE, self.on_mode, MODE_QOS)
        if self.torquer_watch is not None:
            self.data_subscription(Vector3Stamped, TOPIC_DIPOLE, self.on_dipole, LOCKSTEP_QOS, raw=True)
        self.pub = self.data_publisher(Imu, TOPIC_ESTIMATE, LOCKSTEP_QOS)
        self.data_subscription(Imu, TOPIC_IMU, self.on_imu, LOCKSTEP_QOS, raw=True)
        self.data_subscription(MagneticField, TOPIC_MAG, self.on_mag, LOCKSTEP_QOS, raw=True)
        if self.full:
            self.data_subscription(Vector3Stamped, TOPIC_SUN, self.on_sun, LOCKSTEP_QOS, raw=True)
            self.data_subscription(Odometry, TOPIC_POSITION, self.on_position, LOCKSTEP_QOS, raw=True)

    # ---------------------------------------------------------------- inputs (serialized messages)
    def on_mode(self, msg: Mode):
        """The mode manager's mode: the sensor watch watches in POINTING only (unknown ids ignored)."""
        if msg.mode < len(MODES):
            self.mode = MODES[msg.mode]

    def on_dipole(self, data: bytes):
        """controller/dipole_command (raw): kept by stamp for the torquer watch (malformed or non-finite: counted)."""
        f = raw_vector3_stamped(data)
        if f is None:
            return self.diag.count("rejected_malformed", "malformed controller/dipole_command message")
        if not finite(*f[1]):
            return self.diag.count("rejected_nonfinite", "non-finite dipole command")
        self.watch_torquers(self.commands.command(f[0], np.array(f[1])))

    def on_imu(self, data: bytes):
        """sensors/imu (raw bytes): rejects and counts a malformed message or a non-finite gyro rate; else stamp-gated and paired by stamp."""
        f = raw_imu(data)
        if f is None:
            return self.diag.count("rejected_malformed", "malformed sensors/imu message")
        if not finite(*f[2]):
            return self.diag.count("rejected_nonfinite", "non-finite gyro rate")
        self._input(0, f[0], f[2])

    def on_mag(self, data: bytes):
        """sensors/magnetic_field (raw): rejects and counts a malformed message or a non-finite or zero field; else stamp-gated and paired."""
        f = raw_magnetic_field(data)
        if f is None:
            return self.diag.count("rejected_malformed", "malformed sensors/magnetic_field message")
        b = f[1]
        if not finite(*b) or b[0] == b[1] == b[2] == 0.0:
            return self.diag.count("rejected_nonfinite", "non-finite or zero magnetic field")
        self._input(1, f[0], b)

    def on_position(self, data: bytes):
        """sensors/position (raw, full environment): rejects and counts a malformed, non-finite or zero fix; else stamp-gated and paired."""
        f = raw_odometry(data)
        if f is None:
            return self.diag.count("rejected_malformed", "malformed sensors/position message")
        p, v = f[1], f[2]
        if not finite(*p, *v) or p[0] == p[1] == p[2] == 0.0:
            return self.diag.count("rejected_nonfinite", "non-finite or zero position fix")
        self._input(2, f[0], (np.array(p), np.array(v)))

    def on_sun(self, data: bytes):
        """sensors/sun (raw): rejects and counts a malformed or non-unit vector and a sample of a step already estimated (sun_late);
        keeps it by stamp and runs the step that was waiting for it."""
        f = raw_vector3_stamped(data)
        if f is None:
            return self.diag.count("rejected_malformed", "malformed sensors/sun message")
        ns, (x, y, z) = f
        n = math.sqrt(x * x + y * y + z * z) if finite(x, y, z) else 0.0
        if not abs(n - 1.0) < 1e-3:
            return self.diag.count("rejected_nonfinite", "sun vector not finite and unit")
        if ns <= self.last_ns:
            if self.sun_watch.lost:  # a lost sensor's samples come late (no step waits): it is back
                self.sun_watch.lost, self.sun_watch.missing = False, 0
                self.diag.unit_back("sun sensor", "samples again", ns)
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
        if slot == 1 and ns <= self.last_ns:
            return self.diag.count("mag_late", f"field of t={ns * 1e-9:.3f} s came after its step was estimated "
                                               "without it: dropped")
        group = self.sync.add(slot, ns, value)
        if group is None and slot != 1 and self.paired and ns in self.sync.slots[0]:
            group = self.sync.take(ns, missing=1)  # the gyro sample came and its field did not: a dropout
            if group is not None:
                self.diag.count("mag_missing", f"no magnetometer sample of t={ns * 1e-9:.3f} s: gyro propagation only")
        if group is None:
            return
        self.paired = self.paired or group[1] is not None
        if self.pending is not None:  # a newer sample is complete: the pending one goes on without its sun
            self.diag.count("sun_missing", "no sun sample for a step predicted lit")
            self._process(*self.pending[:2])
        if not self.full or ns in self.suns or self.sun_watch.lost or not self.models.lit(self._t(ns), group[2][0]):
            return self._process(ns, group)  # a lost sun sensor: no wait
        self.pending = (ns, group, now_wall())

    def check_pending(self):
        """Steady-time timer (20 Hz): a sample waiting for its sun message more than ``sun_wait`` wall s goes on without it (sun_missing)."""
        if self.data_active and self.pending is not None and now_wall() - self.pending[2] > self.values["sun_wait"]:
            self.diag.count("sun_missing", "no sun sample for a step predicted lit")
            self._process(*self.pending[:2])

    def _t(self, ns: int) -> float:
        return (ns - self.values["time_origin_ns"]) * 1e-9

    # ---------------------------------------------------------------- the step
    def _process(self, ns, group):
        """One MEKF step of sample ``ns`` (onboard.estimator.MekfStream.step) and its estimate."""
        self.pending = None
        self.last_ns = ns
        w, b = group[0], group[1]
        t = self._t(ns)
        r, v = group[2] if self.full else (None, None)
        sun = self.suns.pop(ns, None)
        for k in [k for k in self.suns if k < ns]:
            del self.suns[k]
        s_ref = self.models.sun(t, r) if sun is not None else None
        if self.full:
            self.watch_sun(ns, t, r, sun is not None)
        out = self.stream.step(self.w_prev, b, None if b is None else self.models.field(t, r), sun, s_ref)
        self.w_prev = np.array(w)
        self.diag.count("samples")
        if out.state is None:  # before the coarse fix: "no orientation" (the controller commands zero)
            return self.publish_none(ns)
        if out.started:
            self.diag.extra["fixed_at"] = f"{t:.3f}"
        if out.mag_accepted:
            self.diag.count("mag_accepted")
        elif out.mag_accepted is not None:
            self.diag.count("mag_rejected", f"magnetometer innovation gated (NIS {out.nis_mag:.3g})")
        self.diag.extra["nis_mag"] = f"{out.nis_mag:.4g}"
        if out.sun_accepted is not None:
            if out.sun_accepted:
                self.diag.count("sun_accepted")
            else:
                self.diag.count("sun_rejected", f"sun innovation gated (NIS {out.nis_sun:.3g})")
            self.diag.extra["nis_sun"] = f"{out.nis_sun:.4g}"
        valid = self.validity is None or self.validity.step(out.state.P, out.nis_mag)
        if self.validity is not None:
            self.diag.extra["valid"] = str(valid).lower()
            self.diag.extra["nis_average"] = f"{self.validity.average:.4g}"
            if self.validity.reinit_due:  # not valid for reinit_time: start again from a coarse fix
                self.stream.reset()
                self.validity.reset()
                self.diag.count("reinitialised")
                self.get_logger().info(f"t={t:.1f} s: estimate not valid for {self.values['reinit_time']:g} s: "
                                       "restarting from a coarse fix")
        if self.sensor_watch is not None:
            self.watch_sensors(ns, out, valid)
        q = self.models.to_orbital(out.state.q, t, r, v)
        self.publish(ns, out.state, q, valid)
        if self.torquer_watch is not None:  # after the estimate: the controller waits for it, not for the watch
            watching, self.torquer_armed = watch_mode(self.mode, self.torquer_armed)
            active = valid and watching and b is not None
            self.watch_torquers(self.commands.sample(ns, (self.w_prev - out.state.b, b, q, active)))

    def watch_sensors(self, ns, out, valid: bool):
        """The magnetometer and gyro watch (onboard.sensor_watch.SensorWatch) on this sample (in POINTING, or without a
        mode manager; armed by a valid estimate of a calm body, watch_arm_rate): at a verdict WARN naming the unit,
        stamped with the sample, and its recovery: the unit's bias re-estimated (MekfStream.reopen) and the validity's
        NIS average restarted; OK naming it when back."""
        st, w = out.state, self.w_prev
        calm = math.dist(w, st.b) < self.values["watch_arm_rate"]  # arming needs a calm body (inhibited in a tumble)
        held = self.mode not in (None, POINTING)  # DETUMBLE, ACQUISITION's capture, SAFE: disarmed as by a restart
        verdict = self.sensor_watch.step(out.nis_mag, out.nis_sun, out.sun_accepted, st.b, st.P[3:6, 3:6],
                                         valid and (calm or self.sensor_watch.armed), out.started or held)
        if verdict is None:
            return
        text = verdict.message.removeprefix(f"{verdict.unit}: ")
        if verdict.status != FAILED:
            return self.diag.unit_back(verdict.unit, text, ns)
        v = self.values
        std = v["recover_gyro_bias_std"] if verdict.unit == GYRO else v["recover_mag_bias_std"]
        self.stream.reopen(verdict.unit, std, v["recover_attitude_std"])
        if self.validity is not None and std > 0:
            self.validity.forgive()
        self.diag.unit_fault(verdict.unit, text + ("; re-estimating its bias" if std > 0 else ""), ns)

    def watch_torquers(self, ready: list):
        """The torquer watch (onboard.torquer_watch.TorquerWatch) on each ready sample (inputs.CommandLag: its
        gyro minus the estimated bias, measured field and attitude w.r.t. the orbital axes, with the dipole
        commanded for the period that ended at it; no command: the window restarts, counted). Active on a valid
        estimate in the modes of onboard.torquer_watch.watch_mode: POINTING, and an ACQUISITION after it (a stuck
        torquer can take POINTING to ACQUISITION before its window isolates it), not the capture after DETUMBLE.
        A verdict: ERROR naming the torquer, stamped with its sample; reported only
        (docs/modes.md#torquer-fault-detection)."""
        for ns, (w, b, q, active), m in ready:
            if m is None and active and self.commands.missed(ns):
                self.diag.count("dipole_missing", f"no dipole command for t={ns * 1e-9:.3f} s: the torquer watch restarts")
            verdict = self.torquer_watch.step(w, b, m if m is not None else np.zeros(3), q, active and m is not None)
            if verdict is not None:
                self.diag.unit_fault(verdict.unit, verdict.detail.removeprefix(f"{verdict.unit}: "), ns,
                                     level=DiagnosticStatus.ERROR)

    def watch_sun(self, ns, t, r, have_sun: bool):
        """The sun sensor's watch (onboard.fdir.SunSensorWatch) on this sample: WARN 'sun sensor' at the sample
        its loss is detected, OK when it is back (both stamped with the sample)."""
        verdict = self.sun_watch.step(self.models.lit(t, r), have_sun)
        if verdict == LOST:
            self.diag.unit_fault("sun sensor", f"lost: no sample for {self.sun_watch.loss_samples} steps predicted "
                                               "lit; estimating on magnetometer and gyro", ns)
        elif verdict == BACK:
            self.diag.unit_back("sun sensor", "samples again", ns)

    def publish(self, ns, state, q, valid=True):
        """Publish estimate/attitude of sample ``ns``: the attitude ``q`` w.r.t. the orbital axes with the MEKF's covariance
        (not ``valid``: the estimate with orientation_covariance[0] = -1), gyro rate minus the estimated bias."""
        m = self.msg
        m.header.stamp = ns_to_stamp(ns)
        o = m.orientation
        o.w, o.x, o.y, o.z = float(q[0]), float(q[1]), float(q[2]), float(q[3])
        P = state.P
        # a float64 (9,) copy: rclpy takes it as is; not valid (validity_gate): REP-145's "not known"
        m.orientation_covariance = P[:3, :3].ravel() if valid else self.unknown.copy()
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
        m.header.stamp = ns_to_stamp(ns)
        m.orientation.w, m.orientation.x, m.orientation.y, m.orientation.z = 1.0, 0.0, 0.0, 0.0
        m.orientation_covariance = self.unknown.copy()
        w = self.w_prev
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = (float(x) for x in w)
        m.angular_velocity_covariance = self.unknown.copy()
        self.pub.publish(m)


def main(args=None):
    """Entry point of the attitude_estimator node (console script): run(AttitudeEstimator)'s exit status."""
    return run(AttitudeEstimator, args)


if __name__ == "__main__":
    raise SystemExit(main())
