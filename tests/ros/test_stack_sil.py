"""The full flight stack in the SIL (``magtune sil --modes --attitude estimator``): no truth on board.

One shared run: full environment, a deployment tumble of (3, -2, 4) deg/s, the mode manager bringing
up the sensors, the estimator and the controller; B-dot on the raw magnetometer, the estimate trusted
only once valid (onboard.validity.ValidityMonitor), ACQUISITION and POINTING on the estimate. The
checks read the truth from the bag only (the nodes never see it)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from magtune_core import bags as baglib
from magtune_core.bags.decode import Decoder, stamp_ns
from magtune_core.base.schema import parse
from magtune_core.design.params import load_spacecraft
from magtune_core.onboard.estimator import FilterModel, MekfStream
from magtune_core.onboard.mekf import attitude_error
from magtune_core.onboard.modes import ACQUISITION, DETUMBLE, POINTING
from magtune_core.onboard.params import ESTIMATOR_FIELDS
from magtune_core.onboard.validity import ValidityMonitor
from magtune_core.ros import sil
from magtune_core.studies.report_modes import load_modes

pytestmark = pytest.mark.ros
#: Two orbits (11,224 s): DETUMBLE -> ACQUISITION at ~2600 s, POINTING at ~5350 s, then the second orbit
#: settled (measured 2605 s and 5347 s; the issue's 8-orbit acceptance run is in docs/modes.md).
ORBITS = 2.0
RATE = (3.0, -2.0, 4.0)
#: Words a status may use only for a detected fault of that unit (issue 44's rule).
UNITS = ("torquer x", "torquer y", "torquer z", "magnetometer", "gyro", "sun sensor")


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    """The run's result and its bag decoded by topic and stamp (diagnostics and modes as lists)."""
    tmp = tmp_path_factory.mktemp("stack")
    bag = tmp / "bag"
    run = sil.run_sil("config/gains/sigma_60.yaml", orbits=ORBITS, environment="full", attitude="estimator",
                      modes=True, initial_rate_deg=RATE, log_dir=tmp / "logs", bag=bag, timeout=900)
    dec, topics, diags, modes = Decoder(), {}, [], []
    for msg in baglib.iter_messages(bag):
        if msg.topic == "/diagnostics":
            diags.extend(dec.decode(msg.data, msg.type).status)
        elif msg.topic.startswith(("/sensors/", "/sim/truth", "/estimate/")):
            o = dec.decode(msg.data, msg.type)
            topics.setdefault(msg.topic, {})[stamp_ns(o)] = o
    modes = [(c.t, c.mode, c.reason) for c in load_modes(bag)]
    return run, topics, diags, modes


def _v(v):
    return np.array([v.x, v.y, v.z])


def _q(o):
    return np.array([o.w, o.x, o.y, o.z])


def test_deployment_reaches_pointing_on_the_estimate(stack):
    """DETUMBLE -> ACQUISITION -> POINTING with no other transition, the DETUMBLE exit waiting for a valid
    estimate; the true pointing error settled: RMS over the last orbit below 1 deg and the final error
    below 2 deg (issue 44's acceptance figures; measured 0.39 and 0.40 deg)."""
    run, _, _, modes = stack
    assert [m[1] for m in modes] == [DETUMBLE, ACQUISITION, POINTING], modes
    assert "attitude valid" in modes[1][2]
    err = np.degrees(2.0 * np.arcsin(np.minimum(np.linalg.norm(run.result.q[:, 1:], axis=1), 1.0)))
    last = run.result.t >= run.result.t[-1] - load_spacecraft("config/spacecraft.yaml").orbit_period
    rms = math.sqrt(float(np.mean(err[last] ** 2)))
    assert rms < 1.0 and err[-1] < 2.0, (rms, err[-1])
    assert run.counters.get("missed_steps", 0) == 0


def test_valid_estimates_are_inside_three_sigma(stack):
    """An estimate that is not valid is published as not known (orientation_covariance[0] = -1: REP-145;
    which samples: the replay test below); from the DETUMBLE exit on, >= 95 % of the samples are valid and
    the valid ones are within 3 sigma of the truth per axis in >= 97 % of the samples (99.7 % expected of a
    consistent filter; the margin covers the correlated samples of one run)."""
    _, topics, _, modes = stack
    est, truth = topics["/estimate/attitude"], topics["/sim/truth"]
    valid = {ns: est[ns].orientation_covariance[0] != -1.0 for ns in est}
    t_exit = modes[1][0]
    stamps = [ns for ns in sorted(est) if ns >= t_exit * 1e9 and valid[ns]]
    assert len(stamps) > 0.95 * sum(1 for ns in est if ns >= t_exit * 1e9)
    e = np.array([attitude_error(_q(truth[ns].pose.pose.orientation), _q(est[ns].orientation)) for ns in stamps])
    sig = np.array([np.sqrt(np.diag(np.reshape(est[ns].orientation_covariance, (3, 3)))) for ns in stamps])
    assert np.all(np.mean(np.abs(e) <= 3 * sig, axis=0) >= 0.97)


def test_validity_is_the_core_monitor_on_the_recorded_sensors(stack):
    """The node's valid flag at every sample equals onboard.validity.ValidityMonitor fed by the core's
    MekfStream on the recorded raw sensor messages (same float64 arithmetic: equal, sample for sample)."""
    from magtune_ros.attitude_estimator import models_from  # rclpy: built package

    _, topics, _, _ = stack
    v = parse({"environment": "full", "validity_gate": True}, ESTIMATOR_FIELDS, "test")
    models, stream = models_from(v, load_spacecraft("config/spacecraft.yaml")), MekfStream(FilterModel.from_values(v))
    monitor = ValidityMonitor.from_values(v, stream.ts, stream.gate_mag)
    est, imu, mag, sun, pos = (topics[t] for t in ("/estimate/attitude", "/sensors/imu", "/sensors/magnetic_field",
                                                   "/sensors/sun", "/sensors/position"))
    w_prev, differ, n = None, [], 0
    for ns in sorted(imu):
        t = ns * 1e-9
        r = _v(pos[ns].pose.pose.position)
        s = _v(sun[ns].vector) if ns in sun else None
        out = stream.step(w_prev, _v(mag[ns].magnetic_field), models.field(t, r), s,
                          models.sun(t, r) if s is not None else None)
        w_prev = _v(imu[ns].angular_velocity)
        ok = out.state is not None and monitor.step(out.state.P, out.nis_mag)
        if monitor.reinit_due:  # the node's restart from a coarse fix
            stream.reset()
            monitor.reset()
        if ns in est:
            n += 1
            if ok != (est[ns].orientation_covariance[0] != -1.0):
                differ.append(t)
    assert n > 10000 and not differ, differ[:5]


def test_no_unit_blamed_in_a_fault_free_run(stack):
    """WARN or ERROR naming a unit is reserved for a detected fault of that unit: none in this run."""
    _, _, diags, _ = stack
    blamed = [(d.name, d.message) for d in diags if d.level >= 1 and any(u in f"{d.name} {d.message}".lower()
                                                                          for u in UNITS)]
    assert not blamed, blamed[:5]
