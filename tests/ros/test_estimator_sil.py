"""The attitude_estimator node in the SIL (``magtune sil --attitude estimator``): its output is
the core's MEKF (onboard.estimator.MekfStream, what run_mekf runs) on the recorded raw sensor
messages, its error stays inside its 3-sigma bounds, a bad parameter is one line and exit 2."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from magtune_core import bags as baglib
from magtune_core.bags.decode import Decoder, stamp_ns
from magtune_core.base.schema import parse
from magtune_core.design.params import load_spacecraft
from magtune_core.onboard.estimator import FilterModel, MekfStream
from magtune_core.onboard.mekf import attitude_error
from magtune_core.onboard.params import ESTIMATOR_FIELDS
from magtune_core.ros import process

pytestmark = pytest.mark.ros
ORBITS = 0.2  # the shared flight's first 1123 steps of 1 s, all lit (eclipse from 1720 s): the fix at t = 0


@pytest.fixture(scope="module")
def recorded(estimator_flight):
    """The shared full-environment SIL run flying on the estimator (tests/ros/conftest.py), its first 0.2 orbit
    decoded by stamp: the lit part, where no sun sample meets a shadow boundary."""
    bag, period = estimator_flight
    end_ns = int(ORBITS * period * 1e9)
    dec, topics = Decoder(), {}
    for msg in baglib.iter_messages(bag):
        if msg.topic.startswith(("/sensors/", "/sim/truth", "/estimate/")):
            o = dec.decode(msg.data, msg.type)
            if stamp_ns(o) <= end_ns:
                topics.setdefault(msg.topic, {})[stamp_ns(o)] = o
    return topics


def _v(v):
    return np.array([v.x, v.y, v.z])


def _q(o):
    return np.array([o.w, o.x, o.y, o.z])


def test_node_output_is_the_core_estimator_on_the_recorded_measurements(recorded):
    """Replay: the node's own functions (models_from, FilterModel.from_values, MekfStream) on the bag's raw
    messages. Same float64 inputs and arithmetic: equal to 1e-9 rad / 1e-12 (round-off of the
    frame change; one sun sample arriving late at a shadow boundary would show as a difference,
    none in this lit run)."""
    sys.path.insert(0, "ros2_ws/src/magtune_ros")
    from magtune_ros.attitude_estimator import models_from  # rclpy: built package

    v = parse({"environment": "full"}, ESTIMATOR_FIELDS, "test")
    models, stream = models_from(v, load_spacecraft("config/spacecraft.yaml")), MekfStream(FilterModel.from_values(v))
    est, imu, mag, sun, pos = (recorded[t] for t in ("/estimate/attitude", "/sensors/imu", "/sensors/magnetic_field",
                                                     "/sensors/sun", "/sensors/position"))
    # every sample estimated (the last one may end with the run before the recorder has it)
    assert set(est) <= set(imu) == set(mag) and len(est) >= len(imu) - 1 > 1000
    w_prev, worst_q, worst_p = None, 0.0, 0.0
    for ns in sorted(imu):
        t = ns * 1e-9
        r, vel = _v(pos[ns].pose.pose.position), _v(pos[ns].twist.twist.linear)
        s = _v(sun[ns].vector) if ns in sun else None
        out = stream.step(w_prev, _v(mag[ns].magnetic_field), models.field(t, r), s,
                          models.sun(t, r) if s is not None else None)
        w_prev = _v(imu[ns].angular_velocity)
        q = models.to_orbital(out.state.q, t, r, vel)
        if ns not in est:
            continue
        m = est[ns]
        worst_q = max(worst_q, float(np.linalg.norm(attitude_error(q, _q(m.orientation)))))
        worst_p = max(worst_p, float(np.max(np.abs(np.reshape(m.orientation_covariance, (3, 3)) - out.state.P[:3, :3]))))
        np.testing.assert_allclose(_v(m.angular_velocity), w_prev - out.state.b, atol=1e-15)
    assert worst_q < 1e-9 and worst_p < 1e-12, (worst_q, worst_p)


def test_error_inside_three_sigma(recorded):
    """Estimate vs truth (both body w.r.t. orbital) per body axis inside 3 sqrt(P_ii) for >= 95 %
    of the samples from t = 300 s: the Davenport fix at t = 0 is inflated by the unknown gyro
    bias (prior 5e-4 rad/s), which the filter resolves within a few minutes (docs/estimation.md);
    from 300 s the error is the steady filter's, for which 99.7 % is expected of a consistent one."""
    est, truth = recorded["/estimate/attitude"], recorded["/sim/truth"]
    stamps = [ns for ns in sorted(est) if ns >= 300e9]
    e = np.array([attitude_error(_q(truth[ns].pose.pose.orientation), _q(est[ns].orientation)) for ns in stamps])
    sig = np.array([np.sqrt(np.diag(np.reshape(est[ns].orientation_covariance, (3, 3)))) for ns in stamps])
    inside = np.mean(np.abs(e) <= 3 * sig, axis=0)
    assert np.all(inside >= 0.95), inside
    assert np.all(np.degrees(np.sqrt(np.mean(e**2, axis=0))) < 1.0)  # a coarse sanity: sub-degree RMS


@pytest.mark.parametrize("args, name", [(["--estimator-param", "gate_probability=2"], "gate_probability"),
                                        (["--estimator-param", "igrf_degre=8"], "igrf_degre")])
def test_bad_estimator_parameter_cli_one_line_exit_2(args, name):
    r = subprocess.run([sys.executable, "-m", "magtune_core", "sil", "--gains", "config/gains/sigma_120.yaml",
                        "--attitude", "estimator", "--orbits", "0.01", *args], capture_output=True, text=True, timeout=60)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and name in lines[0], r.stderr


def test_bad_estimator_parameter_node_one_line_exit_2():
    exe = process.resolve_executable("attitude_estimator")
    with process.DomainLock() as lock:
        env = process.child_env(lock.domain_id, process.package_prefix())
        r = subprocess.run([str(exe), "--ros-args", "-p", "igrf_degree:=0"], env=env, capture_output=True, text=True,
                           timeout=30)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "igrf_degree" in lines[0], r.stderr
