"""Magnetometer and attitude-state publisher node (truth + sensor models; noise-free by default).

Subscribes:
  sim/truth              nav_msgs/Odometry          attitude q (see simulator.py)
  sim/inertial_rate      geometry_msgs/Vector3Stamped inertial body rate [rad/s], body axes (the gyro's input)
  sim/magnetic_field     sensor_msgs/MagneticField  true body-frame field [T]
  /clock                 rosgraph_msgs/Clock        (use_sim_time)
Publishes (stamp = truth stamp, frame 'body'):
  sensors/magnetic_field sensor_msgs/MagneticField  b_meas = quantize(b + bias + noise) [T];
                         covariance diag(noise_std^2 + quantum^2/12) [T^2]
  sensors/attitude       sensor_msgs/Imu            orientation = attitude of the body w.r.t. the
                         *orbital* (LVLH) axes, perturbed by a small random rotation;
                         angular_velocity = inertial body rate [rad/s] + bias + noise;
                         linear_acceleration not provided (covariance[0] = -1)
  /diagnostics           counters: samples, rejected_nonfinite, rejected_quaternion,
                         rejected_stamp, stale_inputs, unpaired
QoS: magtune_ros.common.LOCKSTEP_QOS. Noise draws use numpy default_rng(seed), only for nonzero
standard deviations, so zero-noise runs pass the truth through bit-for-bit.
"""
from __future__ import annotations

import math

import numpy as np
from geometry_msgs.msg import Vector3Stamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import Imu, MagneticField

from magtune_core.base.rotations import quat_mul
from magtune_core.design.node_params import SENSOR_FIELDS

from . import common as c


class AttitudeSensors(Node):
    NODE_NAME = "attitude_sensors"

    def __init__(self):
        super().__init__(self.NODE_NAME)
        self.done = Future()
        v = c.parse_fields(self, SENSOR_FIELDS)
        ts, seed = v["ts"], v["seed"]
        self.mag_std, self.mag_bias, self.mag_q = v["mag_noise_std"], v["mag_bias"], v["mag_quantum"]
        self.att_std, self.gyro_std, self.gyro_bias = v["attitude_noise_std"], v["gyro_noise_std"], v["gyro_bias"]
        self.rng = np.random.default_rng(seed)
        self.diag = c.Diagnostics(self, ["samples", "rejected_nonfinite", "rejected_quaternion", "rejected_stamp",
                                         "stale_inputs"])
        self.gate = c.StampGate(self, 2 * c.sec_to_ns(ts), n=3)
        self.sync = c.PairSync(3)  # field, truth (attitude), inertial rate: same stamp t_k
        self.pub_mag = self.create_publisher(MagneticField, c.TOPIC_MAG, c.LOCKSTEP_QOS)
        self.pub_att = self.create_publisher(Imu, c.TOPIC_ATTITUDE, c.LOCKSTEP_QOS)
        self.create_subscription(Odometry, c.TOPIC_TRUTH, self.on_truth, c.LOCKSTEP_QOS)
        self.create_subscription(MagneticField, c.TOPIC_TRUE_FIELD, self.on_field, c.LOCKSTEP_QOS)
        self.create_subscription(Vector3Stamped, c.TOPIC_INERTIAL_RATE, self.on_rate, c.LOCKSTEP_QOS)
        self.msg_mag = MagneticField()
        self.msg_mag.header.frame_id = c.FRAME_BODY
        cov = self.mag_std**2 + self.mag_q**2 / 12.0
        self.msg_mag.magnetic_field_covariance = [cov, 0.0, 0.0, 0.0, cov, 0.0, 0.0, 0.0, cov]
        self.msg_att = Imu()
        self.msg_att.header.frame_id = c.FRAME_BODY
        a2, g2 = self.att_std**2, self.gyro_std**2
        self.msg_att.orientation_covariance = [a2, 0.0, 0.0, 0.0, a2, 0.0, 0.0, 0.0, a2]
        self.msg_att.angular_velocity_covariance = [g2, 0.0, 0.0, 0.0, g2, 0.0, 0.0, 0.0, g2]
        self.msg_att.linear_acceleration_covariance[0] = -1.0

    def on_truth(self, msg: Odometry):
        o, w = msg.pose.pose.orientation, msg.twist.twist.angular
        if not c.finite(o.w, o.x, o.y, o.z, w.x, w.y, w.z):
            return self.diag.count("rejected_nonfinite", "non-finite truth state")
        if abs(math.sqrt(o.w * o.w + o.x * o.x + o.y * o.y + o.z * o.z) - 1.0) > 1e-6:
            return self.diag.count("rejected_quaternion", "truth quaternion not unit")
        self._input(1, msg)

    def on_rate(self, msg: Vector3Stamped):
        w = msg.vector
        if not c.finite(w.x, w.y, w.z):
            return self.diag.count("rejected_nonfinite", "non-finite inertial rate")
        self._input(2, msg)

    def on_field(self, msg: MagneticField):
        b = msg.magnetic_field
        if not c.finite(b.x, b.y, b.z):
            return self.diag.count("rejected_nonfinite", "non-finite true field")
        self._input(0, msg)

    def _input(self, slot, msg):
        ns = c.stamp_to_ns(msg.header.stamp)
        bad = self.gate.check(slot, ns)
        if bad:
            return self.diag.count(*bad)
        pair = self.sync.add(slot, ns, msg)
        if pair:
            self.publish(*pair)

    def publish(self, field: MagneticField, truth: Odometry, rate: Vector3Stamped):
        stamp = truth.header.stamp
        b = field.magnetic_field
        bx, by, bz = b.x, b.y, b.z
        if self.mag_std > 0 or np.any(self.mag_bias):
            n = self.rng.normal(0.0, self.mag_std, 3) if self.mag_std > 0 else np.zeros(3)
            bx, by, bz = (float(v) for v in np.array([bx, by, bz]) + self.mag_bias + n)
        if self.mag_q > 0:
            qz = self.mag_q
            bx, by, bz = (round(v / qz) * qz for v in (bx, by, bz))
        m = self.msg_mag
        m.header.stamp = stamp
        m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z = bx, by, bz
        o, w = truth.pose.pose.orientation, rate.vector  # the gyro measures the inertial rate
        a = self.msg_att
        a.header.stamp = stamp
        if self.att_std > 0:  # q_meas = q (x) exp(dtheta / 2), dtheta ~ N(0, std^2 I) in body axes
            th = self.rng.normal(0.0, self.att_std, 3)
            ang = float(np.linalg.norm(th))
            s = math.sin(ang / 2) / ang if ang > 0 else 0.5
            qm = quat_mul([o.w, o.x, o.y, o.z], [math.cos(ang / 2), *(s * th)])
            a.orientation.w, a.orientation.x, a.orientation.y, a.orientation.z = (float(v) for v in qm)
        else:
            a.orientation = o
        if self.gyro_std > 0 or np.any(self.gyro_bias):
            n = self.rng.normal(0.0, self.gyro_std, 3) if self.gyro_std > 0 else np.zeros(3)
            a.angular_velocity.x, a.angular_velocity.y, a.angular_velocity.z = (
                float(v) for v in np.array([w.x, w.y, w.z]) + self.gyro_bias + n)
        else:
            a.angular_velocity = w
        self.diag.count("samples")
        self.pub_mag.publish(m)
        self.pub_att.publish(a)

    def finish(self):
        if self.context.ok():
            self.diag.publish()


def main(args=None):
    return c.run(AttitudeSensors, args)


if __name__ == "__main__":
    raise SystemExit(main())
