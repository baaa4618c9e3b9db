"""Coarse fixes (TRIAD, Davenport) and the MEKF's propagation, against independent numerics: exact
rotations, Markley's SVD solution, Monte Carlo of the sensor models, finite differences, van Loan."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from magtune_core.base.rotations import quat_mul, rotation_matrix
from magtune_core.design.sensors import Gyro, SunSensor, gyro, noisy_attitude, sun_sensor
from magtune_core.onboard import mekf
from magtune_core.onboard.attitude_fix import davenport, svd_fix, triad


def _random_q(rng):
    q = rng.standard_normal(4)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


@pytest.mark.parametrize("seed", range(5))
def test_fixes_recover_a_known_rotation_exactly(seed):
    """Noise-free pairs: TRIAD, Davenport and SVD give the rotation to rounding (1e-12: ~1e4 ulp)."""
    rng = np.random.default_rng(seed)
    q = _random_q(rng)
    r = rng.standard_normal((3, 3)) * [30e-6, 1.0, 2.0]  # any lengths: the fixes use directions
    b = r @ rotation_matrix(q)  # b_i = R^T r_i
    np.testing.assert_allclose(triad(b[0], b[1], r[0], r[1], 1e-3, 1e-3)[0], q, atol=1e-12)
    np.testing.assert_allclose(davenport(b, r, [1e-3, 2e-3, 5e-3])[0], q, atol=1e-12)
    np.testing.assert_allclose(svd_fix(b, r, [1e-3, 2e-3, 5e-3]), q, atol=1e-12)


def _fix_nees(fix, trials=2000, angle=1.0471975511965976, sigmas=(3e-3, 1e-2)):
    """Mean NEES of a fix's error over seeded trials; body vectors perturbed by the sun sensor model
    (a rotation by sigma n, 2 dof across the vector); ``angle`` [rad] between the first two."""
    rng = np.random.default_rng(7)
    q = _random_q(rng)
    r = np.array([[1.0, 0.0, 0.0], [np.cos(angle), np.sin(angle), 0.0], [0.0, 0.3, 1.0]])
    r[2] /= np.linalg.norm(r[2])
    b = r @ rotation_matrix(q)
    nees = np.empty(trials)
    for i in range(trials):
        bm = np.array([sun_sensor(SunSensor(s), b[j], True, rng.standard_normal(3))[0] for j, s in enumerate(sigmas)])
        qf, P = fix(bm, r[: len(sigmas)], sigmas)
        e = mekf.attitude_error(q, qf)
        nees[i] = e @ np.linalg.solve(P, e)
    return nees.mean()


@pytest.mark.parametrize("name", ["triad", "davenport2", "davenport3"])
def test_fix_covariance_is_consistent(name):
    """The fix error's NEES over 2000 seeded trials inside the chi-square 99.9 % band of its mean
    (6000 dof: 3.00 +- 0.13): the covariances (TRIAD's linearization, Shuster's QUEST) are right."""
    fix = {"triad": lambda b, r, s: triad(b[0], b[1], r[0], r[1], *s),
           "davenport2": davenport, "davenport3": davenport}[name]
    sig = (3e-3, 1e-2, 5e-3) if name == "davenport3" else (3e-3, 1e-2)
    n = 2000
    lo, hi = chi2.ppf([0.0005, 0.9995], 3 * n) / n
    assert lo <= _fix_nees(fix, n, sigmas=sig) <= hi


def test_transition_is_the_jacobian_of_the_propagation():
    """Phi against central finite differences of the nonlinear step (global state, errors in and
    out): agreement 1e-7 (h = 1e-6 rad: truncation ~h^2, rounding ~1e-16/h)."""
    p = mekf.MekfParams()
    s0 = mekf.MekfState(_random_q(np.random.default_rng(1)), np.array([1e-3, -2e-3, 5e-4]), np.eye(6))
    wm, dt, h = np.array([0.05, -0.03, 0.08]), 2.0, 1e-6
    nom = mekf.propagate(s0, wm, dt, p)
    J = np.empty((6, 6))
    for i in range(6):
        col = []
        for sgn in (1.0, -1.0):
            dx = np.zeros(6)
            dx[i] = sgn * h
            s = mekf.MekfState(quat_mul(s0.q, mekf.rotvec_quat(dx[:3])), s0.b + dx[3:], s0.P)  # b_true = b_est + db
            out = mekf.propagate(s, wm, dt, p)  # the perturbed truth, propagated with its own bias
            col.append(np.concatenate([mekf.attitude_error(out.q, nom.q), out.b - nom.b]))
        J[:, i] = (col[0] - col[1]) / (2 * h)
    np.testing.assert_allclose(J, mekf.transition(wm - s0.b, dt), atol=1e-7)


@pytest.mark.parametrize("w,dt", [((0.0, 0.0, 0.0), 1.0), ((1e-3, 0.0, -1e-3), 1.0), ((0.3, 0.1, -0.2), 1.0),
                                  ((0.05, -0.02, 0.04), 10.0)])
def test_process_noise_closed_form_equals_van_loan(w, dt):
    """Q (Gauss-Legendre closed form) against van Loan's expm, relative 1e-12 of the largest entry
    (both exact; the difference is rounding)."""
    p = mekf.MekfParams(1e-3, 1e-4)
    Q, Qv = mekf.process_noise(w, dt, p), mekf.process_noise_van_loan(w, dt, p)
    np.testing.assert_allclose(Q, Qv, rtol=0, atol=1e-12 * np.abs(Qv).max())
    np.testing.assert_allclose(mekf.transition(w, dt)[:3, :3] @ mekf.transition(w, dt)[:3, :3].T, np.eye(3), atol=1e-14)


def test_propagated_covariance_matches_monte_carlo():
    """P after 40 gyro steps against 3000 seeded runs of the true attitude with the Farrenkopf gyro of
    design/sensors.py: mean NEES (6 dof) inside the chi-square 99.9 % band (18000 dof: 6.00 +- 0.20),
    and every standard deviation within 6 % (3000 samples: a std's relative error ~1/sqrt(2 n) = 1.3 %)."""
    M, N, dt = 3000, 40, 1.0
    g = Gyro(arw=1e-3, rrw=1e-4)
    p = mekf.MekfParams(g.arw, g.rrw)
    w = np.array([0.04, -0.03, 0.05])
    P0 = np.diag([1e-4, 2e-4, 1e-4, 1e-6, 1e-6, 4e-6])
    rng = np.random.default_rng(11)
    x0 = rng.multivariate_normal(np.zeros(6), P0, M)
    q_est0 = _random_q(rng)
    q_true = noisy_attitude(np.broadcast_to(q_est0, (M, 4)), 1.0, x0[:, :3])  # q_est (x) exp(dtheta/2)
    w_m, beta = gyro(g, np.broadcast_to(w, (M, N, 3)), dt, x0[:, 3:], rng.standard_normal((M, N, 3)),
                     rng.standard_normal((M, N, 3)))
    q_est = np.broadcast_to(q_est0, (M, 4)).copy()
    step = mekf.rotvec_quat(w * dt)
    for k in range(N):
        q_true = noisy_attitude(q_true, 1.0, np.broadcast_to(w * dt, (M, 3)))
        q_est = noisy_attitude(q_est, 1.0, w_m[:, k] * dt)  # b_est = 0
    s = mekf.MekfState(q_est0, np.zeros(3), P0)
    for k in range(N):
        s = mekf.propagate(s, w, dt, p)  # P depends on the estimated rate only through Phi: the nominal one
    assert np.allclose(step, mekf.rotvec_quat(w * dt))
    err = np.array([np.concatenate([mekf.attitude_error(q_true[i], q_est[i]), beta[i, -1]]) for i in range(M)])
    nees = np.einsum("ij,ij->i", err, np.linalg.solve(s.P, err.T).T).mean()
    lo, hi = chi2.ppf([0.0005, 0.9995], 6 * M) / M
    assert lo <= nees <= hi
    np.testing.assert_allclose(err.std(axis=0), np.sqrt(np.diag(s.P)), rtol=0.06)


def test_update_reset_and_joseph_form():
    """A perfect measurement along a known error: the update moves q toward the truth, the Joseph
    form equals the short form (I - K H) P for the optimal gain (to 1e-12 relative), P stays symmetric."""
    rng = np.random.default_rng(5)
    q = _random_q(rng)
    P = np.diag([1e-4, 1e-4, 1e-4, 1e-8, 1e-8, 1e-8])
    s = mekf.MekfState(q, np.zeros(3), P)
    r = np.array([0.0, 0.0, 1.0])
    R = 1e-6 * np.eye(3)
    q_true = quat_mul(q, mekf.rotvec_quat([0.01, 0.0, 0.0]))
    out, y, nis, ok = mekf.update(s, rotation_matrix(q_true).T @ r, r, R)
    assert ok and nis > 0
    h = rotation_matrix(q).T @ r
    e0, e1 = np.array([0.01, 0.0, 0.0]), mekf.attitude_error(q_true, out.q)
    perp = np.eye(3) - np.outer(h, h)
    # across h, 1e-6 / (1e-4 + 1e-6) ~ 1 % of the error is left; along h it is unobservable (kept)
    assert np.linalg.norm(perp @ e1) < 0.02 * np.linalg.norm(perp @ e0)
    assert abs(h @ e1 - h @ e0) < 1e-5
    H = np.zeros((3, 6))
    H[:, :3] = mekf.skew(rotation_matrix(q).T @ r)
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    np.testing.assert_allclose(out.P, (np.eye(6) - K @ H) @ P, rtol=0, atol=1e-12 * P.max())
    gated, _, nis2, ok2 = mekf.update(s, rotation_matrix(q_true).T @ r, r, R, gate=nis / 2)
    assert not ok2 and gated is s and nis2 == nis
