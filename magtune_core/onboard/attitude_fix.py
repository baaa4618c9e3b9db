"""Coarse attitude fix from vector pairs: TRIAD and the Davenport q-method (QUEST's exact solution).

Convention of the project (:mod:`magtune_core.base.rotations`): q is the attitude of the body
w.r.t. the reference frame, scalar first, ``r = R(q) b`` for a body vector b and its reference
vector r. The error of a fix is the small rotation dtheta in body axes with
q_true = q_fix (x) exp(dtheta/2) (the MEKF's error state, :mod:`magtune_core.onboard.mekf`);
both covariances below are of dtheta [rad^2]. Measurement model: each body unit vector is the
true one rotated by a small random angle of std sigma_i per axis across it (Shuster's QUEST
measurement model, Markley & Crassidis 2014, Fundamentals of Spacecraft Attitude Determination
and Control, sec. 5.5.1). Equations: docs/estimation.md.
"""
from __future__ import annotations

import numpy as np

from ..base.rotations import cross, matrix_to_quat


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _triad_frame(u, v) -> np.ndarray:
    """Columns t1 = u, t2 = u x v / |u x v|, t3 = t1 x t2 (Black 1964), for unit u."""
    t2 = cross(u, v)
    t2 = t2 / np.linalg.norm(t2)
    return np.column_stack([u, t2, cross(u, t2)])


def triad(b1, b2, r1, r2, sigma1: float, sigma2: float) -> tuple[np.ndarray, np.ndarray]:
    """TRIAD fix anchored on pair 1 (Black 1964; Shuster & Oh 1981, JGC 4(1) 70-77).

    ``b1, b2`` body vectors, ``r1, r2`` their reference vectors (any length, not parallel),
    ``sigma1, sigma2`` [rad] the per-axis angle errors of the body unit vectors.
    The covariance is the linearization of the fix in the body-vector errors alpha, beta
    (small rotations of b1, b2): dtheta = J1 alpha + J2 beta with, for t_i the body triad,
    c = b1.b2, s = |b1 x b2|, J1 = t2 t2^T + t3 t3^T - (c/s) t1 t3^T, J2 = t1 ((c/s) t3 + t1)^T
    (docs/estimation.md), so P = sigma1^2 J1 J1^T + sigma2^2 J2 J2^T.

    Parameters
    ----------
    b1, b2 : array_like (3,)
        Body vectors, any length, not parallel (b1 the anchor).
    r1, r2 : array_like (3,)
        Their reference vectors, any length, not parallel.
    sigma1, sigma2 : float
        Per-axis angle error std of the body unit vectors b1, b2 [rad].

    Returns
    -------
    q : ndarray (4,)
        Body w.r.t. reference, scalar first, q0 >= 0.
    P : ndarray (3, 3)
        Covariance of the body-axis error angle [rad^2].
    """
    b1, b2, r1, r2 = (_unit(x) for x in (b1, b2, r1, r2))
    Tb, Tr = _triad_frame(b1, b2), _triad_frame(r1, r2)
    q = matrix_to_quat(Tr @ Tb.T)  # R maps body triad onto reference triad
    t1, t2, t3 = Tb.T
    c, s = float(b1 @ b2), float(np.linalg.norm(cross(b1, b2)))
    J1 = np.outer(t2, t2) + np.outer(t3, t3) - (c / s) * np.outer(t1, t3)
    J2 = np.outer(t1, (c / s) * t3 + t1)
    return q, sigma1**2 * J1 @ J1.T + sigma2**2 * J2 @ J2.T


def davenport(b, r, sigma) -> tuple[np.ndarray, np.ndarray]:
    """Optimal fix of Wahba's problem (weights a_i = sigma_i^-2) by Davenport's q-method.

    The eigenvector of the largest eigenvalue of Davenport's K matrix (Markley & Crassidis 2014,
    sec. 5.3.1, eq. 5.17; ``numpy.linalg.eigh``) is the exact solution QUEST approximates
    (Shuster & Oh 1981). ``b, r`` (n, 3) body and reference vectors, n >= 2 not all parallel;
    ``sigma`` (n,) or scalar [rad]. Covariance: Shuster's QUEST covariance
    P = (sum_i sigma_i^-2 (I - b_i b_i^T))^-1 in body axes (M&C eq. 5.84 with A b for r).

    Parameters
    ----------
    b : array_like (n, 3)
        Body vectors, any length, n >= 2 not all parallel.
    r : array_like (n, 3)
        Their reference vectors, any length.
    sigma : float or array_like (n,)
        Per-axis angle error std of each body unit vector [rad].

    Returns
    -------
    q : ndarray (4,)
        Body w.r.t. reference, scalar first, q0 >= 0.
    P : ndarray (3, 3)
        Covariance of the body-axis error angle [rad^2].
    """
    b, r = _unit(np.atleast_2d(b)), _unit(np.atleast_2d(r))
    a = np.broadcast_to(np.asarray(sigma, dtype=float), (b.shape[0],)) ** -2.0
    B = np.einsum("i,ij,ik->jk", a, b, r)  # attitude profile matrix sum a_i b_i r_i^T (A maps r -> b)
    z = np.array([B[1, 2] - B[2, 1], B[2, 0] - B[0, 2], B[0, 1] - B[1, 0]])
    K = np.zeros((4, 4))
    K[:3, :3] = B + B.T - np.trace(B) * np.eye(3)
    K[:3, 3] = K[3, :3] = z
    K[3, 3] = np.trace(B)
    w, V = np.linalg.eigh(K)
    qv, q4 = V[:3, -1], V[3, -1]  # Markley's vector-first quaternion of A (reference -> body)
    sk = np.array([[0.0, -qv[2], qv[1]], [qv[2], 0.0, -qv[0]], [-qv[1], qv[0], 0.0]])
    A = (q4 * q4 - qv @ qv) * np.eye(3) + 2.0 * np.outer(qv, qv) - 2.0 * q4 * sk  # M&C eq. 2.125
    F = np.einsum("i,ijk->jk", a, np.eye(3) - b[:, :, None] * b[:, None, :])
    return matrix_to_quat(A.T), np.linalg.inv(F)


def svd_fix(b, r, sigma) -> np.ndarray:
    """Wahba's problem by Markley's SVD method (1988): R = U diag(1, 1, det U det V) V^T of
    sum a_i r_i b_i^T; a second, independent solution to check :func:`davenport` against.

    Parameters
    ----------
    b : array_like (n, 3)
        Body vectors, any length, n >= 2 not all parallel.
    r : array_like (n, 3)
        Their reference vectors, any length.
    sigma : float or array_like (n,)
        Per-axis angle error std of each body unit vector [rad] (weights a_i = sigma_i^-2).

    Returns
    -------
    ndarray (4,)
        Body w.r.t. reference, scalar first, q0 >= 0.
    """
    b, r = _unit(np.atleast_2d(b)), _unit(np.atleast_2d(r))
    a = np.broadcast_to(np.asarray(sigma, dtype=float), (b.shape[0],)) ** -2.0
    U, _, Vt = np.linalg.svd(np.einsum("i,ij,ik->jk", a, r, b))
    return matrix_to_quat(U @ np.diag([1.0, 1.0, np.linalg.det(U) * np.linalg.det(Vt)]) @ Vt)
