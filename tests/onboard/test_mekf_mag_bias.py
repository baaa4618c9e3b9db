"""The magnetometer-bias states of the MEKF (onboard/mekf.py, states 7-9): the measurement Jacobian
against finite differences, a zero prior giving the 6-state filter exactly, and over four orbits of
a rotating field a 200 nT per-axis bias estimated to within its sigma with the NEES in its band
(and far outside it without the bias states)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from kinematic import b_ref, wobble_rate  # tests/support
from scipy.stats import binom

from magtune_core.base.rotations import quat_mul, rotation_matrix
from magtune_core.design.sensors import Gyro, Magnetometer, SensorSuite, SunSensor
from magtune_core.onboard import mekf
from magtune_core.onboard.params import ESTIMATOR_FIELDS
from magtune_core.sim import estimation as E
from magtune_core.sim.batch import BatchEstimator

LAG = 100  #: samples between the NEES samples of a window (tests/sim/test_estimation.py)
MAG_BIAS = (2e-7, -2e-7, 2e-7)  #: simulated magnetometer bias [T]: the campaigns' 200 nT per axis
GYRO_BIAS = (2e-4, -3e-4, 1.5e-4)




def _suite(mag_bias=MAG_BIAS):
    return SensorSuite(1.0, Magnetometer(100e-9, tuple(mag_bias)), Gyro(1e-4, 1e-6, GYRO_BIAS), 0.0,
                       SunSensor(math.radians(0.5)))


def _random_q(rng):
    q = rng.standard_normal(4)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def test_default_prior_is_one_value():
    """The node's field, the filter's constant and the campaigns' estimator share the default."""
    field = next(f for f in ESTIMATOR_FIELDS if f.name == "initial_mag_bias_std")
    assert field.default == mekf.MAG_BIAS_STD == BatchEstimator().initial_mag_bias_std == 3e-7
    assert next(f for f in ESTIMATOR_FIELDS if f.name == "mag_bias_rw").default == BatchEstimator().mag_bias_rw == 0.0


@pytest.mark.parametrize("biased", [True, False])
def test_measurement_jacobian_against_finite_differences(biased):
    """H of :func:`mekf.measurement` against central differences of h(q (x) exp(dtheta/2), b + db, m + dm)
    in the 9 error states: [[a x], 0, I] for the magnetometer, [[a x], 0, 0] for the sun sensor
    (h = 1e-6 rad / 1e-9 T: truncation ~h^2, agreement 1e-9 of |b_ref| per unit)."""
    rng = np.random.default_rng(4)
    s0 = mekf.MekfState(_random_q(rng), np.array([1e-3, -2e-3, 5e-4]), np.eye(9), np.array([3e-7, -1e-7, 2e-7]))
    b_ref = np.array([2.1e-5, -1.3e-5, 3.4e-5])
    h0, H = mekf.measurement(s0, b_ref, biased)
    steps = [1e-6] * 6 + [1e-9] * 3
    J = np.empty((3, 9))
    for i in range(9):
        hs = []
        for sgn in (1.0, -1.0):
            dx = np.zeros(9)
            dx[i] = sgn * steps[i]
            s = mekf.MekfState(quat_mul(s0.q, mekf.rotvec_quat(dx[:3])), s0.b + dx[3:6], s0.P, s0.m + dx[6:])
            hs.append(mekf.measurement(s, b_ref, biased)[0])
        J[:, i] = (hs[0] - hs[1]) / (2 * steps[i])
    scale = np.linalg.norm(b_ref)
    np.testing.assert_allclose(J[:, :6], H[:, :6], rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(J[:, 6:], H[:, 6:], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(H[:, 3:6], 0.0)
    np.testing.assert_array_equal(H[:, 6:], np.eye(3) if biased else 0.0)
    a = rotation_matrix(s0.q).T @ b_ref
    np.testing.assert_allclose(h0, a + s0.m if biased else a, rtol=0, atol=1e-20)


def test_zero_prior_is_the_six_state_filter():
    """A 9-state filter with the magnetometer-bias prior 0 and no random walk against the 6-state
    filter (P (6, 6)) on 800 samples of magnetometer and sun updates: the dm block stays exactly zero,
    the bias estimate exactly 0 and q, b, P equal to 1e-12 (measured: bit for bit)."""
    truth = E.kinematic_truth(800, 1.0, wobble_rate, b_ref, sun_ref=(1.0, 1.0, 0.3))
    suite = _suite()
    mag = E.magnetometer(suite.magnetometer, truth.b_body, np.random.default_rng(2).standard_normal((801, 3)))
    p = mekf.MekfParams(1e-4, 1e-6)
    R = suite.magnetometer.covariance
    P_fix = 1e-4 * np.eye(3)
    s6 = mekf.initial_state(truth.q[0], P_fix, 5e-4)
    s9 = mekf.initial_state(truth.q[0], P_fix, 5e-4, mag_bias_std=0.0)
    assert s6.P.shape == (6, 6) and s9.P.shape == (9, 9)
    for k in range(1, 801):
        s6, s9 = (mekf.propagate(s, truth.w[k - 1], 1.0, p) for s in (s6, s9))
        s6, s9 = (mekf.update(s, mag[k], truth.b_ref[k], R, biased=True)[0] for s in (s6, s9))
        s6, s9 = (mekf.update(s, truth.sun_body[k], truth.sun_ref[k], 1e-4 * np.eye(3))[0] for s in (s6, s9))
    assert np.all(s9.P[6:, :] == 0) and np.all(s9.P[:, 6:] == 0) and np.all(s9.m == 0)
    np.testing.assert_allclose(s9.P[:6, :6], s6.P, rtol=0, atol=1e-12 * np.abs(s6.P).max())
    np.testing.assert_allclose(s9.q, s6.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(s9.b, s6.b, rtol=0, atol=1e-12 * 5e-4)


@pytest.fixture(scope="module")
def truth():
    """Four orbits (22 500 s) of the kinematic truth, Sun always visible."""
    return E.kinematic_truth(22500, 1.0, wobble_rate, b_ref, sun_ref=(1.0, 1.0, 0.3))


@pytest.mark.parametrize("use_sun", [True, False])
def test_mag_bias_converges_and_the_filter_stays_consistent(truth, use_sun):
    """200 nT per axis against the default 300 nT prior, magnetometer and sun sensor or the
    magnetometer alone: the bias error inside 3 sigma at the end and in >= 95 % of the last two orbits'
    samples per axis, sigma below a twentieth of the prior (measured: error 0.1-4 nT, sigma 0.8-3.6 nT);
    NEES windows (N = 10 samples LAG apart from 600 s) inside the 95 % band of chi2(30)/10 in >= 80 %
    of the 22 windows (Binomial(22, 0.95): P(< 80 %) = 0.4 %; measured 91 % / 86 %)."""
    run = E.run_mekf(truth, _suite(), seed=3, use_sun=use_sun)
    sig = np.sqrt(np.diagonal(run.P[:, 6:, 6:], axis1=1, axis2=2))
    err = run.mag_bias_error
    assert np.all(np.abs(err[-1]) <= 3 * sig[-1]), (err[-1], sig[-1])
    assert np.all(sig[-1] < mekf.MAG_BIAS_STD / 20), sig[-1]
    tail = slice(11250, None)
    assert np.all(np.mean(np.abs(err[tail]) <= 3 * sig[tail], axis=0) >= 0.95)
    means, lo, hi = E.nees_windows(run.nees[600::LAG], 10)
    assert len(means) == 22 and binom.cdf(17, 22, 0.95) < 0.005
    inside = np.mean((means >= lo) & (means <= hi))
    assert inside >= 0.8, (inside, means)


def test_without_the_bias_states_the_filter_is_inconsistent(truth):
    """The same run with the prior 0 (the 6-state filter): the 200 nT bias taken as attitude
    information, mean NEES far outside its band (measured ~180) and no window inside."""
    run = E.run_mekf(truth, _suite(), seed=3, mag_bias_std=0.0)
    assert np.all(run.mag_bias_error[-1] == MAG_BIAS)
    means, lo, hi = E.nees_windows(run.nees[600::LAG], 10)
    assert np.nanmean(run.nees[600:]) > 30 and np.mean((means >= lo) & (means <= hi)) < 0.2
