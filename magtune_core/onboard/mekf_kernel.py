"""The MEKF of :mod:`magtune_core.onboard.mekf` and the sample logic of
:class:`magtune_core.onboard.estimator.MekfStream` on floats, compiled (numba), for the batched simulation.

The batched closed loop (:func:`magtune_core.sim.batch_kernels.closed_loop`) is a numba kernel and
cannot call the Python filter; this module is the same filter written on scalars and small arrays
(Lefferts, Markley & Shuster 1982; Markley & Crassidis 2014, sec. 6.2): the closed-form Phi
(M&C eqs. 6.83-6.84) and exact Q with the same Taylor-series switch and the same 8-point
Gauss-Legendre rule, the vector update with the same Joseph form, multiplicative reset and
chi-square gate, the Davenport fix (M&C sec. 5.3.1, ``numpy.linalg.eigh`` as in
:func:`magtune_core.onboard.attitude_fix.davenport`) and MekfStream's start (Davenport of magnetometer
and Sun at the first sample, else the magnetometer carried by the gyro once the reference field has
turned by ``init_angle``). tests/onboard/test_mekf_kernel.py runs both on the same measurements: equal
to 1e-12 (attitude, rad) over a run with a start in sunlight and one in eclipse.

State of one filter (:class:`KernelMekf` holds B of them): ``q`` (4,) body w.r.t. the reference frame,
``b`` (3,) gyro bias, ``mb`` (3,) magnetometer bias, ``P`` (9, 9) of [dtheta; db; dm] (the layout of
:mod:`magtune_core.onboard.mekf`; :func:`propagate` and :func:`update` take a (6, 6) P as the filter
without the magnetometer bias), plus the start's memory (first magnetometer sample, its reference, the
carried quaternion).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .mekf import _GL_W, _GL_X

GL_X = np.ascontiguousarray(_GL_X)
GL_W = np.ascontiguousarray(_GL_W)


class KernelMekf(NamedTuple):
    """B filters' parameters and states (arrays written in place by :func:`stream_step`)."""

    on: bool  #: the estimator is in the loop
    ts: float  #: sample period [s]
    sv2: np.ndarray  #: (B,) sigma_v^2 of the filter's gyro model [rad^2/s]
    su2: np.ndarray  #: (B,) sigma_u^2 [rad^2/s^3]
    R_mag: np.ndarray  #: (B, 3, 3) magnetometer measurement covariance [T^2]
    sig_mag: np.ndarray  #: (B,) sqrt(R_mag[0, 0] + mag_bias_std^2) (the coarse fix's weight of the magnetometer)
    sun_std: np.ndarray  #: (B,) sun sensor std [rad] (R_sun = sun_std^2 I)
    gate_mag: float  #: chi-square gate of the magnetometer NIS (3 dof; inf: none)
    gate_sun: float  #: chi-square gate of the sun NIS (2 dof)
    bias_std: float  #: bias prior std [rad/s]
    mag_bias_std: float  #: magnetometer-bias prior std [T] (0: the dm block stays zero)
    sm2: float  #: sigma_m^2 of the magnetometer-bias random walk [T^2/s]
    cos_init: float  #: cos(init_angle) of the magnetometer-only fix
    q: np.ndarray  #: (B, 4) estimate
    b: np.ndarray  #: (B, 3) estimated bias [rad/s]
    mb: np.ndarray  #: (B, 3) estimated magnetometer bias [T]
    P: np.ndarray  #: (B, 9, 9)
    started: np.ndarray  #: (B,) bool: the coarse fix is made
    k: np.ndarray  #: (B,) int64 samples seen minus one (MekfStream.k)
    first: np.ndarray  #: (B, 6) first magnetometer sample and its reference (the magnetometer-only fix)
    carry: np.ndarray  #: (B, 4) gyro-carried quaternion since the first sample
    w_prev: np.ndarray  #: (B, 3) previous gyro sample [rad/s]
    counts: np.ndarray  #: (B, 4) int64 mag accepted, mag rejected, sun accepted, sun rejected
    k0: np.ndarray  #: (B,) int64 sample of the coarse fix (-1: not yet)
    #: the estimate's validity (onboard.validity.ValidityMonitor): valid_sigma^2 [rad^2] (inf: no gate),
    #: exp(-ts / valid_nis_tau), valid_nis_limit; and each filter's NIS average (nan before the fix)
    valid_sigma2: float
    valid_a: float
    valid_limit: float
    nis_avg: np.ndarray
    valid_reinit: int  #: samples not valid after the fix before the filter restarts (0: never)
    invalid_run: np.ndarray  #: (B,) int64 samples in a row not valid since the fix


@njit(cache=True, inline="always")
def _qmul(p0, p1, p2, p3, q0, q1, q2, q3):
    """Hamilton product (:func:`magtune_core.base.rotations.quat_mul`)."""
    return (p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3, p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2,
            p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1, p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0)


@njit(cache=True, inline="always")
def _rotvec_quat(x, y, z):
    """exp(phi/2) (:func:`magtune_core.onboard.mekf.rotvec_quat`)."""
    a = math.sqrt(x * x + y * y + z * z)
    s = 0.5 - a * a / 48.0 if a < 1e-6 else math.sin(a / 2) / a
    return math.cos(a / 2), s * x, s * y, s * z


@njit(cache=True)
def rotation(q):
    """R(q) (3, 3) of a (not necessarily unit) quaternion (:func:`magtune_core.base.rotations.rotation_matrix`)."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    q0, q1, q2, q3 = q[0] / n, q[1] / n, q[2] / n, q[3] / n
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)
    R[1, 0], R[1, 1], R[1, 2] = 2 * (q1 * q2 + q0 * q3), q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3, 2 * (q2 * q3 - q0 * q1)
    R[2, 0], R[2, 1], R[2, 2] = 2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    return R


@njit(cache=True)
def matrix_quat(R):
    """Shepperd's quaternion of R, q0 >= 0 (:func:`magtune_core.base.rotations.matrix_to_quat`)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    i, best = 0, tr
    for j in range(3):
        if R[j, j] > best:
            i, best = j + 1, R[j, j]
    q = np.empty(4)
    if i == 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q[0], q[1], q[2], q[3] = s / 4, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    elif i == 1:
        s = 2.0 * math.sqrt(1.0 + 2 * R[0, 0] - tr)
        q[0], q[1], q[2], q[3] = (R[2, 1] - R[1, 2]) / s, s / 4, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s
    elif i == 2:
        s = 2.0 * math.sqrt(1.0 + 2 * R[1, 1] - tr)
        q[0], q[1], q[2], q[3] = (R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, s / 4, (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + 2 * R[2, 2] - tr)
        q[0], q[1], q[2], q[3] = (R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, s / 4
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    sg = -1.0 if q[0] < 0 else 1.0
    for j in range(4):
        q[j] = sg * q[j] / n
    return q


@njit(cache=True, inline="always")
def _coef(n, s, series):
    """c1, c2, c3 of :func:`magtune_core.onboard.mekf._coefficients` at one s (``series``: the Taylor branch)."""
    x2 = (n * s) ** 2
    if series:
        return (s * (1 - x2 / 6 + x2**2 / 120 - x2**3 / 5040), s**2 * (0.5 - x2 / 24 + x2**2 / 720 - x2**3 / 40320),
                s**3 * (1.0 / 6 - x2 / 120 + x2**2 / 5040 - x2**3 / 362880))
    x = n * s
    return math.sin(x) / n, (1 - math.cos(x)) / n**2, (x - math.sin(x)) / n**3


@njit(cache=True)
def propagate(q, b, P, wm, dt, sv2, su2, sm2, glx, glw):
    """:func:`magtune_core.onboard.mekf.propagate` in place: q (x) exp((wm - b) dt/2), P = Phi P Phi^T + Q
    (closed-form Phi and Q of :func:`~magtune_core.onboard.mekf.transition` and
    :func:`~magtune_core.onboard.mekf.process_noise`; a (9, 9) P: Phi's and Q's magnetometer-bias block
    I and sm2 dt I)."""
    nx = P.shape[0]
    w0, w1, w2 = wm[0] - b[0], wm[1] - b[1], wm[2] - b[2]
    p0, p1, p2, p3 = _rotvec_quat(w0 * dt, w1 * dt, w2 * dt)
    r0, r1, r2, r3 = _qmul(q[0], q[1], q[2], q[3], p0, p1, p2, p3)
    W = np.zeros((3, 3))
    W[0, 1], W[0, 2], W[1, 0], W[1, 2], W[2, 0], W[2, 1] = -w2, w1, w2, -w0, -w1, w0
    W2 = W @ W
    n = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    c1, c2, c3 = _coef(n, dt, n * dt < 1e-2)
    Phi = np.eye(nx)
    for i in range(3):
        for j in range(3):
            e = 1.0 if i == j else 0.0
            Phi[i, j] = e - c1 * W[i, j] + c2 * W2[i, j]
            Phi[i, 3 + j] = -dt * e + c2 * W[i, j] - c3 * W2[i, j]
    s_max = glx[glx.size - 1] * dt
    series = n * s_max < 1e-2
    f = 0.0
    ic3 = 0.0
    for g in range(glx.size):
        s = glx[g] * dt
        _, d2, d3 = _coef(n, s, series)
        f += glw[g] * (2 * s * d3 - d2**2 - n * n * d3**2)
        ic3 += glw[g] * d3
    f *= dt
    ic3 *= dt
    ic2 = c3
    Q = np.zeros((nx, nx))
    for i in range(3):
        for j in range(3):
            e = 1.0 if i == j else 0.0
            Q[i, j] = (sv2 * dt + su2 * dt**3 / 3) * e + su2 * f * W2[i, j]
            Q[i, 3 + j] = su2 * (-0.5 * dt * dt * e + ic2 * W[i, j] - ic3 * W2[i, j])
            Q[3 + i, 3 + j] = su2 * dt * e
    for i in range(3):
        for j in range(3):
            Q[3 + j, i] = Q[i, 3 + j]
        if nx == 9:
            Q[6 + i, 6 + i] = sm2 * dt
    Pn = Phi @ P @ Phi.T + Q
    nq = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2 + r3 * r3)
    q[0], q[1], q[2], q[3] = r0 / nq, r1 / nq, r2 / nq, r3 / nq
    for i in range(nx):
        for j in range(nx):
            P[i, j] = 0.5 * (Pn[i, j] + Pn[j, i])


@njit(cache=True)
def update(q, b, m, P, bm, bref, R, gate, biased):
    """:func:`magtune_core.onboard.mekf.update` in place (``m`` the magnetometer bias, read and reset when
    ``biased`` and P is (9, 9): h = R(q)^T bref + m, H = [[a x], 0, I]); returns (nis, accepted)."""
    nx = P.shape[0]
    bias = biased and nx == 9
    A = rotation(q)
    h = np.empty(3)
    for i in range(3):
        h[i] = A[0, i] * bref[0] + A[1, i] * bref[1] + A[2, i] * bref[2]
    H = np.zeros((3, nx))
    H[0, 1], H[0, 2], H[1, 0], H[1, 2], H[2, 0], H[2, 1] = -h[2], h[1], h[2], -h[0], -h[1], h[0]
    y = np.empty(3)
    for i in range(3):
        if bias:
            H[i, 6 + i] = 1.0
            h[i] += m[i]
        y[i] = bm[i] - h[i]
    PHt = P @ H.T
    S = H @ PHt + R
    nis = float(y @ np.linalg.solve(S, y))
    if not nis <= gate:
        return nis, False
    K = np.linalg.solve(S, PHt.T).T
    dx = K @ y
    IKH = np.eye(nx) - K @ H
    Pn = IKH @ P @ IKH.T + K @ R @ K.T
    r0, r1, r2, r3 = _qmul(q[0], q[1], q[2], q[3], 1.0, 0.5 * dx[0], 0.5 * dx[1], 0.5 * dx[2])
    nq = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2 + r3 * r3)
    q[0], q[1], q[2], q[3] = r0 / nq, r1 / nq, r2 / nq, r3 / nq
    for i in range(3):
        b[i] += dx[3 + i]
        if nx == 9:
            m[i] += dx[6 + i]
    for i in range(nx):
        for j in range(nx):
            P[i, j] = 0.5 * (Pn[i, j] + Pn[j, i])
    return nis, True


@njit(cache=True)
def davenport2(b1, r1, s1, b2, r2, s2):
    """:func:`magtune_core.onboard.attitude_fix.davenport` of two pairs (q, P_fix (3, 3))."""
    bu = np.empty((2, 3))
    ru = np.empty((2, 3))
    nb1, nb2 = math.sqrt(b1 @ b1), math.sqrt(b2 @ b2)
    nr1, nr2 = math.sqrt(r1 @ r1), math.sqrt(r2 @ r2)
    for j in range(3):
        bu[0, j], bu[1, j], ru[0, j], ru[1, j] = b1[j] / nb1, b2[j] / nb2, r1[j] / nr1, r2[j] / nr2
    a = np.array([s1**-2.0, s2**-2.0])
    B = np.zeros((3, 3))
    for i in range(2):
        for j in range(3):
            for k in range(3):
                B[j, k] += a[i] * bu[i, j] * ru[i, k]
    z = np.array([B[1, 2] - B[2, 1], B[2, 0] - B[0, 2], B[0, 1] - B[1, 0]])
    tr = B[0, 0] + B[1, 1] + B[2, 2]
    K = np.zeros((4, 4))
    for i in range(3):
        for j in range(3):
            K[i, j] = B[i, j] + B[j, i] - (tr if i == j else 0.0)
        K[i, 3] = K[3, i] = z[i]
    K[3, 3] = tr
    _, V = np.linalg.eigh(K)
    qv0, qv1, qv2, q4 = V[0, 3], V[1, 3], V[2, 3], V[3, 3]
    qv = np.array([qv0, qv1, qv2])
    sk = np.array([[0.0, -qv2, qv1], [qv2, 0.0, -qv0], [-qv1, qv0, 0.0]])
    At = np.empty((3, 3))
    d = q4 * q4 - (qv0 * qv0 + qv1 * qv1 + qv2 * qv2)
    for i in range(3):
        for j in range(3):
            At[j, i] = (d if i == j else 0.0) + 2.0 * qv[i] * qv[j] - 2.0 * q4 * sk[i, j]
    F = np.zeros((3, 3))
    for i in range(2):
        for j in range(3):
            for k in range(3):
                F[j, k] += a[i] * ((1.0 if j == k else 0.0) - bu[i, j] * bu[i, k])
    return matrix_quat(At), np.linalg.inv(F)


@njit(cache=True)
def _start(m, i, q, P):
    """MekfStream's initial_state: q, P_fix and the bias priors (biases 0)."""
    for j in range(4):
        m.q[i, j] = q[j]
    for j in range(9):
        for k in range(9):
            m.P[i, j, k] = 0.0
    for j in range(3):
        m.b[i, j] = 0.0
        m.mb[i, j] = 0.0
        for k in range(3):
            m.P[i, j, k] = P[j, k]
        m.P[i, 3 + j, 3 + j] = m.bias_std**2
        m.P[i, 6 + j, 6 + j] = m.mag_bias_std**2
    m.started[i] = True


@njit(cache=True)
def stream_step(m, i, mag, bref, sun_ok, sun, sref):
    """One sample of filter ``i`` (:meth:`magtune_core.onboard.estimator.MekfStream.step`): the coarse fix
    or the propagation with ``m.w_prev[i]``, then the magnetometer update and, when ``sun_ok``, the
    sun's. Returns (nis_mag, nis_sun) (nan: none). The caller stores the gyro sample in ``m.w_prev[i]``
    afterwards."""
    m.k[i] += 1
    k = m.k[i]
    if not m.started[i]:
        if k == 0:
            if sun_ok:
                q, Pf = davenport2(mag, bref, m.sig_mag[i] / math.sqrt(mag @ mag), sun, sref, m.sun_std[i])
                _start(m, i, q, Pf)
                if m.k0[i] < 0:  # the first fix (a restart keeps it)
                    m.k0[i] = k
            else:
                for j in range(3):
                    m.first[i, j], m.first[i, 3 + j] = mag[j], bref[j]
                return math.nan, math.nan
        else:
            w = m.w_prev[i]
            c = m.carry[i]
            p0, p1, p2, p3 = _rotvec_quat(w[0] * m.ts, w[1] * m.ts, w[2] * m.ts)
            c[0], c[1], c[2], c[3] = _qmul(c[0], c[1], c[2], c[3], p0, p1, p2, p3)
            mag0, b0 = m.first[i, :3], m.first[i, 3:]
            cosang = (bref @ b0) / (math.sqrt(bref @ bref) * math.sqrt(b0 @ b0))
            if cosang > m.cos_init:
                return math.nan, math.nan
            T = k * m.ts
            A = rotation(c)
            b_old = A.T @ mag0
            s_old = math.sqrt((m.sig_mag[i] / math.sqrt(mag0 @ mag0)) ** 2 + (m.bias_std * T) ** 2 + m.sv2[i] * T)
            q, Pf = davenport2(mag, bref, m.sig_mag[i] / math.sqrt(mag @ mag), b_old, b0, s_old)
            _start(m, i, q, Pf)
            if m.k0[i] < 0:
                m.k0[i] = k
    else:
        propagate(m.q[i], m.b[i], m.P[i], m.w_prev[i], m.ts, m.sv2[i], m.su2[i], m.sm2, GL_X, GL_W)
    nis_m, ok = update(m.q[i], m.b[i], m.mb[i], m.P[i], mag, bref, m.R_mag[i], m.gate_mag, True)
    m.counts[i, 0 if ok else 1] += 1
    nis_s = math.nan
    if sun_ok:
        Rs = m.sun_std[i] ** 2 * np.eye(3)
        nis_s, ok = update(m.q[i], m.b[i], m.mb[i], m.P[i], sun, sref, Rs, m.gate_sun, False)
        m.counts[i, 2 if ok else 3] += 1
    return nis_m, nis_s


def kernel_state(B: int, ts: float, *, arw, rrw, mag_cov, sun_std, gate_probability: float = 0.9999,
                 bias_std: float = 5e-4, init_angle: float = math.radians(10.0), mag_bias_std: float | None = None,
                 mag_bias_rw: float = 0.0, on: bool = True) -> KernelMekf:
    """B fresh filters (MekfStream's start state) with the filter's model: ``arw`` sigma_v, ``rrw`` sigma_u
    (scalars or (B,)), ``mag_cov`` (3, 3) or (B, 3, 3) [T^2], ``sun_std`` [rad] (scalar or (B,)), the
    magnetometer-bias prior ``mag_bias_std`` [T] (None: MekfStream's default) and random walk
    ``mag_bias_rw`` [T/s^0.5]; the chi-square gates of :class:`magtune_core.onboard.mekf.MekfParams`.
    ``on`` False: a placeholder the kernel does not read.

    Parameters
    ----------
    B : int
        Number of filters.
    ts : float
        Sample period [s].
    arw : float or array_like (B,)
        Gyro angle random walk sigma_v [rad/s^0.5].
    rrw : float or array_like (B,)
        Gyro rate random walk sigma_u [rad/s^1.5].
    mag_cov : array_like (3, 3) or (B, 3, 3)
        Magnetometer measurement covariance [T^2].
    sun_std : float or array_like (B,)
        Sun sensor angle error std per axis [rad].
    gate_probability : float
        Chi-square gate quantile of the NIS (1: no gating).
    bias_std : float
        Gyro-bias prior std per axis [rad/s].
    init_angle : float
        Turn of the reference field before the magnetometer-only fix [rad].
    mag_bias_std : float or None
        Magnetometer-bias prior std per axis [T] (None: :data:`~magtune_core.onboard.mekf.MAG_BIAS_STD`).
    mag_bias_rw : float
        Magnetometer-bias random walk std [T/s^0.5].
    on : bool
        The estimator is in the loop (False: a placeholder).

    Returns
    -------
    KernelMekf
        The parameters and the start states of the B filters.
    """
    from .mekf import MAG_BIAS_STD, MekfParams

    mb = MAG_BIAS_STD if mag_bias_std is None else float(mag_bias_std)

    def per_run(v):
        return np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=float), (B,)))

    gp = MekfParams(1.0, 1.0, gate_probability)
    R = np.ascontiguousarray(np.broadcast_to(np.asarray(mag_cov, dtype=float), (B, 3, 3)))
    carry = np.zeros((B, 4))
    carry[:, 0] = 1.0
    sig = np.sqrt(R[:, 0, 0]) if mb == 0 else np.sqrt(R[:, 0, 0] + mb**2)  # MekfStream.sig_mag
    return KernelMekf(bool(on), float(ts), per_run(arw) ** 2, per_run(rrw) ** 2, R, sig.copy(),
                      per_run(sun_std), gp.gate(3), gp.gate(2), float(bias_std), mb, float(mag_bias_rw) ** 2,
                      math.cos(init_angle), np.zeros((B, 4)), np.zeros((B, 3)), np.zeros((B, 3)), np.zeros((B, 9, 9)),
                      np.zeros(B, dtype=np.bool_),
                      np.full(B, -1, dtype=np.int64), np.zeros((B, 6)), carry, np.zeros((B, 3)),
                      np.zeros((B, 4), dtype=np.int64), np.full(B, -1, dtype=np.int64),
                      math.inf, 0.0, math.inf, np.full(B, np.nan), 0, np.zeros(B, dtype=np.int64))


def with_validity(m: KernelMekf, sigma: float, tau: float, limit: float, reinit: float = 0.0) -> KernelMekf:
    """``m`` with the validity gate of :class:`~magtune_core.onboard.validity.ValidityMonitor` (the same numbers).

    Parameters
    ----------
    m : KernelMekf
        Filters from :func:`kernel_state` (no gate: every estimate after the fix is valid).
    sigma : float
        ``valid_sigma`` [rad].
    tau : float
        ``valid_nis_tau`` [s].
    limit : float
        ``valid_nis_limit``.
    reinit : float
        ``reinit_time`` [s] (0: never).

    Returns
    -------
    KernelMekf
        The same filters, gated.
    """
    return m._replace(valid_sigma2=float(sigma) * float(sigma), valid_a=math.exp(-m.ts / float(tau)),
                      valid_limit=float(limit), valid_reinit=int(math.ceil(float(reinit) / m.ts - 1e-9)))


@njit(cache=True, error_model="numpy")
def valid_step(m, i, nis_mag):
    """:meth:`magtune_core.onboard.validity.ValidityMonitor.step` for filter ``i`` after its fix (the same
    arithmetic: average from 3 at the fix, NIS capped at the gate, a nan NIS holds it), and its restart
    when not valid for ``valid_reinit`` samples (MekfStream.reset: the next sample is a first one)."""
    if m.valid_sigma2 == math.inf:
        return True
    avg = m.nis_avg[i]
    if math.isnan(avg):
        avg = 3.0
    if not math.isnan(nis_mag):
        avg = m.valid_a * avg + (1.0 - m.valid_a) * min(nis_mag, m.gate_mag)
    m.nis_avg[i] = avg
    P = m.P[i]
    valid = max(P[0, 0], P[1, 1], P[2, 2]) < m.valid_sigma2 and avg < m.valid_limit
    m.invalid_run[i] = 0 if valid else m.invalid_run[i] + 1
    if m.valid_reinit > 0 and m.invalid_run[i] >= m.valid_reinit:  # ValidityMonitor.reinit_due: restart
        m.started[i], m.k[i], m.invalid_run[i], m.nis_avg[i] = False, -1, 0, math.nan
        m.carry[i, 0], m.carry[i, 1], m.carry[i, 2], m.carry[i, 3] = 1.0, 0.0, 0.0, 0.0
    return valid
