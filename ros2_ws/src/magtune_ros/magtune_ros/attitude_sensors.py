"""Sensors node, managed (lifecycle): truth in, raw and controller measurements out (models:
magtune_core.design.sensors). configure loads and validates the parameters and builds the models;
activate seeds the noise and creates the topics below (magtune_ros.lifecycle.ManagedNode).

Subscribes:
  sim/truth              nav_msgs/Odometry          attitude q (see simulator.py)
  sim/inertial_rate      geometry_msgs/Vector3Stamped inertial body rate [rad/s], body axes (the gyro's input)
  sim/magnetic_field     sensor_msgs/MagneticField  true body-frame field [T]
  sim/torquer_field      sensor_msgs/MagneticField  the torquers' field at the magnetometer [T] (only with a
                         nonzero torquer_coupling, TORQUER_FIELDS: the magnetometer then reads b + this)
  sim/orbit, sim/sun     nav_msgs/Odometry, geometry_msgs/Vector3Stamped: r, v and the Sun in ECI
                         (environment 'full' only; without them no sun sensor and no position fix)
  /clock                 rosgraph_msgs/Clock        (use_sim_time)
Publishes (stamp = truth stamp):
  sensors/magnetic_field sensor_msgs/MagneticField, frame 'body': b_m = quantize(M b + bias + noise) [T];
                         covariance diag(noise_std^2 + quantum^2/12) [T^2]
  sensors/imu            sensor_msgs/Imu, frame 'body': the Farrenkopf gyro's rate [rad/s] and the
                         covariance of its white part; orientation_covariance[0] = -1 (no
                         orientation), linear_acceleration_covariance[0] = -1
  sensors/attitude       sensor_msgs/Imu, frame 'body': what the controller reads; orientation = attitude
                         of the body w.r.t. the *orbital* (LVLH) axes, perturbed by a small random
                         rotation (attitude_noise_std); angular_velocity = the gyro of sensors/imu
  sensors/sun            geometry_msgs/Vector3Stamped, frame 'body': measured unit satellite->Sun vector;
                         not published in eclipse or outside the field of view (counters sun_eclipse,
                         sun_out_of_fov); covariance sun_noise_std^2 (I - s s^T), not carried
  sensors/position       nav_msgs/Odometry, frame and child 'eci': position fix r [m] and v [m/s] with
                         pose/twist covariance diag(std^2) (rotational entries -1: not measured)
  /diagnostics           counters: samples, rejected_malformed, rejected_nonfinite, rejected_quaternion,
                         rejected_stamp, stale_inputs, sun_samples, sun_eclipse, sun_out_of_fov, faulted_samples, mag_dropped
Faults (parameter ``faults``, magtune_core.design.faults): the magnetometer and gyro faults act on
the samples of their sim time (``faults.measure``); a dropped magnetometer sample is not published,
nor a sun sample while ``sun_loss`` acts (``faults.sun_lost``).
The inputs are taken serialized (raw subscriptions) and only the fields used are read (magtune_ros.raw):
building a nav_msgs/Odometry costs 0.13-0.15 ms, more than this node's models (bench/sil_hops.py).
QoS: magtune_ros.qos.LOCKSTEP_QOS. Noise: one row of design.sensors.NORMALS_PER_STEP standard
normals per sample from numpy default_rng(seed), drawn only when some noise or bias is set (so
zero-noise runs pass the truth through bit for bit); sun and position from sensors.aux_rng(seed).
"""
from __future__ import annotations

import math

import numpy as np
from geometry_msgs.msg import Vector3Stamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu, MagneticField

from magtune_core.base.errors import ConfigError
from magtune_core.base.topics import (
    FRAME_BODY,
    FRAME_ECI,
    TOPIC_ATTITUDE,
    TOPIC_IMU,
    TOPIC_INERTIAL_RATE,
    TOPIC_MAG,
    TOPIC_ORBIT,
    TOPIC_POSITION,
    TOPIC_SUN,
    TOPIC_TORQUER_FIELD,
    TOPIC_TRUE_FIELD,
    TOPIC_TRUE_SUN,
    TOPIC_TRUTH,
)
from magtune_core.design import faults as fl
from magtune_core.design import sensors as s
from magtune_core.design.node_params import FAULTS, SENSOR_FIELDS, check_sensors
from magtune_core.onboard.params import TORQUER_FIELDS
from magtune_core.onboard.torquers import Torquers

from .inputs import PairSync, StampGate, finite, ns_to_stamp, sec_to_ns
from .lifecycle import ManagedNode
from .main import run
from .params import check, param_error, parse_fields
from .qos import LOCKSTEP_QOS
from .raw import raw_magnetic_field, raw_odometry, raw_odometry_attitude, raw_vector3_stamped


def _cov3(var: float) -> list:
    return [var, 0.0, 0.0, 0.0, var, 0.0, 0.0, 0.0, var]


class AttitudeSensors(ManagedNode):
    """The attitude_sensors node, managed (lifecycle): the simulator's sim/* truth in, the noisy sensors/* measurements of each t_k out;
    configure builds the sensor models, activate seeds the noise and creates the topics."""
    NODE_NAME = "attitude_sensors"

    def __init__(self):
        super().__init__(self.NODE_NAME, ["samples", "rejected_malformed", "rejected_nonfinite", "rejected_quaternion", "rejected_stamp",
                                          "stale_inputs", "sun_samples", "sun_eclipse", "sun_out_of_fov", "faulted_samples",
                                          "mag_dropped"])

    # ---------------------------------------------------------------- lifecycle
    def configure(self):
        """Load and validate the sensor parameters; build the sensor models (design.sensors)."""
        v = parse_fields(self, SENSOR_FIELDS)
        check(check_sensors, v, self)
        self.values = v
        self.suite = s.SensorSuite.from_values(v)
        self.coupled = Torquers.from_values(parse_fields(self, TORQUER_FIELDS)).coupled
        try:
            self.faults = fl.from_list(parse_fields(self, (FAULTS,))["faults"], "faults")
        except ConfigError as exc:
            raise param_error(exc) from None
        self.make_messages()

    def activate(self):
        """Noise generators from the seed (an activation replays the same noise), input state, then
        the publishers and the subscriptions to the simulator's truth."""
        v = self.values
        self.rng, self.aux = np.random.default_rng(v["seed"]), s.aux_rng(v["seed"])
        self.beta = np.asarray(self.suite.gyro.bias, dtype=float)  # gyro bias before the next sample
        self.fault_state = fl.FaultState()
        self.gate = StampGate(self, 2 * sec_to_ns(self.suite.ts), n=6)
        # field, truth (attitude), inertial rate (and the torquers' field when coupled): same stamp t_k
        self.sync = PairSync(4 if self.coupled else 3)
        self.sync_orbit = PairSync(3)  # truth, orbit, Sun (full environment)
        self.pub_mag = self.data_publisher(MagneticField, TOPIC_MAG, LOCKSTEP_QOS)
        self.pub_imu = self.data_publisher(Imu, TOPIC_IMU, LOCKSTEP_QOS)
        self.pub_att = self.data_publisher(Imu, TOPIC_ATTITUDE, LOCKSTEP_QOS)
        self.pub_sun = self.data_publisher(Vector3Stamped, TOPIC_SUN, LOCKSTEP_QOS)
        self.pub_pos = self.data_publisher(Odometry, TOPIC_POSITION, LOCKSTEP_QOS)
        self.data_subscription(Odometry, TOPIC_TRUTH, self.on_truth, LOCKSTEP_QOS, raw=True)
        self.data_subscription(MagneticField, TOPIC_TRUE_FIELD, self.on_field, LOCKSTEP_QOS, raw=True)
        self.data_subscription(Vector3Stamped, TOPIC_INERTIAL_RATE, self.on_rate, LOCKSTEP_QOS, raw=True)
        self.data_subscription(Odometry, TOPIC_ORBIT, self.on_orbit, LOCKSTEP_QOS, raw=True)
        self.data_subscription(Vector3Stamped, TOPIC_TRUE_SUN, self.on_sun, LOCKSTEP_QOS, raw=True)
        if self.coupled:
            self.data_subscription(MagneticField, TOPIC_TORQUER_FIELD, self.on_torquer_field, LOCKSTEP_QOS, raw=True)

    def make_messages(self):
        """Preallocated messages with their frames and (constant) covariances."""
        su = self.suite
        self.msg_mag = MagneticField()
        self.msg_mag.header.frame_id = FRAME_BODY
        self.msg_mag.magnetic_field_covariance = su.magnetometer.covariance.ravel().tolist()
        g2 = su.gyro.white_std(su.ts) ** 2
        self.msg_imu, self.msg_att = Imu(), Imu()
        for m in (self.msg_imu, self.msg_att):
            m.header.frame_id = FRAME_BODY
            m.angular_velocity_covariance = _cov3(g2)
            m.linear_acceleration_covariance[0] = -1.0
        self.msg_imu.orientation_covariance[0] = -1.0
        self.msg_att.orientation_covariance = _cov3(su.attitude_std**2)
        self.msg_sun = Vector3Stamped()
        self.msg_sun.header.frame_id = FRAME_BODY
        self.msg_pos = Odometry()
        self.msg_pos.header.frame_id = self.msg_pos.child_frame_id = FRAME_ECI
        p2, v2 = su.position.noise_std**2, su.position.velocity_noise_std**2
        self.msg_pos.pose.covariance = np.diag([p2, p2, p2, -1.0, -1.0, -1.0]).ravel().tolist()
        self.msg_pos.twist.covariance = np.diag([v2, v2, v2, -1.0, -1.0, -1.0]).ravel().tolist()

    # ---------------------------------------------------------------- inputs
    def on_truth(self, data: bytes):
        """sim/truth (raw): rejects and counts a malformed message, a non-finite state or a non-unit quaternion; else
        stamp-gated and paired for both measurement sets."""
        f = raw_odometry_attitude(data)
        if f is None:
            return self.diag.count("rejected_malformed", "malformed sim/truth message")
        ns, q, w = f
        if not finite(*q, *w):
            return self.diag.count("rejected_nonfinite", "non-finite truth state")
        if abs(math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) - 1.0) > 1e-6:
            return self.diag.count("rejected_quaternion", "truth quaternion not unit")
        if self._accept(1, ns):
            self._pair(self.sync, 1, ns, q, self.publish)
            self._pair(self.sync_orbit, 0, ns, q, self.publish_orbit)

    def on_rate(self, data: bytes):
        """sim/inertial_rate (raw; the gyro's input): rejects and counts a malformed message or a non-finite rate; else stamp-gated
        and paired by stamp."""
        self._vector(data, 2, self.sync, 2, self.publish, "inertial rate")

    def on_field(self, data: bytes):
        """sim/magnetic_field (raw; the magnetometer's input): rejects and counts a malformed message or a non-finite field; else
        stamp-gated and paired by stamp."""
        self._vector(data, 0, self.sync, 0, self.publish, "true field", raw_magnetic_field)

    def on_torquer_field(self, data: bytes):
        """sim/torquer_field (raw; coupled torquers only): rejects and counts a malformed message or a non-finite field; else
        stamp-gated and paired, added to the field the magnetometer reads."""
        self._vector(data, 5, self.sync, 3, self.publish, "torquer field", raw_magnetic_field)

    def on_orbit(self, data: bytes):
        """sim/orbit (raw; full environment): rejects and counts a malformed message or a non-finite r, v; else stamp-gated and
        paired with truth and Sun for the sun sensor and the position fix."""
        f = raw_odometry(data)
        if f is None:
            return self.diag.count("rejected_malformed", "malformed sim/orbit message")
        ns, r, v = f
        if not finite(*r, *v):
            return self.diag.count("rejected_nonfinite", "non-finite orbit state")
        if self._accept(3, ns):
            self._pair(self.sync_orbit, 1, ns, (r, v), self.publish_orbit)

    def on_sun(self, data: bytes):
        """sim/sun (raw; full environment): rejects and counts a malformed message or a non-finite or zero Sun position; else
        stamp-gated and paired with truth and orbit."""
        self._vector(data, 4, self.sync_orbit, 2, self.publish_orbit, "Sun position", reject_zero=True)

    def _vector(self, data, gate_slot, sync, slot, then, what, reader=raw_vector3_stamped, reject_zero=False):
        """A stamped 3-vector input: malformed or non-finite (or zero, with ``reject_zero``) counted, else stamp-gated and
        paired."""
        f = reader(data)
        if f is None:
            return self.diag.count("rejected_malformed", f"malformed {what} message")
        ns, u = f
        if not finite(*u) or (reject_zero and u == (0.0, 0.0, 0.0)):
            return self.diag.count("rejected_nonfinite", f"non-finite or zero {what}" if reject_zero else f"non-finite {what}")
        if self._accept(gate_slot, ns):
            self._pair(sync, slot, ns, u, then)

    def _accept(self, slot, ns: int) -> bool:
        bad = self.gate.check(slot, ns)
        if bad:
            self.diag.count(*bad)
        return not bad

    @staticmethod
    def _pair(sync, slot, ns, value, then):
        pair = sync.add(slot, ns, value)
        if pair:
            then(ns, *pair)

    # ---------------------------------------------------------------- outputs
    def publish(self, ns: int, field, q_true, rate, torquer=None):
        """Magnetometer, gyro and attitude of t_k = ``ns`` from the true field, attitude (w, x, y, z) and inertial rate (one row
        of normals when anything is noisy)."""
        su, stamp = self.suite, ns_to_stamp(ns)
        n = s.draw(self.rng) if su.noisy else np.zeros(s.NORMALS_PER_STEP)
        b_at = np.array(field)
        if torquer is not None:  # the field at the magnetometer: the geomagnetic one plus the torquers'
            b_at = b_at + np.array(torquer)
        b = s.magnetometer(su.magnetometer, b_at, n[s.MAG])
        wm, beta = s.gyro(su.gyro, [rate], su.ts, self.beta, n[None, s.GYRO_V], n[None, s.GYRO_U])
        self.beta = beta[-1]
        q = s.noisy_attitude(list(q_true), su.attitude_std, n[s.ATT])
        w_out = wm[0]
        if self.faults:
            b0, w0 = b, w_out
            b, w_out, self.fault_state = fl.measure(self.faults, ns * 1e-9, su.ts, b, w_out, self.fault_state)
            if b is None or np.any(b != b0) or np.any(w_out != w0):
                self.diag.count("faulted_samples")
        m, imu, att = self.msg_mag, self.msg_imu, self.msg_att
        m.header.stamp = imu.header.stamp = att.header.stamp = stamp
        if b is not None:
            m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z = (float(x) for x in b)
        r = imu.angular_velocity
        r.x, r.y, r.z = (float(x) for x in w_out)
        att.angular_velocity = r
        a = att.orientation
        a.w, a.x, a.y, a.z = (float(x) for x in q)
        self.diag.count("samples")
        if b is not None:
            self.pub_mag.publish(m)
        else:  # a magnetometer dropout: no message
            self.diag.count("mag_dropped")
        self.pub_att.publish(att)
        self.pub_imu.publish(imu)

    def publish_orbit(self, ns: int, q_true, orbit, sun):
        """Sun sensor (when lit and in view) and position fix of t_k = ``ns`` from the true attitude, orbit (r, v) and Sun (ECI)."""
        su, stamp = self.suite, ns_to_stamp(ns)
        r, vel, sun_eci = np.array(orbit[0]), np.array(orbit[1]), np.array(sun)
        n = s.draw(self.aux, width=s.AUX_NORMALS)
        s_true = s.sun_direction_body(list(q_true), r, vel, sun_eci)
        lit = s.illuminated(r, sun_eci)
        s_m, valid, _ = s.sun_sensor(su.sun, s_true, lit, n[s.SUN])
        rm, vm = s.position_fix(su.position, r, vel, n[s.FIX])
        pos = self.msg_pos
        pos.header.stamp = stamp
        pp, pv = pos.pose.pose.position, pos.twist.twist.linear
        pp.x, pp.y, pp.z = (float(x) for x in rm)
        pv.x, pv.y, pv.z = (float(x) for x in vm)
        self.pub_pos.publish(pos)
        if not valid:
            return self.diag.count("sun_out_of_fov" if lit else "sun_eclipse")
        if self.faults and fl.sun_lost(self.faults, ns * 1e-9):  # injected: nothing comes out
            return self.diag.count("faulted_samples")
        m = self.msg_sun
        m.header.stamp = stamp
        m.vector.x, m.vector.y, m.vector.z = (float(x) for x in s_m)
        self.diag.count("sun_samples")
        self.pub_sun.publish(m)


def main(args=None):
    """Entry point of the attitude_sensors node (console script): run(AttitudeSensors)'s exit status."""
    return run(AttitudeSensors, args)


if __name__ == "__main__":
    raise SystemExit(main())
