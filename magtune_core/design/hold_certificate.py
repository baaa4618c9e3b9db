"""The certificate of the hold requirement: the held loop stable at every scale of the gain margin, at every admissible period.

A gain margin gm means what an engineer reads (docs/requirements.md, "The hold requirement"):
the sample-and-hold loop (:mod:`.sampled`) is stable with k K for **every** k in [1, gm], at
**every** period the flight computer may run in [ts_min, ts_max]. Near the nutation limit the
held loop's stability is not monotone in k (the gains shipped before this module were unstable
for 3.87-3.995 x K at Ts = 30.03 s and stable at 4 x K), so checking the two ends is not enough.

What is proven, and at what resolution:

* **periods**: the LTP model holds the dipole over h = T / N (N = round(T / Ts)), so a flight at
  any Ts in [ts_min, ts_max] is modelled by one N in [round(T / ts_max), round(T / ts_min)]. All of
  them are checked (5,429 for the paper's orbit at 1-30 s), none interpolated;
* **scales**: a uniform grid k = 1 .. gm (1 + guard) with step <= ``step`` (0.005 by default);
  an instability island narrower than the step can be missed, which the certificate states;
* **guard band**: the grid runs ``guard`` (0.5 %) past gm. Near the boundary a mode ringing at
  the Nyquist rate makes the monodromy strongly non-normal and its eigenvalue's error relative
  in k reaches ~5e-4 (:func:`.sampled.hold_gain_margin`: 1.9993 against 2.0002 for one gain with
  two summation orders), so "stable at 4 x K" is not decidable at 4 itself; the guard is 10x that.

How it is computed (the issue's hint): for one period the interval maps are Ad + k B_i with
B_i = Gamma_i K independent of k. The monodromy prod_i (Ad + k B_i) is formed for the whole
k grid at once (structure of arrays over k, compiled), by blocks of consecutive intervals: a
block's product is a matrix polynomial in k whose coefficients are built once, then evaluated
by Horner at every k, so a k point costs ~50 flops per interval instead of ~320. A block grows
while prod (1 + k_max |B_i| / |Ad|) <= :data:`BLOCK_GROWTH` (the ratio of the coefficients'
sum of magnitudes to a direct product's, which bounds the extra round-off); at large h a block
is one interval (a direct product); a constant field repeats one map, whose radius is raised to
the N-th power. Any period with a multiplier on the grid within a factor :data:`DIRECT_BAND` of 1
is recomputed with direct products, so every verdict near the boundary comes from the same
arithmetic as :meth:`.sampled.SampledLoop.spectral_radius`; elsewhere the blocks (1e-8 in log rho
from the direct products, tests/design/test_hold_certificate.py) decide. Where the monodromy's
norm proves its radius below :data:`EXACT_ABOVE`, no eigenvalue is computed.
"""
from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit
from scipy.linalg import expm

from ..base.rotations import skew_field
from .model import AttitudeLTP

#: Largest scale step of the certificate's grid (the stated resolution in k).
STEP = 0.005
#: Relative guard band past the required margin (10x the eigenvalue's error in k near the boundary).
GUARD = 0.005
#: Largest intervals in one polynomial block.
BLOCK_MAX = 16
#: Largest growth factor of a block's coefficient magnitudes over a direct product's (module docstring).
BLOCK_GROWTH = 64.0
#: Below this the monodromy's norm bound stands for its radius (no eigenvalues computed).
EXACT_ABOVE = 1e-2
#: A period with a multiplier on the grid within this factor of 1 is recomputed with direct products: near
#: the boundary the verdict comes from the tuner's arithmetic; elsewhere the blocks' 1e-8 in log rho decides.
DIRECT_BAND = 2.0


@njit(cache=True, nogil=True, fastmath=True)
def _block_products(Ad, B, ks, block_max, growth):  # pragma: no cover - compiled; checked against direct products
    """prod_i (Ad + k B_i) for every k of ``ks`` (the latest interval on the left), by polynomial blocks
    in d = k - kc around the grid's centre kc (module docstring): (M (6, 6, nk) renormalized per k, log
    of the scale factors (nk,))."""
    N, nk = B.shape[0], ks.size
    kc = 0.5 * (np.max(ks) + np.min(ks))
    dmax = 0.5 * (np.max(ks) - np.min(ks))
    M = np.zeros((6, 6, nk))
    for r in range(6):
        M[r, r, :] = 1.0
    Mn = np.empty((6, 6, nk))
    VT = np.empty((block_max + 1, nk))  # powers of k - kc, degree by row
    VT[0, :] = 1.0
    for d in range(1, block_max + 1):
        for q in range(nk):
            VT[d, q] = VT[d - 1, q] * (ks[q] - kc)
    logs = np.zeros(nk)
    C = np.zeros((block_max + 1, 6, 6))
    T = np.empty((6, 6))
    A = np.empty((6, 6))
    i = 0
    while i < N:
        C[:] = 0.0
        for r in range(6):
            C[0, r, r] = 1.0
        deg = 0
        bound = 1.0
        while i < N and deg < block_max:
            na = 0.0
            nb = 0.0
            for r in range(6):
                sa = 0.0
                sb = 0.0
                for c in range(6):
                    A[r, c] = Ad[r, c] + kc * B[i, r, c]
                    sa += abs(A[r, c])
                    sb += abs(B[i, r, c])
                na = max(na, sa)
                nb = max(nb, sb)
            f = 1.0 + dmax * nb / na
            if deg > 0 and bound * f > growth:
                break
            bound *= f
            for d in range(deg + 1, -1, -1):  # C_d <- A_i C_d + B_i C_{d-1}, highest degree first
                for r in range(6):
                    for c in range(6):
                        acc = 0.0
                        if d <= deg:
                            for j in range(6):
                                acc += A[r, j] * C[d, j, c]
                        if d >= 1:
                            for j in range(6):
                                acc += B[i, r, j] * C[d - 1, j, c]
                        T[r, c] = acc
                C[d] = T
            deg += 1
            i += 1
        # P(k) = sum_d (k - kc)^d C_d at every k: one matrix product with the powers (BLAS)
        P2 = np.dot(np.ascontiguousarray(C[: deg + 1].reshape(deg + 1, 36).T), VT[: deg + 1])
        P = P2.reshape(6, 6, nk)
        for r in range(6):  # M <- P M
            for c in range(6):
                for q in range(nk):
                    Mn[r, c, q] = 0.0
                for j in range(6):
                    for q in range(nk):
                        Mn[r, c, q] += P[r, j, q] * M[j, c, q]
        for q in range(nk):  # renormalize every block (keeps unstable products finite)
            s = 0.0
            for r in range(6):
                for c in range(6):
                    s = max(s, abs(Mn[r, c, q]))
            if s > 0.0 and np.isfinite(s):
                for r in range(6):
                    for c in range(6):
                        M[r, c, q] = Mn[r, c, q] / s
                logs[q] += np.log(s)
            else:
                for r in range(6):
                    for c in range(6):
                        M[r, c, q] = Mn[r, c, q]
    return M, logs


def scan_products(Ad, B, ks, block_max: int = BLOCK_MAX, growth: float = BLOCK_GROWTH,
                  exact_above: float = 0.0) -> np.ndarray:
    """Largest |characteristic multiplier| of prod_i (Ad + k B_i) for every k of ``ks``.

    Parameters
    ----------
    Ad : ndarray (6, 6)
        Open-loop map over one interval.
    B : ndarray (N, 6, 6)
        Gamma_i K per interval.
    ks : ndarray (nk,)
        Scales of the gain.
    block_max : int
        Largest intervals per polynomial block (1: direct products).
    growth : float
        Largest coefficient growth of a block (module docstring).
    exact_above : float
        Where the monodromy's infinity norm (an upper bound on rho) is below this, return the bound
        instead of the eigenvalues (0: eigenvalues everywhere); the first scale's is always exact.

    Returns
    -------
    ndarray (nk,)
        rho per scale (or its norm bound, below ``exact_above``); inf where the product is not finite.
    """
    M, logs = _block_products(np.ascontiguousarray(Ad, dtype=float), np.ascontiguousarray(B, dtype=float),
                              np.ascontiguousarray(ks, dtype=float), int(block_max), float(growth))
    M = np.moveaxis(M, -1, 0)
    rho = np.full(len(ks), np.inf)
    with np.errstate(all="ignore"):
        ok = np.all(np.isfinite(M), axis=(1, 2))
        bound = np.exp(np.log(np.abs(M).sum(axis=-1).max(axis=-1)) + logs)
        cheap = ok & (bound < exact_above)
        cheap[0] = False  # rho at the first scale (K itself) always exactly
        rho[cheap] = bound[cheap]
        need = ok & ~cheap
        if need.any():
            ev = np.abs(np.linalg.eigvals(M[need])).max(axis=-1)
            rho[need] = np.exp(np.log(np.maximum(ev, 1e-300)) + logs[need])
    return rho


def admissible_intervals(period: float, ts_min: float, ts_max: float) -> np.ndarray:
    """Every number of hold intervals per orbit a flight at a sample period in [ts_min, ts_max] is modelled by.

    Parameters
    ----------
    period : float
        Orbit (model) period T [s].
    ts_min, ts_max : float
        Sample-period range [s].

    Returns
    -------
    ndarray of int
        N = round(T / ts_max) .. round(T / ts_min), ascending (at least 1); the periods are T / N.
    """
    lo = max(1, int(round(period / float(ts_max))))
    hi = max(lo, int(round(period / float(ts_min))))
    return np.arange(lo, hi + 1)


def scale_grid(gain_margin: float, step: float = STEP, guard: float = GUARD) -> np.ndarray:
    """The certificate's scales: uniform from 1 to gain_margin x (1 + guard), step at most ``step``.

    Parameters
    ----------
    gain_margin : float
        Required margin (>= 1).
    step : float
        Largest step.
    guard : float
        Relative guard band past the margin.

    Returns
    -------
    ndarray
        Scales, 1 first and gain_margin (1 + guard) last.
    """
    top = float(gain_margin) * (1.0 + float(guard))
    n = max(1, int(math.ceil((top - 1.0) / float(step) - 1e-9)))
    return np.linspace(1.0, top, n + 1)


@lru_cache(maxsize=4)
def _gauss(nodes: int):
    """Gauss-Legendre nodes and weights on [-1, 1] (0.7 ms a call: a fifth of a constant field's period)."""
    return np.polynomial.legendre.leggauss(nodes)


def interval_maps(model: AttitudeLTP, n: int, nodes: int = 4, panel: float = 2.5, count: int | None = None,
                  exponential: Exponential | None = None):
    """Ad and the held-torque maps Gamma_i of the held loop with h = T / n (:class:`.sampled.SampledLoop`'s rule).

    The same quadrature as :meth:`.sampled.SampledLoop.build` (composite Gauss-Legendre, panels of
    at most ``panel`` s), with the node exponentials from :class:`Exponential`.

    Parameters
    ----------
    model : AttitudeLTP
        Design model.
    n : int
        Intervals per orbit.
    nodes : int
        Gauss-Legendre nodes per panel.
    panel : float
        Longest panel [s].
    count : int or None
        Build the first ``count`` intervals only (None: all n).
    exponential : Exponential or None
        e^{A t} of the model's A, built once by the caller (None: built here).

    Returns
    -------
    (ndarray (6, 6), ndarray (count, 6, 3))
        Ad = e^{A h} and Gamma_i (x_{i+1} = (Ad + Gamma_i K) x_i).
    """
    T = model.period
    h = T / n
    p = max(1, int(np.ceil(h / panel)))
    x, w = _gauss(nodes)
    s = ((np.arange(p)[:, None] + 0.5 * (x + 1.0)) * (h / p)).ravel()
    w = np.tile(0.5 * (h / p) * w, p)
    E = (exponential or Exponential.of(model.A))(np.append(h - s, h))
    Ad, E = E[-1], E[:-1] @ model.BT  # (nodes, 6, 3)
    tk = np.arange(n if count is None else min(n, int(count))) * h
    S = skew_field(model.field(tk[:, None] + s[None, :]))  # (n, nodes, 3, 3)
    G = np.matmul((w[:, None, None] * E)[None], S).sum(axis=1)  # (n, 6, 3)
    b0 = model.field(tk)
    Ck = np.swapaxes(skew_field(b0), -1, -2) / np.sum(b0**2, axis=-1)[:, None, None]
    return Ad, G @ Ck


@dataclass(frozen=True)
class Exponential:
    """t -> e^{A t} for many t, by the eigendecomposition of A when it is well conditioned (the attitude
    model's A has six distinct eigenvalues, cond(V) ~300: 3e-14 from scipy's expm, which costs ~4 ms a
    call and was a third of the scan), else scipy's ``expm`` one by one. Built once per model."""

    A: np.ndarray
    w: np.ndarray | None = None
    V: np.ndarray | None = None
    Vi: np.ndarray | None = None

    @classmethod
    def of(cls, A) -> "Exponential":
        """The exponential of ``A`` (its eigendecomposition when usable).

        Parameters
        ----------
        A : ndarray (n, n)
            Real matrix.

        Returns
        -------
        Exponential
            Callable on an array of times.
        """
        A = np.asarray(A, dtype=float)
        w, V = np.linalg.eig(A)
        if np.linalg.cond(V) < 1e6 and len(np.unique(np.round(w, 12))) == len(w):
            return cls(A, w, V, np.linalg.inv(V))
        return cls(A)

    def __call__(self, taus) -> np.ndarray:
        """e^{A tau} for every tau: (m, n, n)."""
        taus = np.asarray(taus, dtype=float)
        if self.w is None:
            return np.stack([expm(self.A * t) for t in taus])
        return np.real((self.V[None] * np.exp(self.w[None, :] * taus[:, None])[:, None, :]) @ self.Vi)


def _power_radius(P, n: int, exact_above: float) -> np.ndarray:
    """rho(P_q)^n for each matrix P_q (a constant field's one interval map): the infinity norm of P_q^n
    (binary powers, renormalized) where it proves the radius below ``exact_above``, else n log rho(P_q)
    from the eigenvalues (always for the first: rho(K) is reported exactly)."""
    P = np.asarray(P, dtype=float)
    M = np.broadcast_to(np.eye(P.shape[-1]), P.shape).copy()
    logm, logb = np.zeros(len(P)), np.zeros(len(P))
    base, e = P.copy(), int(n)
    with np.errstate(all="ignore"):
        while e:
            if e & 1:
                M = base @ M
                sc = np.abs(M).max(axis=(1, 2))
                M, logm = M / sc[:, None, None], logm + logb + np.log(sc)
            e >>= 1
            if e:
                base = base @ base
                sc = np.abs(base).max(axis=(1, 2))
                base, logb = base / sc[:, None, None], 2.0 * logb + np.log(sc)
        bound = np.exp(np.log(np.abs(M).sum(axis=-1).max(axis=-1)) + logm)
        need = ~(np.isfinite(bound) & (bound < exact_above))
        need[0] = True
        rho = bound.copy()
        ev = np.abs(np.linalg.eigvals(P[need])).max(axis=-1)
        rho[need] = np.exp(n * np.log(np.maximum(ev, 1e-300)))
    return rho


def _scan_one(model, n, K, ks, exponential=None):
    constant = bool(getattr(model.field, "is_constant", False))
    Ad, Gamma = interval_maps(model, n, count=1 if constant else None, exponential=exponential)
    B = Gamma @ K
    if constant:  # one map repeated: rho = rho(Ad + k B_0)^n
        return _power_radius(Ad[None] + ks[:, None, None] * B[0][None], n, EXACT_ABOVE), False
    rho = scan_products(Ad, B, ks, exact_above=EXACT_ABOVE)
    direct = bool(np.any((rho > 1.0 / DIRECT_BAND) & (rho < DIRECT_BAND)))
    if direct:
        rho = scan_products(Ad, B, ks, block_max=1)
    return rho, direct


@dataclass(frozen=True)
class HoldCertificate:
    """What the exhaustive scan proved of one gain (module docstring): per admissible period, the
    largest multiplier over the scale grid and the first unstable scale.

    Attributes
    ----------
    gain_margin, step, guard : float
        The requirement and the grid's resolution.
    max_multiplier : float
        Bound on rho(K) at every period (1: stable only).
    scales : ndarray (nk,)
        The grid, 1 .. gain_margin (1 + guard).
    periods : ndarray (m,)
        The admissible periods T / N [s], descending (N ascending).
    rho_max : ndarray (m,)
        Largest |multiplier| over the grid, per period.
    rho_gain : ndarray (m,)
        |multiplier| with K itself, per period.
    first_unstable : ndarray (m,)
        First grid scale with rho >= 1 per period (inf: none).
    direct : int
        Periods recomputed with direct products.
    seconds : float
        Wall time of the scan.
    unstable : tuple of (float, float)
        (period [s], scale) where the grid found the loop unstable (the tuner's cutting planes).
    """

    gain_margin: float
    step: float
    guard: float
    max_multiplier: float
    scales: np.ndarray
    periods: np.ndarray
    rho_max: np.ndarray
    rho_gain: np.ndarray
    first_unstable: np.ndarray
    direct: int
    seconds: float
    unstable: tuple = ()  # (period, scale) pairs found unstable: first, middle and last per failing period

    @property
    def top(self) -> float:
        """The largest scale checked.

        Returns
        -------
        float
            gain_margin (1 + guard), the grid's last scale.
        """
        return float(self.scales[-1])

    @property
    def margin(self) -> float:
        """The certified margin.

        Returns
        -------
        float
            The largest grid scale below which every grid scale is stable at every period (``top`` when
            none is unstable; 0 when K itself is).
        """
        f = float(np.min(self.first_unstable))
        if not np.isfinite(f):
            return self.top
        i = int(np.searchsorted(self.scales, f))
        return float(self.scales[i - 1]) if i > 0 else 0.0

    @property
    def tightest(self) -> int:
        """Where the requirement is closest to failing.

        Returns
        -------
        int
            Index of the period with the smallest first unstable scale (else with the largest multiplier).
        """
        if np.isfinite(self.first_unstable).any():
            return int(np.argmin(self.first_unstable))
        return int(np.argmax(self.rho_max))

    @property
    def met(self) -> bool:
        """Whether the requirement holds.

        Returns
        -------
        bool
            Every grid scale stable at every period, and rho(K) below ``max_multiplier``.
        """
        return bool(not np.isfinite(self.first_unstable).any() and np.all(self.rho_gain < self.max_multiplier))

    def provenance(self) -> dict:
        """What a gains file records of the certificate.

        Returns
        -------
        dict
            ``hold_margin_min`` (certified margin), ``hold_tightest_ts`` (its period), ``hold_rho_max`` (the
            largest multiplier over the grid, every period), ``hold_multiplier_max`` / ``hold_multiplier_ts``
            (rho(K)) and ``hold_certificate`` (resolution, periods, guard, seconds).
        """
        i, j = self.tightest, int(np.argmax(self.rho_gain))
        return {"hold_margin_min": round(self.margin, 4), "hold_tightest_ts": round(float(self.periods[i]), 4),
                "hold_rho_max": float(f"{float(np.max(self.rho_max)):.4g}"),
                "hold_multiplier_max": float(f"{float(self.rho_gain[j]):.4g}"),
                "hold_multiplier_ts": round(float(self.periods[j]), 4),
                "hold_certificate": {"periods": int(len(self.periods)), "scale_step": float(f"{self.step:.6g}"),
                                     "scale_top": round(self.top, 6), "guard": float(self.guard),
                                     "ts_first": round(float(self.periods[-1]), 6),
                                     "ts_last": round(float(self.periods[0]), 6),
                                     "seconds": round(self.seconds, 1)}}


def certify_hold(model: AttitudeLTP, K, ts_min: float, ts_max: float, gain_margin: float,
                 max_multiplier: float = 1.0, *, step: float = STEP, guard: float = GUARD,
                 workers: int = 2) -> HoldCertificate:
    """Scan the held loop of ``K`` at every admissible period and every grid scale (module docstring).

    Parameters
    ----------
    model : AttitudeLTP
        Design model.
    K : array_like (3, 6)
        Gain.
    ts_min, ts_max : float
        Sample-period range [s].
    gain_margin : float
        Required margin (>= 1).
    max_multiplier : float
        Bound on rho(K) (1: stability only).
    step, guard : float
        Grid step and guard band (:func:`scale_grid`).
    workers : int
        Threads scanning periods (the compiled kernel releases the GIL).

    Returns
    -------
    HoldCertificate
        Per-period figures and the verdict.

    Raises
    ------
    ValueError
        If ``gain_margin`` < 1 or ``step`` is not in (0, 0.05].
    """
    if not gain_margin >= 1.0:
        raise ValueError(f"certify_hold: gain_margin must be >= 1, got {gain_margin}")
    if not 0.0 < step <= 0.05:
        raise ValueError(f"certify_hold: step must be in (0, 0.05], got {step}")
    t0 = time.perf_counter()
    K = np.asarray(K, dtype=float).reshape(3, 6)
    ks = scale_grid(gain_margin, step, guard)
    ns = admissible_intervals(model.period, ts_min, ts_max)
    pool = ThreadPoolExecutor(max(1, int(workers)))
    try:
        expo = Exponential.of(model.A)
        out = list(pool.map(lambda n: _scan_one(model, int(n), K, ks, expo), ns))
    finally:  # a stop request (Ctrl-C) cancels the periods not started instead of waiting for them
        pool.shutdown(wait=True, cancel_futures=True)
    rho = np.array([r for r, _ in out])
    unstable = rho >= 1.0
    first = np.where(unstable.any(axis=1), ks[np.argmax(unstable, axis=1)], np.inf)
    periods = model.period / ns
    pts = []
    for i in np.flatnonzero(unstable.any(axis=1)):
        kk = ks[unstable[i]]
        pts += [(float(periods[i]), k) for k in sorted({float(kk[0]), float(kk[len(kk) // 2]), float(kk[-1])})]
    return HoldCertificate(float(gain_margin), float(ks[1] - ks[0]) if len(ks) > 1 else float(step), float(guard),
                           float(max_multiplier), ks, periods, rho.max(axis=1), rho[:, 0], first,
                           int(sum(d for _, d in out)), time.perf_counter() - t0, tuple(pts))


def compile_all() -> None:
    """Compile (or load from numba's cache) the certificate's kernel: ``scripts/bootstrap.sh`` calls it
    at install time, so a certificate's ``seconds`` is its scan, not the compilation (~8 s)."""
    scan_products(np.eye(6), np.zeros((2, 6, 6)), np.linspace(1.0, 2.0, 3))
