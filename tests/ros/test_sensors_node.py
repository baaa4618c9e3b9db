"""The attitude_sensors node's raw outputs over real DDS (separate processes, recorded in a bag):
standard messages with covariances, sim-time stamps, the same numbers as the core models
(magtune_core.design.sensors) for the same seed, no sun vector in eclipse, bad parameter = exit 2.

run_sil isolates the run (DomainLock: its own ROS_DOMAIN_ID, LOCALHOST discovery) and stops
every process in ``finally``; the executable test below uses the same lock and child env.
"""
from __future__ import annotations

import subprocess

import numpy as np
import pytest

from magtune_core import bags as baglib
from magtune_core.bags.decode import Decoder, stamp_ns
from magtune_core.base.schema import parse
from magtune_core.design import sensors as sm
from magtune_core.design.node_params import SENSOR_FIELDS
from magtune_core.ros import process, sil

pytestmark = pytest.mark.ros
TS, STEPS = 5.0, 450  # 2250 s of the default orbit: lit until 1720 s, then in the Earth's shadow
NOISE = dict(mag_noise_std=1e-7, mag_bias=[1e-7, 0.0, -2e-7], gyro_arw=1e-5, gyro_rrw=1e-7,
             gyro_bias=[1e-4, 0.0, -1e-4], sun_noise_std=0.01, position_noise_std=10.0, velocity_noise_std=0.1,
             seed=4)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """One full-environment SIL run with noisy sensors, every topic recorded, decoded by stamp."""
    tmp = tmp_path_factory.mktemp("sensors")
    bag = tmp / "bag"
    run = sil.run_sil("config/gains/sigma_120.yaml", steps=STEPS, ts=TS, environment="full", log_dir=tmp / "logs",
                      bag=bag, sensor_params=NOISE, timeout=180)
    dec = Decoder()
    topics: dict = {}
    diags = []
    for msg in baglib.iter_messages(bag):
        o = dec.decode(msg.data, msg.type)
        if msg.topic == "/diagnostics":
            diags += [{v.key: v.value for v in st.values} for st in o.status if st.name.endswith("attitude_sensors")]
        elif msg.topic.startswith(("/sensors/", "/sim/")):
            topics.setdefault(msg.topic, {})[stamp_ns(o)] = o
    return run, topics, diags


def _vec(v):
    return [v.x, v.y, v.z]


def test_standard_messages_with_covariances_in_sim_time(recorded):
    run, topics, _ = recorded
    suite = sm.SensorSuite.from_values(parse(NOISE | {"ts": TS}, SENSOR_FIELDS, "test"))
    stamps = [int(round(k * TS * 1e9)) for k in range(STEPS + 1)]  # sim time t_k = k Ts from 0
    for name in ("/sensors/imu", "/sensors/magnetic_field", "/sensors/attitude", "/sensors/position"):
        assert sorted(topics[name]) == stamps, name
    imu = topics["/sensors/imu"][stamps[3]]
    assert imu.header.frame_id == "body" and imu.orientation_covariance[0] == -1.0
    assert imu.linear_acceleration_covariance[0] == -1.0
    g2 = suite.gyro.white_std(TS) ** 2  # sigma_v^2/Ts + sigma_u^2 Ts/12
    assert np.allclose(np.reshape(imu.angular_velocity_covariance, (3, 3)), np.eye(3) * g2, rtol=1e-15, atol=0)
    mag = topics["/sensors/magnetic_field"][stamps[3]]
    assert np.allclose(np.reshape(mag.magnetic_field_covariance, (3, 3)), np.eye(3) * 1e-14, rtol=1e-15, atol=0)
    pos = topics["/sensors/position"][stamps[3]]
    assert pos.header.frame_id == pos.child_frame_id == "eci"
    assert np.allclose(np.diag(np.reshape(pos.pose.covariance, (6, 6))), [100.0] * 3 + [-1.0] * 3)
    assert np.allclose(np.diag(np.reshape(pos.twist.covariance, (6, 6))), [0.01] * 3 + [-1.0] * 3)
    sun = next(iter(topics["/sensors/sun"].values()))
    assert sun.header.frame_id == "body" and abs(np.linalg.norm(_vec(sun.vector)) - 1.0) < 1e-15


def test_node_measurements_are_the_core_models_for_the_seed(recorded):
    """The node's gyro, magnetometer and attitude equal design.sensors on the recorded truth with
    the seed's rows of normals; sun and position with the auxiliary generator's rows."""
    _, topics, _ = recorded
    suite = sm.SensorSuite.from_values(parse(NOISE | {"ts": TS}, SENSOR_FIELDS, "test"))
    ks = sorted(topics["/sim/inertial_rate"])
    rows = sm.draw(np.random.default_rng(NOISE["seed"]), len(ks))
    w = np.array([_vec(topics["/sim/inertial_rate"][k].vector) for k in ks])
    b = np.array([_vec(topics["/sim/magnetic_field"][k].magnetic_field) for k in ks])
    wm, _ = sm.gyro(suite.gyro, w, TS, suite.gyro.bias, rows[:, sm.GYRO_V], rows[:, sm.GYRO_U])
    assert np.array_equal(np.array([_vec(topics["/sensors/imu"][k].angular_velocity) for k in ks]), wm)
    assert np.array_equal(np.array([_vec(topics["/sensors/attitude"][k].angular_velocity) for k in ks]), wm)
    bm = sm.magnetometer(suite.magnetometer, b, rows[:, sm.MAG])
    assert np.array_equal(np.array([_vec(topics["/sensors/magnetic_field"][k].magnetic_field) for k in ks]), bm)
    aux = sm.draw(sm.aux_rng(NOISE["seed"]), len(ks), sm.AUX_NORMALS)
    r = np.array([[o.pose.pose.position.x, o.pose.pose.position.y, o.pose.pose.position.z]
                  for o in (topics["/sim/orbit"][k] for k in ks)])
    v = np.array([_vec(topics["/sim/orbit"][k].twist.twist.linear) for k in ks])
    rm, _ = sm.position_fix(suite.position, r, v, aux[:, sm.FIX])
    got = np.array([[p.x, p.y, p.z] for p in (topics["/sensors/position"][k].pose.pose.position for k in ks)])
    assert np.array_equal(got, rm) and 1.0 < np.std(got - r) < 100.0  # 10 m noise on the truth


def test_no_sun_vector_in_eclipse(recorded):
    """sensors/sun is published exactly at the lit samples of the environment's shadow model, and
    the measured vector is within a few noise std of the true direction; eclipses are counted."""
    _, topics, diags = recorded
    ks = sorted(topics["/sim/orbit"])
    r = np.array([[o.pose.pose.position.x, o.pose.pose.position.y, o.pose.pose.position.z]
                  for o in (topics["/sim/orbit"][k] for k in ks)])
    v = np.array([_vec(topics["/sim/orbit"][k].twist.twist.linear) for k in ks])
    sun = np.array([_vec(topics["/sim/sun"][k].vector) for k in ks])
    lit = sm.illuminated(r, sun)
    assert 0 < lit.sum() < len(ks)  # the run crosses the shadow boundary
    assert sorted(topics["/sensors/sun"]) == [k for k, ok in zip(ks, lit) if ok]
    q = np.array([[o.pose.pose.orientation.w, o.pose.pose.orientation.x, o.pose.pose.orientation.y,
                   o.pose.pose.orientation.z] for o in (topics["/sim/truth"][k] for k in ks)])
    s_true = sm.sun_direction_body(q, r, v, sun)[lit]
    s_meas = np.array([_vec(topics["/sensors/sun"][k].vector) for k in sorted(topics["/sensors/sun"])])
    ang = np.arccos(np.clip(np.sum(s_true * s_meas, axis=-1), -1.0, 1.0))
    # angle error ~ 0.01 rad x sqrt(chi2(2)): RMS sqrt(2) x 0.01; 5.5 sigma x 0.01 bounds the max over 345
    assert 0.01 < np.sqrt(np.mean(ang**2)) < 0.02 and np.max(ang) < 0.055
    last = diags[-1]
    assert int(last["sun_eclipse"]) > 0 and int(last["sun_out_of_fov"]) == 0


@pytest.mark.parametrize("arg, name", [("gyro_rrw:=1.0", "gyro_rrw"), ("sun_boresight:=[0.0, 0.0, 0.0]",
                                                                      "sun_boresight")])
def test_bad_sensor_parameter_exits_2_with_one_line(arg, name):
    exe = process.resolve_executable("attitude_sensors")
    with process.DomainLock() as lock:
        env = process.child_env(lock.domain_id, process.package_prefix())
        r = subprocess.run([str(exe), "--ros-args", "-p", arg], env=env, capture_output=True, text=True, timeout=30)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and name in lines[0], r.stderr


def test_sun_input_refuses_zero_nonfinite_and_malformed(domain, built_package):
    """The node's sim/sun callback (in this process, configured and active on its own domain): a zero or
    non-finite Sun position counts rejected_nonfinite and a byte string that is not a Vector3Stamped
    rejected_malformed, neither reaching the pairing; a good one is stamp-gated and paired (no count)."""
    import rclpy
    from geometry_msgs.msg import Vector3Stamped
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    from rclpy.serialization import serialize_message

    from magtune_ros.attitude_sensors import AttitudeSensors

    def sun(stamp, x, y, z):
        m = Vector3Stamped()
        m.header.stamp = stamp
        m.vector.x, m.vector.y, m.vector.z = x, y, z
        return serialize_message(m)

    rclpy.init(domain_id=domain)
    try:
        node = AttitudeSensors()
        (srv,) = [s for s in node.services if s.srv_type is ChangeState]
        for tid in (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
            assert srv.callback(ChangeState.Request(transition=Transition(id=tid)), ChangeState.Response()).success
        counts = node.diag.counts
        now = node.get_clock().now().to_msg()  # the node's clock (no /clock here: wall time), within the gate's age limit
        node.on_sun(sun(now, 0.0, 0.0, 0.0))
        node.on_sun(sun(now, float("nan"), 1.0, 0.0))
        node.on_sun(b"\x00\x01\x00\x00\x07")
        assert counts["rejected_nonfinite"] == 2 and counts["rejected_malformed"] == 1
        # had either passed the stamp gate, the good sample of the same stamp would count as a duplicate
        node.on_sun(sun(now, 1.5e11, 0.0, 0.0))
        node.on_sun(sun(now, 1.5e11, 0.0, 0.0))  # ... as this repeat does
        assert counts["rejected_nonfinite"] == 2 and counts["rejected_malformed"] == 1 and counts["rejected_stamp"] == 1
        node.destroy_node()
    finally:
        rclpy.shutdown()
