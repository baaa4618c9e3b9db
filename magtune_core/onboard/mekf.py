"""Multiplicative extended Kalman filter (MEKF) of attitude, gyro bias and magnetometer bias.

Lefferts, Markley & Shuster 1982 (JGC 5(5) 417-429); Markley & Crassidis 2014, Fundamentals of
Spacecraft Attitude Determination and Control, sec. 6.2 (MC below; the magnetometer bias appended
as a calibration state, MC ch. 6). Global state: q (body w.r.t. an inertial reference frame,
scalar first, the project's convention), the gyro bias b [rad/s] and the magnetometer bias m [T]
(body axes); error state x = [dtheta; db; dm] (9) with q_true = q (x) exp(dtheta/2), dtheta in
body axes, b_true = b + db, m_true = m + dm. The first 6 states alone (P of shape (6, 6)) are the
filter without the magnetometer bias: every function reads the dimension from P, and a 9-state P
whose dm block is zero (prior std 0, random walk 0) gives the 6-state results (the zero block stays
exactly zero). The gyro is the Farrenkopf model of :mod:`magtune_core.design.sensors` (sigma_v,
sigma_u); the magnetometer bias a random walk of sigma_m [T/s^0.5] (0: constant), entering only the
magnetometer's measurement b_m = R(q)^T b_ref + m + noise. Pure functions on a frozen
:class:`MekfState`; equations: docs/estimation.md.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import expm
from scipy.stats import chi2

from ..base.rotations import quat_mul, rotation_matrix

#: Default magnetometer-bias prior std per axis [T] (params ESTIMATOR_FIELDS initial_mag_bias_std,
#: MekfStream, the batch's estimator): above the campaigns' 200 nT per-axis bias draw (docs/estimation.md).
MAG_BIAS_STD = 3e-7


@dataclass(frozen=True)
class MekfParams:
    """Process noise and gating of the filter (SI units)."""

    arw: float = 1e-4  #: gyro angle random walk sigma_v [rad/s^0.5]
    rrw: float = 1e-6  #: gyro rate random walk sigma_u [rad/s^1.5]
    gate_probability: float = 0.9999  #: chi-square gate: innovations beyond this quantile are rejected
    mag_rw: float = 0.0  #: magnetometer-bias random walk sigma_m [T/s^0.5] (9-state filter; 0: constant bias)

    def gate(self, dof: int) -> float:
        """Chi-square threshold of the NIS for ``dof`` degrees of freedom (inf: no gating).

        Parameters
        ----------
        dof : int
            Degrees of freedom of the innovation.

        Returns
        -------
        float
            The ``gate_probability`` quantile of chi2(dof); inf when ``gate_probability`` >= 1.
        """
        return math.inf if self.gate_probability >= 1.0 else float(chi2.ppf(self.gate_probability, dof))


@dataclass(frozen=True)
class MekfState:
    """Estimate: q (4,) body w.r.t. reference (scalar first), b (3,) gyro bias [rad/s], P (9, 9)
    covariance of [dtheta (body axes, rad); db (rad/s); dm (T)], m (3,) magnetometer bias [T] (body
    axes). P (6, 6): the filter without the magnetometer bias (m not read)."""

    q: np.ndarray
    b: np.ndarray
    P: np.ndarray
    m: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def mag_bias(self) -> bool:
        """The magnetometer bias is a state (P is 9 x 9).

        Returns
        -------
        bool
            True for the 9-state filter.
        """
        return self.P.shape[0] == 9


def skew(v) -> np.ndarray:
    """[v x], the cross-product matrix of a 3-vector.

    Parameters
    ----------
    v : array_like (3,)
        The vector.

    Returns
    -------
    ndarray (3, 3)
        [v x], with [v x] u = v x u.
    """
    x, y, z = np.asarray(v, dtype=float)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotvec_quat(phi) -> np.ndarray:
    """exp(phi/2) = [cos(|phi|/2); sin(|phi|/2) phi/|phi|]: the rotation by the vector ``phi`` [rad].

    Parameters
    ----------
    phi : array_like (3,)
        Rotation vector [rad].

    Returns
    -------
    ndarray (4,)
        Unit quaternion, scalar first.
    """
    phi = np.asarray(phi, dtype=float)
    a = float(np.linalg.norm(phi))
    s = 0.5 - a * a / 48.0 if a < 1e-6 else math.sin(a / 2) / a  # sin(a/2)/a, series below 1e-6
    return np.concatenate([[math.cos(a / 2)], s * phi])


def quat_rotvec(q) -> np.ndarray:
    """The rotation vector phi [rad] of unit q (inverse of :func:`rotvec_quat`, |phi| <= pi).

    Parameters
    ----------
    q : array_like (4,)
        Unit quaternion, scalar first (either sign).

    Returns
    -------
    ndarray (3,)
        Rotation vector phi [rad], |phi| <= pi.
    """
    q = np.asarray(q, dtype=float)
    q = -q if q[0] < 0 else q
    v = q[1:]
    s = float(np.linalg.norm(v))
    return v * (2.0 if s < 1e-12 else 2.0 * math.atan2(s, q[0]) / s)


def attitude_error(q_true, q_est) -> np.ndarray:
    """dtheta [rad] in body axes with q_true = q_est (x) exp(dtheta/2).

    Parameters
    ----------
    q_true : array_like (4,)
        True attitude, scalar first.
    q_est : array_like (4,)
        Estimated attitude, scalar first.

    Returns
    -------
    ndarray (3,)
        The error angle dtheta [rad], body axes, |dtheta| <= pi.
    """
    qe = np.asarray(q_est, dtype=float)
    return quat_rotvec(quat_mul(qe * np.array([1.0, -1.0, -1.0, -1.0]), q_true))


def _coefficients(n: float, s):
    """c1 = sin(ns)/n, c2 = (1 - cos ns)/n^2, c3 = (ns - sin ns)/n^3 at s (array), by their Taylor
    series below ns = 1e-2 (truncation < 1e-20 relative; the closed forms lose digits there)."""
    s = np.asarray(s, dtype=float)
    x2 = (n * s) ** 2
    if n * float(np.max(s)) < 1e-2:
        return (s * (1 - x2 / 6 + x2**2 / 120 - x2**3 / 5040),
                s**2 * (0.5 - x2 / 24 + x2**2 / 720 - x2**3 / 40320),
                s**3 * (1.0 / 6 - x2 / 120 + x2**2 / 5040 - x2**3 / 362880))
    x = n * s
    return np.sin(x) / n, (1 - np.cos(x)) / n**2, (x - np.sin(x)) / n**3


def transition(omega, dt: float) -> np.ndarray:
    """Phi (6, 6) of the error dynamics for a constant rate ``omega`` over ``dt`` (closed form,
    MC eqs. 6.83-6.84; Crassidis & Junkins 2012 eq. 7.45):
    d(dtheta)/dt = -[w x] dtheta - db - eta_v, d(db)/dt = eta_u.

    Parameters
    ----------
    omega : array_like (3,)
        Estimated body rate w [rad/s], constant over the step.
    dt : float
        Step [s].

    Returns
    -------
    ndarray (6, 6)
        Phi of [dtheta; db].
    """
    W = skew(omega)
    W2 = W @ W
    c1, c2, c3 = _coefficients(float(np.linalg.norm(omega)), dt)
    Phi = np.eye(6)
    Phi[:3, :3] = np.eye(3) - c1 * W + c2 * W2
    Phi[:3, 3:] = -dt * np.eye(3) + c2 * W - c3 * W2
    return Phi


#: 8-point Gauss-Legendre rule on [0, 1] (exact for polynomials of degree 15).
_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
_GL_X, _GL_W = 0.5 * (_GL_X + 1.0), 0.5 * _GL_W


def process_noise(omega, dt: float, params: MekfParams) -> np.ndarray:
    """Q (6, 6) of one step for a constant ``omega`` over ``dt``: Q = int_0^dt Phi(s) diag(sigma_v^2 I,
    sigma_u^2 I) Phi(s)^T ds with the error dynamics of :func:`transition`. With
    B(s) = -s I + c2(s) W - c3(s) W^2 (W = [w x]): Q11 = (sigma_v^2 dt + sigma_u^2 dt^3/3) I +
    sigma_u^2 f W^2, f = int_0^dt (2 s c3 - c2^2 - |w|^2 c3^2) ds (8-point Gauss-Legendre: the
    integrand is entire and |w| dt << 1), Q12 = sigma_u^2 int B, Q22 = sigma_u^2 dt I. At w = 0 these are
    Farrenkopf's (Crassidis & Junkins 2012 eq. 7.46); :func:`process_noise_van_loan` checks them.

    Parameters
    ----------
    omega : array_like (3,)
        Estimated body rate w [rad/s], constant over the step.
    dt : float
        Step [s].
    params : MekfParams
        The gyro noise (``arw`` sigma_v [rad/s^0.5], ``rrw`` sigma_u [rad/s^1.5]).

    Returns
    -------
    ndarray (6, 6)
        Q of [dtheta; db] [rad^2, rad^2/s, rad^2/s^2].
    """
    W = skew(omega)
    W2 = W @ W
    n = float(np.linalg.norm(omega))
    s = _GL_X * dt
    _, c2, c3 = _coefficients(n, s)
    f = dt * float(_GL_W @ (2 * s * c3 - c2**2 - n * n * c3**2))
    int_c2 = _coefficients(n, dt)[2]  # int_0^dt c2(s) ds = c3(dt)
    int_c3 = dt * float(_GL_W @ c3)
    su2, sv2 = params.rrw**2, params.arw**2
    Q = np.zeros((6, 6))
    Q[:3, :3] = (sv2 * dt + su2 * dt**3 / 3) * np.eye(3) + su2 * f * W2
    Q[:3, 3:] = su2 * (-0.5 * dt * dt * np.eye(3) + int_c2 * W - int_c3 * W2)
    Q[3:, :3] = Q[:3, 3:].T
    Q[3:, 3:] = su2 * dt * np.eye(3)
    return Q


def process_noise_van_loan(omega, dt: float, params: MekfParams) -> np.ndarray:
    """Q (6, 6) by van Loan's method (1978, IEEE TAC 23(3)): expm of [[-F, G Qc G^T], [0, F^T]] dt,
    F = [[-[w x], -I], [0, 0]]; the independent reference for :func:`process_noise` (slower).

    Parameters
    ----------
    omega : array_like (3,)
        Estimated body rate w [rad/s], constant over the step.
    dt : float
        Step [s].
    params : MekfParams
        The gyro noise (``arw`` sigma_v [rad/s^0.5], ``rrw`` sigma_u [rad/s^1.5]).

    Returns
    -------
    ndarray (6, 6)
        Q of [dtheta; db], symmetrized.
    """
    F = np.zeros((6, 6))
    F[:3, :3] = -skew(omega)
    F[:3, 3:] = -np.eye(3)
    M = np.zeros((12, 12))
    M[:6, :6] = -F
    M[:6, 6:] = np.diag([params.arw**2] * 3 + [params.rrw**2] * 3)
    M[6:, 6:] = F.T
    E = expm(M * dt)
    Q = E[6:, 6:].T @ E[:6, 6:]
    return 0.5 * (Q + Q.T)


def propagate(state: MekfState, omega_meas, dt: float, params: MekfParams) -> MekfState:
    """State after ``dt`` [s] with the gyro sample ``omega_meas`` [rad/s] held over the step.

    q+ = q (x) exp((w_m - b) dt / 2) (exact for the constant estimated rate; MC eq. 6.60 in
    the project's Hamilton convention), b+ = b, m+ = m, P+ = Phi P Phi^T + Q (:func:`transition`,
    :func:`process_noise`; with the magnetometer bias, Phi = blockdiag(Phi, I) and
    Q = blockdiag(Q, sigma_m^2 dt I)).

    Parameters
    ----------
    state : MekfState
        Estimate at the start of the step (6- or 9-state).
    omega_meas : array_like (3,)
        Gyro sample w_m [rad/s], body axes.
    dt : float
        Step [s].
    params : MekfParams
        Process noise (``arw``, ``rrw``, ``mag_rw``).

    Returns
    -------
    MekfState
        The propagated estimate (q normalized, P symmetrized).
    """
    w = np.asarray(omega_meas, dtype=float) - state.b
    q = quat_mul(state.q, rotvec_quat(w * dt))
    n = state.P.shape[0]
    Phi, Q = np.eye(n), np.zeros((n, n))
    Phi[:6, :6] = transition(w, dt)
    Q[:6, :6] = process_noise(w, dt, params)
    if n == 9:
        Q[6:, 6:] = params.mag_rw**2 * dt * np.eye(3)
    P = Phi @ state.P @ Phi.T + Q
    return MekfState(q / np.linalg.norm(q), state.b.copy(), 0.5 * (P + P.T), state.m.copy())


def measurement(state: MekfState, b_ref, biased: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Predicted body vector h and its Jacobian H (3, n) w.r.t. the error state of ``state``.

    h = R(q)^T b_ref (+ m when ``biased``: the magnetometer, with the bias a state), H = [[a x], 0, I]
    with a = R(q)^T b_ref (MC eq. 6.41; the bias block I only for ``biased``, zeros for the sun
    sensor; no bias block in a 6-state filter).

    Parameters
    ----------
    state : MekfState
        The estimate (n = 6 or 9 states).
    b_ref : array_like (3,)
        Reference vector, reference axes.
    biased : bool
        The magnetometer's measurement (bias m added when the state has it).

    Returns
    -------
    h : ndarray (3,)
        Predicted body vector.
    H : ndarray (3, n)
        Its Jacobian w.r.t. the error state.
    """
    a = rotation_matrix(state.q).T @ np.asarray(b_ref, dtype=float)
    n = state.P.shape[0]
    H = np.zeros((3, n))
    H[:, :3] = skew(a)
    if biased and n == 9:
        H[:, 6:] = np.eye(3)
        return a + state.m, H
    return a, H


def update(state: MekfState, b_meas, b_ref, R, gate: float = math.inf, biased: bool = False
           ) -> tuple[MekfState, np.ndarray, float, bool]:
    """One vector update: body measurement ``b_meas`` of the reference vector ``b_ref`` with
    measurement covariance ``R`` (3, 3); ``biased``: the magnetometer's (its bias m is in the
    measurement when the state has it).

    Predicted h and H of :func:`measurement`, S = H P H^T + R, K = P H^T S^-1;
    Joseph-form covariance (I - K H) P (I - K H)^T + K R K^T (Bucy & Joseph 1968) and the
    multiplicative reset q (x) [1; dtheta/2] normalized, b + db, m + dm (MC eqs. 6.27-6.28). The
    update is skipped (state returned unchanged, accepted False) when the NIS exceeds ``gate``.

    Parameters
    ----------
    state : MekfState
        The estimate before the update.
    b_meas : array_like (3,)
        Measured vector, body axes.
    b_ref : array_like (3,)
        Its reference vector, reference axes.
    R : ndarray (3, 3)
        Measurement covariance (units of b_meas squared).
    gate : float
        NIS threshold (inf: no gating; :meth:`MekfParams.gate`).
    biased : bool
        The magnetometer's measurement (its bias m in h and H).

    Returns
    -------
    state : MekfState
        Updated (or unchanged) estimate.
    innovation : ndarray (3,)
        b_meas - h.
    nis : float
        Normalized innovation squared y^T S^-1 y.
    accepted : bool
        NIS within the gate.
    """
    h, H = measurement(state, b_ref, biased)
    y = np.asarray(b_meas, dtype=float) - h
    PHt = state.P @ H.T
    S = H @ PHt + R
    nis = float(y @ np.linalg.solve(S, y))
    if not nis <= gate:
        return state, y, nis, False
    K = np.linalg.solve(S, PHt.T).T  # S symmetric
    dx = K @ y
    IKH = np.eye(H.shape[1]) - K @ H
    P = IKH @ state.P @ IKH.T + K @ R @ K.T
    q = quat_mul(state.q, np.concatenate([[1.0], 0.5 * dx[:3]]))
    m = state.m + dx[6:] if state.mag_bias else state.m.copy()
    return MekfState(q / np.linalg.norm(q), state.b + dx[3:6], 0.5 * (P + P.T), m), y, nis, True


def initial_state(q_fix, P_fix, bias_std: float, bias=(0.0, 0.0, 0.0), mag_bias_std: float | None = None
                  ) -> MekfState:
    """Start from a coarse fix (:mod:`magtune_core.onboard.attitude_fix`): q and its attitude
    covariance, the bias prior ``bias`` with std ``bias_std`` [rad/s] per axis, uncorrelated;
    ``mag_bias_std`` [T]: the 9-state filter with the magnetometer-bias prior 0 of that std per axis
    (0: the bias block stays zero, the 6-state results), None: the 6-state filter.

    Parameters
    ----------
    q_fix : array_like (4,)
        Coarse fix, body w.r.t. reference, scalar first.
    P_fix : ndarray (3, 3)
        Its attitude covariance [rad^2].
    bias_std : float
        Gyro-bias prior std per axis [rad/s].
    bias : array_like (3,)
        Gyro-bias prior mean [rad/s].
    mag_bias_std : float or None
        Magnetometer-bias prior std per axis [T] (None: the 6-state filter).

    Returns
    -------
    MekfState
        The initial estimate, P (6, 6) or (9, 9) block diagonal, m = 0.
    """
    n = 6 if mag_bias_std is None else 9
    P = np.zeros((n, n))
    P[:3, :3] = P_fix
    P[3:6, 3:6] = bias_std**2 * np.eye(3)
    if n == 9:
        P[6:, 6:] = mag_bias_std**2 * np.eye(3)
    return MekfState(np.asarray(q_fix, dtype=float), np.asarray(bias, dtype=float).copy(), P)
