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

Algorithm (it is the costly part of the tuner's feasibility screen, run for every candidate):

* only the *terms* that enter the worst case are formed, each the response to one z = [x_0;
  m_res] (9 entries): the nominal term z = [0, rate_nominal, residual_nominal] (by linearity
  M_k v_nom is its response), a unit term per box entry with a radius > 0 and the three dq unit
  terms when r_q > 0: 7 of the 9 unit responses at the default spec, 1 at the paper's case;
* the loop is N-periodic (C_k, Gamma_k, G_k with k = s mod N), so at step s = qN + k a term's
  state is x_s = Pi_k x_{qN} + F_k m_res (Pi_k: the homogeneous transition over the first k
  intervals, F_k: the forced response to a unit residual dipole from rest) and its dipole is
  m_s = R_k z_q, with R_k = C_k K [Pi_k | F_k] (3 x 9) of the first orbit and z_q = [x_{qN};
  m_res] = E^q z, E = [[Pi_N, F_N], [0, I]]. The kernel steps the 9 unit responses over the
  first orbit once, keeps R_k, and every later orbit costs one 3 x 9 product per term and step,
  vectorized over k, instead of a 6 x 6 propagation. Short horizons and few terms (the paper's
  case) step the terms themselves instead, whichever costs less (:func:`_periodic`);
* a step is x_{s+1} = Ad x_s + G_k (m_s + m_res) (Gamma_k = G_k C_k, so the dipole the output
  needs anyway is reused), each column's state held in registers; the worst case is combined
  per block of steps with k innermost;
* the feasibility screen only asks whether the peak exceeds the budget: with ``stop_above``
  a gain stops once an axis exceeds it (:func:`peak_dipole`).

bench/bench_tuner.py times it against the held loop's spectral radius.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .sampled import SampledLoop

_BLOCK = 512  #: steps per pass of the worst-case combination, and between early-exit checks


@njit(cache=True)
def _step_columns(lp, K, X, s0, s1, M, off):  # pragma: no cover - compiled
    """Steps s0 <= s < s1 of the columns X (ncol, 9) = [x_s, m_res] in place (``lp`` = (Ad, G, C)):
    M[:, j, s - off] = m_s = C_k K x_s (k = s mod N), then x_{s+1} = Ad x_s + G_k (m_s + m_res)
    (= (Ad + Gamma_k K) x_s + G_k m_res, as Gamma_k = G_k C_k). A column's state is held in registers."""
    Ad, G, C = lp
    N = C.shape[0]
    CK = np.empty((3, 6))
    for s in range(s0, s1):
        k = s % N
        for i in range(3):
            for c in range(6):
                CK[i, c] = C[k, i, 0] * K[0, c] + C[k, i, 1] * K[1, c] + C[k, i, 2] * K[2, c]
        for j in range(X.shape[0]):
            x0, x1, x2, x3, x4, x5 = X[j, 0], X[j, 1], X[j, 2], X[j, 3], X[j, 4], X[j, 5]
            m0 = CK[0, 0] * x0 + CK[0, 1] * x1 + CK[0, 2] * x2 + CK[0, 3] * x3 + CK[0, 4] * x4 + CK[0, 5] * x5
            m1 = CK[1, 0] * x0 + CK[1, 1] * x1 + CK[1, 2] * x2 + CK[1, 3] * x3 + CK[1, 4] * x4 + CK[1, 5] * x5
            m2 = CK[2, 0] * x0 + CK[2, 1] * x1 + CK[2, 2] * x2 + CK[2, 3] * x3 + CK[2, 4] * x4 + CK[2, 5] * x5
            M[0, j, s - off] = m0
            M[1, j, s - off] = m1
            M[2, j, s - off] = m2
            u0, u1, u2 = m0 + X[j, 6], m1 + X[j, 7], m2 + X[j, 8]
            for i in range(6):
                X[j, i] = (Ad[i, 0] * x0 + Ad[i, 1] * x1 + Ad[i, 2] * x2 + Ad[i, 3] * x3 + Ad[i, 4] * x4 + Ad[i, 5] * x5
                           + G[k, i, 0] * u0 + G[k, i, 1] * u1 + G[k, i, 2] * u2)


@njit(cache=True)
def _term_values(M, i, k0, k1, Zq, sel, t, v):  # pragma: no cover - compiled
    """v[k - k0] = term t's dipole on axis i at k0 <= k < k1: column sel[t] of M if sel[t] >= 0 (a term that
    is a stepped column), else Zq[t] . M[i, :, k] (M: the 9 unit responses). k innermost (vectorized)."""
    if sel[t] >= 0:
        v[:k1 - k0] = M[i, sel[t], k0:k1]
    else:
        r0, r1, r2, r3, r4 = M[i, 0, k0:k1], M[i, 1, k0:k1], M[i, 2, k0:k1], M[i, 3, k0:k1], M[i, 4, k0:k1]
        r5, r6, r7, r8 = M[i, 5, k0:k1], M[i, 6, k0:k1], M[i, 7, k0:k1], M[i, 8, k0:k1]
        z0, z1, z2, z3, z4, z5, z6, z7, z8 = Zq[t, 0], Zq[t, 1], Zq[t, 2], Zq[t, 3], Zq[t, 4], Zq[t, 5], Zq[t, 6], Zq[t, 7], Zq[t, 8]
        for k in range(k1 - k0):
            v[k] = (r0[k] * z0 + r1[k] * z1 + r2[k] * z2 + r3[k] * z3 + r4[k] * z4 + r5[k] * z5 + r6[k] * z6
                    + r7[k] * z7 + r8[k] * z8)


@njit(cache=True)
def _block_peak(M, k0, k1, Zq, sel, terms, mx):  # pragma: no cover - compiled
    """mx[i] = max over k0 <= k < k1 of the worst case of axis i, sum_{t < nbox} w_t |m_t| + rq ||(m_t)_{t >= nbox}||
    (``terms`` = (Z0, unit, w, nbox, rq); m_t from :func:`_term_values`); nan wins (an overflowed response)."""
    w, nbox, rq = terms[2], terms[3], terms[4]
    L, nt = k1 - k0, Zq.shape[0]
    v, acc, q2 = np.empty(L), np.empty(L), np.empty(L)
    for i in range(3):
        acc[:] = 0.0
        q2[:] = 0.0
        for t in range(nt):
            _term_values(M, i, k0, k1, Zq, sel, t, v)
            if t < nbox:
                wt = w[t]
                for k in range(L):
                    acc[k] += wt * abs(v[k])
            else:
                for k in range(L):
                    q2[k] += v[k] * v[k]
        if nbox < nt:
            for k in range(L):
                acc[k] += rq * math.sqrt(q2[k])
        top = 0.0
        for k in range(L):
            if acc[k] > top or acc[k] != acc[k]:
                top = acc[k]
        mx[i] = top


@njit(cache=True)
def _merge(out, g, mx, stop):  # pragma: no cover - compiled
    """out[g] = max(out[g], mx) per axis; True when gain g is done: a value that is not finite (an
    overflowing response: every axis inf) or an axis above ``stop``."""
    done = False
    for i in range(3):
        if mx[i] > out[g, i] or mx[i] != mx[i]:
            out[g, i] = mx[i]
        if not abs(out[g, i]) < np.inf:
            out[g, :] = np.inf
            return True
        done = done or out[g, i] > stop
    return done


@njit(cache=True)
def _later_orbits(M, X, terms, steps, stop, out, g):  # pragma: no cover - compiled
    """Orbits q >= 1 of gain g from the first orbit's R_k = M[:, :, k] and X = E^T (the 9 unit responses
    [x_N, m_res] after one orbit): term t's dipole at step qN + k is R_k z_q, z_q = E z_{q-1}, z_0 = Z0[t]."""
    N = M.shape[2]
    Zq = terms[0].copy()
    Zn = np.empty_like(Zq)
    dense = np.full(Zq.shape[0], -1)
    mx = np.empty(3)
    for q in range(1, steps // N + 1):
        for t in range(Zq.shape[0]):
            for a in range(9):
                acc = 0.0
                for j in range(9):
                    acc += X[j, a] * Zq[t, j]
                Zn[t, a] = acc
        Zq[:, :] = Zn
        end = min(N, steps - q * N + 1)
        for k0 in range(0, end, _BLOCK):
            _block_peak(M, k0, min(k0 + _BLOCK, end), Zq, dense, terms, mx)
            if _merge(out, g, mx, stop):
                return


@njit(cache=True)
def _peak_kernel(lp, Ks, steps, cols, terms, periodic, stop):  # pragma: no cover - compiled
    """Worst-case peak per axis over steps 0..steps for each gain of Ks (n, 3) (module docstring).

    ``lp`` = (Ad, G, C) of the loop; ``cols`` (ncol, 9): the stepped columns [x_0, m_res], the 9 unit
    responses (identity; reused over the orbits after the first) if ``periodic``, else the terms; ``terms`` =
    (Z0 (nt, 9), unit (nt,), w (nt,), nbox, rq): the terms' z, the unit response each unit term is (-1: none,
    the nominal term), the weights of the nbox box terms (nominal first) and the ball radius of the rest.
    A gain stops once an axis exceeds ``stop``."""
    n, N = Ks.shape[0], lp[2].shape[0]
    out = np.zeros((n, 3))
    M = np.empty((3, cols.shape[0], N if periodic else _BLOCK))
    sel = terms[1] if periodic else np.arange(cols.shape[0])
    last = min(steps, N - 1) if periodic else steps  # the first pass (periodic, steps >= N: then X = E^T)
    X = np.empty_like(cols)
    mx = np.empty(3)
    for g in range(n):
        X[:, :] = cols
        done = False
        for s0 in range(0, last + 1, _BLOCK):
            s1 = min(s0 + _BLOCK, last + 1)
            off = 0 if periodic else s0
            _step_columns(lp, Ks[g], X, s0, s1, M, off)
            _block_peak(M, s0 - off, s1 - off, terms[0], sel, terms, mx)
            done = _merge(out, g, mx, stop)
            if done:
                break
        if periodic and not done:
            _later_orbits(M, X, terms, steps, stop, out, g)
    return out


def _terms(case):
    """The kernel's terms of ``case`` (module docstring): (Z0 (nt, 9), unit (nt,), w (nt,), nbox, rq), the
    nominal term first, then a unit term per positive box radius (weight: the radius), then the dq terms of
    the ball; ``unit``: which unit response each term is (-1 for the nominal one)."""
    nominal, radius, rq = case.vectors()
    box = [j for j in range(9) if radius[j] > 0]
    ball = [0, 1, 2] if rq > 0 else []
    eye = np.eye(9)
    Z0 = np.vstack([nominal[None], eye[box], eye[ball]])
    w = np.concatenate([[1.0], radius[box], np.zeros(len(ball))])
    unit = np.array([-1] + box + ball, dtype=np.int64)
    return np.ascontiguousarray(Z0), unit, w, 1 + len(box), float(rq)


def _periodic(nt: int, steps: int, N: int) -> bool:
    """Whether the 9 unit responses over (at most) the first orbit and their reuse over the later ones
    (module docstring) cost less than stepping the nt terms over steps 0..steps. Measured at Ts = 1 s:
    a step costs about 1.25 + ncol column-steps, a later-orbit step a quarter column-step per term."""
    return min(steps + 1, N) * 10.25 + max(0, steps + 1 - N) * nt / 4 < (steps + 1) * (nt + 1.25)


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


def peak_dipole(loop: SampledLoop, Ks, case: DipoleCase = DipoleCase(), stop_above: float = np.inf) -> np.ndarray:
    """Worst-case peak commanded dipole per axis of the held loop ``loop`` over ``case``, per gain.

    Parameters
    ----------
    loop : SampledLoop
        Sample-and-hold loop of the design model (interval maps over one period).
    Ks : array_like (n, 3, 6)
        Gains (any shape with a multiple of 18 entries).
    case : DipoleCase
        Initial states, residual dipoles and horizon of the check.
    stop_above : float
        A gain may stop as soon as an axis exceeds this [A m^2] (a screen against a budget); its
        value is then only a lower bound, but > ``stop_above`` on that axis. inf: exact values.

    Returns
    -------
    ndarray (n, 3)
        max_k max over the case's sets of |m_k,i| [A m^2] for each gain of ``Ks`` (n, 3, 6);
        inf where the response overflows (an unstable held loop). With a finite ``stop_above``,
        a gain whose largest axis is > ``stop_above`` may carry a lower bound of its values.
    """
    Ks = np.ascontiguousarray(np.asarray(Ks, dtype=float).reshape(-1, 3, 6))
    terms = _terms(case)
    steps = int(round(case.orbits * loop.intervals))
    periodic = _periodic(len(terms[0]), steps, loop.intervals)
    cols = np.eye(9) if periodic else terms[0]
    lp = tuple(np.ascontiguousarray(a, dtype=float) for a in (loop.Ad, loop.G, loop.C))
    with np.errstate(all="ignore"):
        out = _peak_kernel(lp, Ks, steps, cols, terms, periodic, float(stop_above))
    return np.where(np.isfinite(out), out, np.inf)
