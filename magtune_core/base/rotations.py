"""Quaternions, rotation matrices and the 3-vector cross product (scalar-first quaternions).

``q = [q0, q1, q2, q3]`` is the attitude of the body w.r.t. a reference frame (orbital axes in
the paper); ``R(q)`` takes body vectors to reference axes: ``v_ref = q (x) v_body (x) q*``.
One implementation each: :func:`rotation_matrix` (arrays, batched), :func:`dcm_floats` (plain
floats, the RK4 hot path), :func:`cross` (arrays, batched).
"""
from __future__ import annotations

import numpy as np


def quat_mul(p, q) -> np.ndarray:
    """Hamilton product p (x) q of scalar-first quaternions."""
    p0, p1, p2, p3 = p
    q0, q1, q2, q3 = q
    return np.array([
        p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3,
        p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2,
        p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1,
        p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0,
    ])


def rotation_matrix(q) -> np.ndarray:
    """R(q): body vectors to orbital axes, for scalar-first (not necessarily unit) quaternions.

    ``q`` (4,) or (..., 4); returns (3, 3) or (..., 3, 3) with ``v_ref = R @ v_body`` when q is
    the attitude of the body w.r.t. the reference frame (SPEC.md convention).
    """
    q = np.asarray(q, dtype=float)
    if q.ndim > 1:
        q = q / np.linalg.norm(q, axis=-1, keepdims=True)
        q0, q1, q2, q3 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
        return np.stack([
            np.stack([q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)], -1),
            np.stack([2 * (q1 * q2 + q0 * q3), q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3, 2 * (q2 * q3 - q0 * q1)], -1),
            np.stack([2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3], -1),
        ], axis=-2)
    # one quaternion: the arithmetic of the earlier dynamics.rotation_matrix, kept bit for bit
    # (the offline simulation and the SIL evaluate the measured field with it)
    q0, q1, q2, q3 = q / np.sqrt(np.dot(q, q))
    return np.array([
        [q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)],
        [2 * (q1 * q2 + q0 * q3), q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3, 2 * (q2 * q3 - q0 * q1)],
        [2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3],
    ])


def dcm_floats(q0: float, q1: float, q2: float, q3: float) -> tuple:
    """R(q) of the normalized quaternion, row-major, on plain floats (the RK4 hot path)."""
    n2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3
    a0, a1, a2, a3 = (q0, q1, q2, q3) if n2 == 1.0 else (v / n2**0.5 for v in (q0, q1, q2, q3))
    return (a0 * a0 + a1 * a1 - a2 * a2 - a3 * a3, 2 * (a1 * a2 - a0 * a3), 2 * (a1 * a3 + a0 * a2),
            2 * (a1 * a2 + a0 * a3), a0 * a0 - a1 * a1 + a2 * a2 - a3 * a3, 2 * (a2 * a3 - a0 * a1),
            2 * (a1 * a3 - a0 * a2), 2 * (a2 * a3 + a0 * a1), a0 * a0 - a1 * a1 - a2 * a2 + a3 * a3)


def cross(a, b) -> np.ndarray:
    """a x b over the last axis with broadcasting; same result as np.cross, ~3x less overhead per call."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.ndim == 1 and b.ndim == 1:  # one vector each: plain float arithmetic
        a0, a1, a2 = a.tolist()
        b0, b1, b2 = b.tolist()
        return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack(np.broadcast_arrays(a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0), axis=-1)


def matrix_to_quat(R) -> np.ndarray:
    """Scalar-first unit quaternion q with ``rotation_matrix(q) == R`` (R proper orthogonal, (3, 3)).

    Shepperd's method: the largest of 1 + trace, 1 + 2 R_ii - trace chooses the pivot, so the
    division is always by a number >= 1/2 (no loss of precision near 180 deg). Sign: q0 >= 0.
    """
    R = np.asarray(R, dtype=float)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    d = np.array([tr, R[0, 0], R[1, 1], R[2, 2]])
    i = int(np.argmax(d))
    if i == 0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = np.array([s / 4, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    elif i == 1:
        s = 2.0 * np.sqrt(1.0 + 2 * R[0, 0] - tr)
        q = np.array([(R[2, 1] - R[1, 2]) / s, s / 4, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s])
    elif i == 2:
        s = 2.0 * np.sqrt(1.0 + 2 * R[1, 1] - tr)
        q = np.array([(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, s / 4, (R[1, 2] + R[2, 1]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + 2 * R[2, 2] - tr)
        q = np.array([(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, s / 4])
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q

def skew_field(b) -> np.ndarray:
    """S(b) of paper eq. (13), so that m x b = S(b) m; vectorized over leading axes of b."""
    b = np.asarray(b, dtype=float)
    S = np.zeros(b.shape[:-1] + (3, 3))
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    S[..., 0, 1], S[..., 0, 2] = bz, -by
    S[..., 1, 0], S[..., 1, 2] = -bz, bx
    S[..., 2, 0], S[..., 2, 1] = by, -bx
    return S
