"""H2 norm of a stable LTP system from its periodic controllability Gramian.

||G||_2^2 = (1/T) int_0^T tr(C(t) P(t) C(t)^T) dt, P the T-periodic solution of
P' = A P + P A^T + B B^T (Bittanti & Colaneri 2009; Zhou & Hagiwara 2002b). Used for the
paper's c2 (T_d -> dipole m, eq. 29) under SPEC.md's reading of that garbled definition.

Per interval, the Van Loan block [[A, B B^T], [0, -A^T]] propagated with the same Magnus
exponentials as the transition matrices gives phi and the interval Gramian W = Y12 Y11^T.
The periodic P(0) solves the discrete Lyapunov equation P0 = psi P0 psi^T + W_T (Smith
doubling, batched); the time average is the trapezoid rule on the uniform grid, which is
spectrally accurate for a smooth periodic integrand.
"""
from __future__ import annotations

import numpy as np

from .system import DEFAULT_STEPS, LTPSystem, generator_at_nodes, interval_grid, magnus_exponentials


def _van_loan(sys: LTPSystem, t):
    A, B = sys.sample("A", t), sys.sample("B", t)
    BBt = B @ np.swapaxes(B, -1, -2)
    shape = np.broadcast_shapes(A.shape, BBt.shape)
    n = shape[-1]
    M = np.zeros(shape[:-2] + (2 * n, 2 * n))
    M[..., :n, :n] = A
    M[..., :n, n:] = BBt
    M[..., n:, n:] = -np.swapaxes(np.broadcast_to(A, shape), -1, -2)
    return M


def periodic_gramian(sys: LTPSystem, steps: int = DEFAULT_STEPS) -> np.ndarray:
    """P(t_k) at the grid t_k = k T / steps, shape (*batch, steps, n, n).

    The T-periodic solution of the periodic Lyapunov equation P' = A P + P A^T + B B^T
    (Bittanti & Colaneri 2009), the Gramian behind :func:`h2norm`.

    Parameters
    ----------
    sys : LTPSystem
        The (stable) system, possibly batched; only A(t) and B(t) are used.
    steps : int
        Magnus intervals per period (the grid t_k = k T / steps).

    Returns
    -------
    ndarray (*batch, steps, n, n)
        The periodic controllability Gramian P(t_k), t_k = k T / steps (Van Loan blocks, Smith doubling).
    """
    M1, M2, h = generator_at_nodes(lambda t: _van_loan(sys, t), sys.period, steps)
    Y = magnus_exponentials(M1, M2, h)
    n = Y.shape[-1] // 2
    phi = Y[..., :n, :n]
    W = Y[..., :n, n:] @ np.swapaxes(phi, -1, -2)
    W = 0.5 * (W + np.swapaxes(W, -1, -2))
    # One sweep from P = 0 gives W_T and the monodromy.
    P = np.zeros(W.shape[:-3] + (n, n))
    psi = np.broadcast_to(np.eye(n), P.shape).copy()
    for k in range(steps):
        P = phi[..., k, :, :] @ P @ np.swapaxes(phi[..., k, :, :], -1, -2) + W[..., k, :, :]
        psi = phi[..., k, :, :] @ psi
    P0 = _stein(psi, P)
    out = np.empty(W.shape[:-3] + (steps, n, n))
    P = P0
    for k in range(steps):
        out[..., k, :, :] = P
        P = phi[..., k, :, :] @ P @ np.swapaxes(phi[..., k, :, :], -1, -2) + W[..., k, :, :]
    return out


def _stein(a: np.ndarray, q: np.ndarray, tol: float = 1e-15, max_iter: int = 64) -> np.ndarray:
    """X = a X a^T + q for stable a (Smith doubling: X <- X + a X a^T, a <- a a), batched."""
    x, a = q.copy(), a.copy()
    for _ in range(max_iter):
        x = x + a @ x @ np.swapaxes(a, -1, -2)
        a = a @ a
        if np.max(np.abs(a)) < tol:
            break
    return x


def h2norm(sys: LTPSystem, steps: int = DEFAULT_STEPS) -> np.ndarray:
    """H2 norm sqrt((1/T) int_0^T tr(C P C^T) dt) of a stable, strictly proper LTP system.

    Parameters
    ----------
    sys : LTPSystem
        The stable system without feedthrough (D None or zero), possibly batched.
    steps : int
        Magnus intervals per period (Gramian grid and trapezoid rule of the time average).

    Returns
    -------
    ndarray (*batch)
        The periodic H2 norm per system (paper eq. 29 in the standard reading); a float array of shape ().

    Raises
    ------
    ValueError
        If ``sys`` has a feedthrough D(t) != 0 (its H2 norm is infinite).
    """
    if sys.has_feedthrough:
        raise ValueError("h2norm: the H2 norm of a system with a feedthrough D(t) != 0 is infinite")
    P = periodic_gramian(sys, steps)
    t0, _, _ = interval_grid(sys.period, steps)
    C = sys.sample("C", t0)
    integrand = np.einsum("...tij,...tjk,...tik->...t", C, P, C)
    return np.sqrt(np.mean(integrand, axis=-1))
