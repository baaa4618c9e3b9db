"""The dipole budget on the LTP model: worst-case peak |m_i| of the held closed loop.

The torquers deliver at most ``dipole_limit`` per axis; J (eq. 21) weighs the torque u = K x,
not the dipole m = S(b)^T K x / |b|^2 (eq. 17) they must produce, so a low-J gain can command
far more than the torquers have (the unconstrained sigma = 60 optimum: 80 A m^2 against 50).
The budget is checked where the flight commands it: on the sample-and-hold loop of
:class:`.sampled.SampledLoop`, x_{k+1} = (Ad + Gamma_k K) x_k + G_k m_res, m_k = C_k K x_k,
from the requirement's set of initial states (rate error in a box, attitude error in a ball)
with a residual dipole in a box. The loop is linear, so m_k is an affine function of (x_0,
m_res) and its worst case over those sets is exact: |M_k v_nom| + sum_j |M_k,j| r_j (boxes)
+ r_q ||M_k,dq|| (ball), M_k the responses to unit initial states and unit residual dipoles.
The proxy is checked against the nonlinear closed loop in tests/design/test_dipole.py.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .sampled import SampledLoop, interval_map


@njit(cache=True)
def _peak_kernel(Ad, Gamma, G, C, Ks, steps, nominal, radius, rq):  # pragma: no cover - compiled
    """max over k <= steps of the worst-case |m_k,i| per gain (n, 3): 9 unit responses (6 initial
    states, 3 residual dipoles) advanced together, combined with ``nominal`` / ``radius`` (9,)
    and the attitude-ball radius ``rq`` at every step (module docstring)."""
    n, N = Ks.shape[0], Gamma.shape[0]
    out = np.zeros((n, 3))
    X = np.zeros((6, 9))
    Y = np.zeros((6, 9))
    P = np.zeros((6, 6))
    U = np.zeros((3, 9))
    for g in range(n):
        X[:, :] = 0.0
        for i in range(6):
            X[i, i] = 1.0
        for step in range(steps + 1):
            k = step % N
            for i in range(3):
                for j in range(9):
                    acc = 0.0
                    for c in range(6):
                        acc += Ks[g, i, c] * X[c, j]
                    U[i, j] = acc
            for i in range(3):
                v = 0.0
                w = 0.0
                q2 = 0.0
                for j in range(9):
                    m = C[k, i, 0] * U[0, j] + C[k, i, 1] * U[1, j] + C[k, i, 2] * U[2, j]
                    v += m * nominal[j]
                    w += abs(m) * radius[j]
                    if j < 3:
                        q2 += m * m
                peak = abs(v) + w + rq * math.sqrt(q2)
                if not peak <= out[g, i]:  # also propagates nan
                    out[g, i] = peak
            if step == steps:
                break
            interval_map(Ad, Gamma[k], Ks[g], P)
            for i in range(6):
                for j in range(9):
                    acc = 0.0
                    for c in range(6):
                        acc += P[i, c] * X[c, j]
                    if j >= 6:
                        acc += G[k, i, j - 6]
                    Y[i, j] = acc
            X[:, :] = Y
    return out


@dataclass(frozen=True)
class DipoleCase:
    """The initial states and residual dipoles the budget must hold for (SI; module docstring).

    rate_nominal, rate_radius : the initial rate error dw(0) in nominal +- radius per axis [rad/s]
    attitude_max_deg : initial attitude error up to this rotation angle about any axis [deg]
    residual_nominal, residual_radius : the residual dipole in nominal +- radius per axis [A m^2]
    orbits : horizon of the check [orbits] (the transient and one period of the periodic response)
    """

    rate_nominal: tuple = (1e-3, 2e-3, 0.0)
    rate_radius: tuple = (0.0, 0.0, 0.0)
    attitude_max_deg: float = 0.0
    residual_nominal: tuple = (1.0, 1.0, 1.0)
    residual_radius: tuple = (0.0, 0.0, 0.0)
    orbits: float = 2.0

    def vectors(self):
        """(nominal (9,), radius (9,), attitude-ball radius of dq): the kernel's inputs.

        Returns
        -------
        nominal : ndarray (9,)
            Nominal initial state and residual dipole: [0 (dq), rate_nominal [rad/s], residual_nominal [A m^2]].
        radius : ndarray (9,)
            Box half-widths of the same entries (0 for dq).
        rq : float
            Radius of the dq ball: sin(attitude_max_deg / 2).
        """
        nominal = np.concatenate([np.zeros(3), self.rate_nominal, self.residual_nominal]).astype(float)
        radius = np.concatenate([np.zeros(3), self.rate_radius, self.residual_radius]).astype(float)
        return nominal, radius, math.sin(math.radians(self.attitude_max_deg) / 2.0)


def peak_dipole(loop: SampledLoop, Ks, case: DipoleCase = DipoleCase()) -> np.ndarray:
    """Worst-case peak commanded dipole per axis of the held loop ``loop`` over ``case``, per gain.

    Parameters
    ----------
    loop : SampledLoop
        Sample-and-hold loop of the design model (interval maps over one period).
    Ks : array_like (n, 3, 6)
        Gains (any shape with a multiple of 18 entries).
    case : DipoleCase
        Initial states, residual dipoles and horizon of the check.

    Returns
    -------
    ndarray (n, 3)
        max_k max over the case's sets of |m_k,i| [A m^2] for each gain of ``Ks`` (n, 3, 6);
        inf where the response overflows (an unstable held loop).
    """
    Ks = np.ascontiguousarray(np.asarray(Ks, dtype=float).reshape(-1, 3, 6))
    nominal, radius, rq = case.vectors()
    steps = int(round(case.orbits * loop.intervals))
    with np.errstate(all="ignore"):
        out = _peak_kernel(loop.Ad, np.ascontiguousarray(loop.Gamma), np.ascontiguousarray(loop.G),
                           np.ascontiguousarray(loop.C), Ks, steps, nominal, radius, rq)
    return np.where(np.isfinite(out), out, np.inf)
