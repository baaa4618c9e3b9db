"""An independent held-loop scan for the tests: not the tuner's or the certificate's path.

The interval maps come from a dense RK4 integration of the held dipole's effect (the field turning
during the hold, Z' = A Z + B_T S(b(t)), Z(0) = 0, and Phi' = A Phi), not from Gauss-Legendre
quadrature of matrix exponentials; the monodromy at each gain scale is a plain numpy product of
the interval maps, and its spectral radius comes from numpy's eigvals.
"""
from __future__ import annotations

import numpy as np

from magtune_core.base.rotations import skew_field


def interval_maps_rk4(model, n: int, dt: float = 0.25):
    """Phi = e^{A h} and Gamma_i of the held loop with h = T / n, by RK4 at about ``dt`` seconds.

    RK4's error at dt = 0.25 s: (0.082 rad/s x 0.25 s)^5 / 120 ~ 3e-11 per step of the fastest mode,
    far below the 1e-3 a scan near the boundary needs.
    """
    h = model.period / n
    m = max(1, int(np.ceil(h / dt)))
    d = h / m
    A, BT = model.A, model.BT
    t0 = np.arange(n) * h

    def rhs(t, Z):
        return A @ Z + BT @ skew_field(model.field(t))  # (n, 6, 3)

    Z = np.zeros((n, 6, 3))
    Phi = np.eye(6)
    for j in range(m):
        t = t0 + j * d
        k1 = rhs(t, Z)
        k2 = rhs(t + d / 2, Z + d / 2 * k1)
        k3 = rhs(t + d / 2, Z + d / 2 * k2)
        k4 = rhs(t + d, Z + d * k3)
        Z = Z + d / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        p1 = A @ Phi
        p2 = A @ (Phi + d / 2 * p1)
        p3 = A @ (Phi + d / 2 * p2)
        p4 = A @ (Phi + d * p3)
        Phi = Phi + d / 6 * (p1 + 2 * p2 + 2 * p3 + p4)
    b0 = model.field(t0)
    C = np.swapaxes(skew_field(b0), -1, -2) / np.sum(b0**2, axis=-1)[:, None, None]
    return Phi, Z @ C


def held_radii(model, K, n: int, scales) -> np.ndarray:
    """rho(prod_i (Phi + k Gamma_i K)) for every k of ``scales`` (renormalized every 16 intervals)."""
    Phi, Gam = interval_maps_rk4(model, n)
    B = Gam @ np.asarray(K, dtype=float).reshape(3, 6)
    ks = np.asarray(scales, dtype=float)
    M = np.broadcast_to(np.eye(6), (len(ks), 6, 6)).copy()
    logs = np.zeros(len(ks))
    for i in range(n):
        M = (Phi[None] + ks[:, None, None] * B[i][None]) @ M
        if i % 16 == 15:
            s = np.abs(M).max(axis=(1, 2))
            M /= s[:, None, None]
            logs += np.log(s)
    ev = np.abs(np.linalg.eigvals(M)).max(axis=-1)
    return np.exp(np.log(ev) + logs)
