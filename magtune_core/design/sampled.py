"""The sample-and-hold loop of a projection-based gain, as a discrete linear periodic system.

The paper tunes K on the continuous-time LTP model (eqs. 19-21) and then implements it "in
digital form, using a conventional sample and hold scheme" (section 5): at t_k = k Ts the
controller reads x_k and b_k = b(t_k), commands m_k = S(b_k)^T K x_k / |b_k|^2 (eq. 17) and
holds it, so the torque over the interval is S(b(t)) m_k, not the projection of eq. (18). Over
one interval the linearized closed loop is exactly

    x_{k+1} = (Ad + Gamma_k K) x_k,   Ad = e^{A h},
    Gamma_k = int_0^h e^{A (h - s)} B_T S(b(t_k + s)) ds  S(b_k)^T / |b_k|^2,

and the product of the N = T / h interval maps is the monodromy of the sampled loop; its
spectral radius decides stability of the digital controller (Bittanti & Colaneri, periodic
systems, ch. 6). Gamma_k does not depend on K, so it is built once per model and Ts and a batch
of gains costs N batched 6x6 products.

Decision (docs/decisions.md, "J is minimized under a sample-and-hold gain margin of 2"): T is rarely a multiple of Ts, so the interval is
h = T / round(T / Ts) (relative change below Ts / (2 T), 1e-4 at Ts = 1 s); the integral is a
composite 4-point Gauss-Legendre rule on panels of at most 2.5 s (one panel at Ts = 1 s; checked
against scipy's ZOH discretization and a dense RK4 integration in tests/design/test_sampled.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.linalg import expm

from ..base.rotations import skew_field
from ..onboard.params import TS_DEFAULT
from .model import AttitudeLTP

_RESCALE_EVERY = 32  #: interval products between renormalizations (keeps unstable products finite)


@njit(cache=True)
def interval_map(Ad, Gk, K, P):  # pragma: no cover - compiled
    """P = Ad + Gk K in place: the held loop's map over one interval (module docstring)."""
    for i in range(6):
        for j in range(6):
            acc = Ad[i, j]
            for c in range(3):
                acc += Gk[i, c] * K[c, j]
            P[i, j] = acc


@njit(cache=True)
def _held_products(Ad, Gamma, Ks):  # pragma: no cover - compiled; checked against numpy in the tests
    """prod_k (Ad + Gamma_k K) for each gain, renormalized every _RESCALE_EVERY intervals:
    (M (n, 6, 6), log of the scale factors (n,)). Compiled: 5,615 6x6 products per gain in numpy
    cost ~10 ms per gain in Python overhead, here ~1 ms."""
    n, N = Ks.shape[0], Gamma.shape[0]
    M = np.zeros((n, 6, 6))
    logscale = np.zeros(n)
    P = np.empty((6, 6))
    T = np.empty((6, 6))
    for g in range(n):
        for i in range(6):
            M[g, i, i] = 1.0
        for k in range(N):
            interval_map(Ad, Gamma[k], Ks[g], P)
            for i in range(6):
                for j in range(6):
                    acc = 0.0
                    for c in range(6):
                        acc += P[i, c] * M[g, c, j]
                    T[i, j] = acc
            M[g] = T
            if (k + 1) % _RESCALE_EVERY == 0:
                s = 0.0
                for i in range(6):
                    for j in range(6):
                        s = max(s, abs(M[g, i, j]))
                if s > 0.0 and np.isfinite(s):
                    M[g] /= s
                    logscale[g] += np.log(s)
    return M, logscale


@dataclass(frozen=True)
class SampledLoop:
    """Interval maps of the sample-and-hold loop of one model at one sample period.

    Attributes
    ----------
    ts : float
        The interval h actually used, T / round(T / Ts) [s].
    Ad : ndarray (6, 6)
        e^{A h}, the open-loop map over one interval.
    Gamma : ndarray (N, 6, 3)
        Held-torque input maps, x_{k+1} = (Ad + Gamma_k K) x_k.
    G : ndarray (N, 6, 3)
        Held-dipole input maps: a dipole m held over interval k moves the state by G_k m
        (Gamma_k = G_k C_k; a constant residual dipole enters the same way).
    C : ndarray (N, 3, 3)
        S(b_k)^T / |b_k|^2: the commanded dipole is m_k = C_k K x_k (eq. 17).
    """

    ts: float
    Ad: np.ndarray
    Gamma: np.ndarray
    G: np.ndarray | None = None
    C: np.ndarray | None = None

    @classmethod
    def build(cls, model: AttitudeLTP, ts: float, nodes: int = 4, panel: float = 2.5) -> "SampledLoop":
        """Interval maps for sample period ``ts`` (see module docstring for the rule).

        Parameters
        ----------
        model : AttitudeLTP
            Design model.
        ts : float
            Requested sample period [s] (the interval used is T / round(T / ts)).
        nodes : int
            Gauss-Legendre nodes per panel.
        panel : float
            Longest quadrature panel [s].

        Returns
        -------
        SampledLoop
            ts = h, Ad, Gamma, G, C of the held loop over one period.
        """
        T = model.period
        n = max(1, int(round(T / float(ts))))
        h = T / n
        A = model.A
        # composite Gauss-Legendre: panels of <= `panel` seconds, so (nutation rate x panel)^8 / 8!
        # stays below 1e-13 (a single 4-point rule over 60 s was 1e-3 off: test_sampled.py)
        p = max(1, int(np.ceil(h / panel)))
        x, w = np.polynomial.legendre.leggauss(nodes)
        s = ((np.arange(p)[:, None] + 0.5 * (x + 1.0)) * (h / p)).ravel()
        w = np.tile(0.5 * (h / p) * w, p)
        # scipy's expm node by node (~4 p calls): the batched ltp.expm is 30x faster but differs by
        # round-off, which moves gains tuned onto the margin boundary across it (docs/decisions.md)
        E = np.stack([expm(A * (h - sj)) @ model.BT for sj in s])  # (p nodes, 6, 3)
        tk = np.arange(n) * h
        G = np.zeros((n, 6, 3))
        for j in range(len(s)):  # node by node: memory n x 3 x 3, not n x nodes x 3 x 3
            G += w[j] * np.einsum("ab,kbc->kac", E[j], skew_field(model.field(tk + s[j])))
        b0 = model.field(tk)
        Ck = np.swapaxes(skew_field(b0), -1, -2) / np.sum(b0**2, axis=-1)[:, None, None]
        return cls(ts=h, Ad=expm(A * h), Gamma=G @ Ck, G=G, C=Ck)

    @classmethod
    def at(cls, model: AttitudeLTP, periods, cache: dict | None = None) -> list:
        """The loops at ``periods`` [s], reusing and filling ``cache`` ({ts: SampledLoop} of this one
        model): the dense scans of a tuning (cutting planes, provenance) share their ~100 loops.

        Parameters
        ----------
        model : AttitudeLTP
            Design model.
        periods : iterable of float
            Sample periods [s].
        cache : dict or None
            {ts: SampledLoop} of this model, read and filled; None: a fresh one.

        Returns
        -------
        list of SampledLoop
            One per period, in order.
        """
        cache = {} if cache is None else cache
        out = []
        for t in periods:
            t = float(t)
            if t not in cache:
                cache[t] = cls.build(model, t)
            out.append(cache[t])
        return out

    @property
    def intervals(self) -> int:
        """Number of hold intervals in one orbit period.

        Returns
        -------
        int
            N = len(Gamma).
        """
        return len(self.Gamma)

    def spectral_radius(self, Ks) -> np.ndarray:
        """Max |characteristic multiplier| of the sampled loop over one period, per gain.

        Parameters
        ----------
        Ks : array_like (n, 3, 6)
            Gains (any shape with a multiple of 18 entries).

        Returns
        -------
        ndarray (n,)
            rho of prod_k (Ad + Gamma_k K); inf where the product overflows or is not finite.
        """
        Ks = np.ascontiguousarray(np.asarray(Ks, dtype=float).reshape(-1, 3, 6))
        n = len(Ks)
        M, logscale = _held_products(self.Ad, np.ascontiguousarray(self.Gamma), Ks)
        with np.errstate(all="ignore"):
            rho = np.full(n, np.inf)
            ok = np.all(np.isfinite(M), axis=(1, 2))
            if ok.any():
                ev = np.abs(np.linalg.eigvals(M[ok])).max(axis=-1)
                rho[ok] = np.exp(np.log(np.maximum(ev, 1e-300)) + logscale[ok])
        return rho


def sampled_margin_ok(loop: SampledLoop, Ks, gain_margin: float) -> np.ndarray:
    """Whether the sampled loop stays stable with every gain scaled by ``gain_margin``, per gain.

    Parameters
    ----------
    loop : SampledLoop
        Held loop of one model at one sample period.
    Ks : array_like (n, 3, 6)
        Gains.
    gain_margin : float
        Factor the gains are multiplied by.

    Returns
    -------
    ndarray of bool (n,)
        rho(prod_k (Ad + Gamma_k g K)) < 1 with g = gain_margin.
    """
    return loop.spectral_radius(gain_margin * np.asarray(Ks, dtype=float).reshape(-1, 3, 6)) < 1.0


@dataclass(frozen=True)
class HoldConstraint:
    """Feasibility of a gain for its digital implementation: the sample-and-hold loop at ``ts``
    stays stable with the gain multiplied by ``gain_margin`` (2 = the classical 6 dB).

    Why (docs/tuning.md, "What is minimized"): J alone rewards loop gain without bound at large
    sigma (the infimum needs unbounded gains, as in the constant-field case), and the J-optimal
    gains of sigma = 120 / 240 are unstable when held at Ts = 1 s.
    """

    ts: float = TS_DEFAULT
    gain_margin: float = 2.0

    def __post_init__(self):
        if not (np.isfinite(self.ts) and self.ts > 0):
            raise ValueError(f"hold constraint: ts must be positive, got {self.ts}")
        if not (np.isfinite(self.gain_margin) and self.gain_margin >= 1):
            raise ValueError(f"hold constraint: gain_margin must be >= 1, got {self.gain_margin}")

    def screen(self, model: AttitudeLTP) -> "HoldScreen":
        """The check of this constraint on one model (:class:`HoldScreen`).

        Parameters
        ----------
        model : AttitudeLTP
            Design model.

        Returns
        -------
        HoldScreen
            The held loop of ``model`` at ``ts`` and the gain margin.
        """
        return HoldScreen(SampledLoop.build(model, self.ts), self.gain_margin)


@dataclass(frozen=True)
class HoldScreen:
    """Callable Ks (n, 3, 6) -> bool (n,): the held loop meets the gain margin (one model, one Ts).
    The single-period case of ``.requirements.FlightScreen``; picklable (sent to the tuner's workers)."""

    loop: SampledLoop
    gain_margin: float

    def __call__(self, Ks) -> np.ndarray:
        """Whether each gain's held loop is stable with the gain times ``gain_margin``."""
        return sampled_margin_ok(self.loop, Ks, self.gain_margin)


def hold_gain_margin(loop: SampledLoop, K, upper: float = 16.0, points: int = 48, rtol: float = 1e-3) -> float:
    """Largest factor g in (0, upper] with a stable sampled loop for every g' in [1, g], of one gain.

    A geometric grid of ``points`` factors in [1, upper] is evaluated as one batch, then the first
    crossing is narrowed to ``rtol`` (four factors per batch). The result is the largest factor
    known stable, so it is at most ``rtol`` below the true margin. 0.0 if K itself is unstable
    when held, ``upper`` if no factor of the grid destabilizes it.

    Accuracy: ~1e-3, not round-off. On the boundary a fast mode rings near the Nyquist rate, so
    rho = |z|^N with N = 5,615 intervals: ln rho moves ~10^4 times faster than ln g, and the
    explicit monodromy is strongly non-normal (||M|| / rho ~ 1e4), so its largest eigenvalue
    carries a relative error of order one within ~2e-4 of the boundary (seen: 1.9993 vs 2.0002
    for the same gain with two summation orders). A gain tuned for margin 2 shows 2 +- 1e-3.

    Parameters
    ----------
    loop : SampledLoop
        Held loop of one model at one sample period.
    K : array_like (3, 6)
        Gain.
    upper : float
        Largest factor tested.
    points : int
        Factors of the first geometric grid.
    rtol : float
        Relative width to which the crossing is narrowed.

    Returns
    -------
    float
        The sampled-data gain margin (a factor, not dB) of K at ``loop.ts``.
    """
    K = np.asarray(K, dtype=float).reshape(3, 6)
    g = np.geomspace(1.0, upper, points)
    bad = loop.spectral_radius(g[:, None, None] * K) >= 1.0
    if bad[0]:
        return 0.0
    if not bad.any():
        return float(upper)
    i = int(np.argmax(bad))
    lo, hi = g[i - 1], g[i]
    while hi / lo > 1.0 + rtol:
        mids = np.geomspace(lo, hi, 6)[1:-1]
        b = loop.spectral_radius(mids[:, None, None] * K) >= 1.0
        j = int(np.argmax(b)) if b.any() else len(mids)
        lo = mids[j - 1] if j > 0 else lo
        hi = mids[j] if j < len(mids) else hi
    return float(lo)


def feasible_start(model, K0, hold, shrink: float = 0.95, tries: int = 90):
    """A start gain meeting ``hold`` (a HoldConstraint or ``.requirements.Requirements``): K0 itself,
    or K0 scaled down by the largest factor that meets it
    among 1 - 1e-4 2^i (i = 0..8) and shrink^j (j = 1..tries).

    The fine factors first: a gain tuned on the constraint (the shipped optima, margin 2 +- 1e-3)
    can fail the check by round-off (:func:`hold_gain_margin`: the monodromy is strongly non-normal
    there; the sigma = 120 gain tuned with the numpy product fails the compiled one, rho 2.75 at
    2 K), and 0.9999 K then keeps its J, where 0.95 K would cost ~1 %.

    ``model`` is one AttitudeLTP or a sequence (a robust model set): a scaling counts only where
    every model's held loop meets the margin, checked together (feasibility need not be monotone
    in the scale, so scaling model by model in turn could undo an earlier model's check).

    Parameters
    ----------
    model : AttitudeLTP or sequence of AttitudeLTP
        Design model(s).
    K0 : array_like (3, 6)
        Start gain.
    hold : HoldConstraint or Requirements
        Constraint with a ``screen(model)`` method.
    shrink : float
        Ratio of the coarse scale factors.
    tries : int
        Number of coarse factors.

    Returns
    -------
    (ndarray (3, 6), str)
        The gain and a note ("" if K0 already meets the constraint).

    Raises
    ------
    ValueError
        If no factor down to the smallest meets the constraint on every model.
    """
    models = (model,) if isinstance(model, AttitudeLTP) else tuple(model)
    K0 = np.asarray(K0, dtype=float).reshape(3, 6)
    screens = [hold.screen(m) for m in models]
    fine = 1.0 - 1e-4 * 2.0 ** np.arange(9)
    coarse = shrink ** np.arange(1, tries + 1)
    f = np.concatenate([[1.0], fine, coarse[coarse < fine[-1]]])
    for chunk in np.array_split(np.arange(len(f)), -(-len(f) // 8)):  # batches of 8: the largest feasible
        ok = np.ones(len(chunk), dtype=bool)
        for screen in screens:
            if ok.any():
                ok[ok] = screen(f[chunk[ok], None, None] * K0)
        if ok.any():
            j = int(chunk[np.argmax(ok)])
            return (K0, "") if j == 0 else (f[j] * K0, f"scaled by {f[j]:.5g}")
    raise ValueError(f"no scaling of the start gain down to {f[-1]:.2g} meets " + (
        hold.describe() if hasattr(hold, "describe") else
        f"the hold constraint (gain margin {hold.gain_margin:g} at Ts = {hold.ts:g} s)"))


def hold_provenance(model: AttitudeLTP, K, ts: float, gain_margin: float) -> dict:
    """What a gains file records about its digital implementation: the constraint it was tuned
    under (0 = none) and the achieved sample-and-hold gain margin at ``ts``.

    Parameters
    ----------
    model : AttitudeLTP
        Design model.
    K : array_like (3, 6)
        Gain.
    ts : float
        Sample period [s].
    gain_margin : float
        Gain margin the gain was tuned under (0: none).

    Returns
    -------
    dict
        {"hold_gain_margin_required": float, "hold_gain_margin": achieved margin rounded to 3 decimals}.
    """
    loop = SampledLoop.build(model, ts)
    return {"hold_gain_margin_required": float(gain_margin),
            "hold_gain_margin": round(hold_gain_margin(loop, K), 3)}
