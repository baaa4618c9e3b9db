"""Exact H-infinity norm of LTP systems: a periodic Riccati gamma-test, bisected.

For gamma > sup_t ||D(t)||, ||G||_inf < gamma iff the periodic H-infinity Riccati equation
(bounded real lemma, e.g. Bittanti & Colaneri 2009, ch. 9)

    -X' = A_g^T X + X A_g + X B R^-1 B^T X + C^T (I + D R^-1 D^T) C,   R = gamma^2 I - D^T D

has a bounded, stabilizing, periodic solution X(t) >= 0 over the whole period. Equivalently,
the finite-horizon Riccati solution (terminal X = 0) exists on every horizon, with no
conjugate point, and converges. That is what we test, with no product over the long period:

* each interval of the Hamiltonian flow [x; p]' = H(t) [x; p] is taken in scattering
  ("standard symplectic") form  x1 = E x0 + G p1,  p0 = Hs x0 + F p1  (G, Hs >= 0);
* intervals are joined by the Redheffer star product (pairwise tree over the period, then
  repeated doubling over 2^k periods, as in the structured doubling algorithm); a conjugate
  point shows up as an eigenvalue of G_a Hs_b reaching 1 at some junction;
* the gamma-test passes when every junction stays below 1 and the long-horizon E has decayed
  (the Riccati solution X(0) = Hs is stabilizing).

Checking only "no Hamiltonian multiplier on the unit circle" can pass for gamma below the norm
(the stable subspace may lose its graph form inside the period); the junction test above
catches exactly that, on every horizon that starts at a multiple of the period, which suffices
because any finite-horizon gain window lies inside such a horizon (periodicity).
"""
from __future__ import annotations

import numpy as np

from .htf import lti_hinfnorm
from .system import DEFAULT_STEPS, LTPSystem, generator_at_nodes, magnus_exponentials

MAX_DOUBLINGS = 48
_CONVERGED = 1e-13


def hamiltonian(sys: LTPSystem, gamma, t) -> np.ndarray:
    """The (balanced) H-infinity Hamiltonian at times t, shape (*batch, len(t), 2n, 2n); gamma broadcast."""
    A, B, C = sys.sample("A", t), sys.sample("B", t), sys.sample("C", t)
    g2 = (np.asarray(gamma, dtype=float) ** 2)[..., None, None, None]
    if sys.has_feedthrough:
        D = sys.sample("D", t)
        R = g2 * np.eye(D.shape[-1]) - np.swapaxes(D, -1, -2) @ D
        RinvBt = _safe_solve(R, np.swapaxes(B, -1, -2))  # NaN (test fails) at gamma = ||D||
        RinvDtC = _safe_solve(R, np.swapaxes(D, -1, -2) @ C)
        Ag = A + B @ RinvDtC
        G = B @ RinvBt
        Q = np.swapaxes(C, -1, -2) @ C + np.swapaxes(C, -1, -2) @ D @ RinvDtC
    else:
        Ag = A
        G = (B @ np.swapaxes(B, -1, -2)) / g2
        Q = np.swapaxes(C, -1, -2) @ C
    # Balance p = alpha p' so both off-diagonal blocks have the same size: the Hamiltonian's
    # norm drops by orders of magnitude (fewer squarings in expm, better accuracy); conjugate
    # points, signs and the convergence test are invariant (X' = X / alpha).
    gq = np.max(np.abs(Q), axis=(-3, -2, -1)), np.max(np.abs(G), axis=(-3, -2, -1))
    alpha = np.sqrt(np.where((gq[0] > 0) & (gq[1] > 0), gq[0] / np.where(gq[1] > 0, gq[1], 1.0), 1.0))
    alpha = alpha[..., None, None, None]
    shape = np.broadcast_shapes(Ag.shape, G.shape, Q.shape)
    n = shape[-1]
    H = np.empty(shape[:-2] + (2 * n, 2 * n))
    H[..., :n, :n] = Ag
    H[..., :n, n:] = G * alpha
    H[..., n:, :n] = -Q / alpha
    H[..., n:, n:] = -np.swapaxes(np.broadcast_to(Ag, shape), -1, -2)
    return H


def scattering(phi: np.ndarray):
    """Scattering blocks (E, G, Hs, F) of a Hamiltonian transition [[P11, P12], [P21, P22]]."""
    n = phi.shape[-1] // 2
    P11, P12, P21, P22 = phi[..., :n, :n], phi[..., :n, n:], phi[..., n:, :n], phi[..., n:, n:]
    F = _safe_solve(P22, np.broadcast_to(np.eye(n), P22.shape))
    G = P12 @ F
    Hs = -F @ P21
    E = P11 + P12 @ Hs
    return E, G, Hs, F


def star(a, b):
    """Redheffer star product of an earlier segment a and a later segment b; also the junction check.

    Returns ((E, G, Hs, F), ok) where ok is False where the junction has a conjugate point
    (an eigenvalue of G_a Hs_b at or beyond 1) or the numbers are no longer finite.
    """
    Ea, Ga, Ha, Fa = a
    Eb, Gb, Hb, Fb = b
    GH = Ga @ Hb
    S = np.eye(GH.shape[-1]) - GH
    SinvEa = _safe_solve(S, Ea)
    SinvGaFb = _safe_solve(S, Ga @ Fb)
    E = Eb @ SinvEa
    G = Gb + Eb @ SinvGaFb
    FaHb = Fa @ Hb
    Hs = Ha + FaHb @ SinvEa
    F = Fa @ Fb + FaHb @ SinvGaFb
    Hs = _sym(Hs)
    ok = _finite(E, G, Hs, F) & (_max_eig_product(Ga, Hb) < 1.0)
    ok = ok & _psd(np.where(ok[..., None, None], Hs, 0.0))
    return (E, G, Hs, F), ok


def _max_eig_product(G, H):
    """Largest eigenvalue of G H for symmetric G, H >= 0, via the symmetric H^1/2 G H^1/2.

    That eigenvalue reaching 1 at a junction is a conjugate point: the Riccati solution
    escapes to infinity (finite-horizon gain >= gamma). Non-finite inputs give +inf.
    """
    fin = np.all(np.isfinite(G), axis=(-1, -2)) & np.all(np.isfinite(H), axis=(-1, -2))
    G = np.where(fin[..., None, None], _sym(G), 0.0)
    H = np.where(fin[..., None, None], _sym(H), 0.0)
    lam, V = np.linalg.eigh(H)
    Hh = (V * np.sqrt(np.maximum(lam, 0.0))[..., None, :]) @ np.swapaxes(V, -1, -2)
    top = np.linalg.eigvalsh(Hh @ G @ Hh)[..., -1]
    return np.where(fin, top, np.inf)


def _psd(X, rtol=1e-9):
    """Symmetric X >= 0 up to round-off relative to its size."""
    lam = np.linalg.eigvalsh(X)
    return lam[..., 0] >= -rtol * np.maximum(np.abs(lam[..., -1]), 1e-300)


def _safe_solve(a, b):
    """Batched solve that marks singular or non-finite systems with NaN instead of raising."""
    bad = ~np.all(np.isfinite(a), axis=(-1, -2))
    if bad.any():
        a = np.where(bad[..., None, None], np.eye(a.shape[-1]), a)
    try:
        x = np.linalg.solve(a, b)
    except np.linalg.LinAlgError:
        x = np.empty(np.broadcast_shapes(a.shape[:-2], b.shape[:-2]) + b.shape[-2:])
        a_b = np.broadcast_to(a, x.shape[:-2] + a.shape[-2:])
        b_b = np.broadcast_to(b, x.shape)
        for idx in np.ndindex(*x.shape[:-2]):
            try:
                x[idx] = np.linalg.solve(a_b[idx], b_b[idx])
            except np.linalg.LinAlgError:
                x[idx] = np.nan
    if bad.any():
        x = np.where(bad[..., None, None], np.nan, x)
    return x


def _sym(X):
    return 0.5 * (X + np.swapaxes(X, -1, -2))


def _finite(*arrs):
    ok = True
    for a in arrs:
        ok = ok & np.all(np.isfinite(a), axis=(-1, -2))
    return ok


def _take(blocks, sl):
    return tuple(x[..., sl, :, :] for x in blocks)


def period_scattering(sys: LTPSystem, gamma, steps: int = DEFAULT_STEPS):
    """Scattering blocks of one period of the Hamiltonian flow, and where they exist."""
    M1, M2, h = generator_at_nodes(lambda t: hamiltonian(sys, gamma, t), sys.period, steps)
    with np.errstate(all="ignore"):
        blocks = scattering(magnus_exponentials(M1, M2, h))  # (..., steps, n, n) each
        ok = _finite(*blocks).all(axis=-1)
        while blocks[0].shape[-3] > 1:  # pairwise star products, earlier interval first
            k = blocks[0].shape[-3]
            if k % 2:
                tail, ok_t = star(_take(blocks, slice(-2, -1)), _take(blocks, slice(-1, None)))
                blocks = tuple(np.concatenate([x[..., :-2, :, :], y], axis=-3) for x, y in zip(blocks, tail))
                ok = ok & ok_t[..., 0]
                continue
            blocks, ok_l = star(_take(blocks, slice(0, None, 2)), _take(blocks, slice(1, None, 2)))
            ok = ok & ok_l.all(axis=-1)
    return tuple(x[..., 0, :, :] for x in blocks), ok


def gamma_test(sys: LTPSystem, gamma, steps: int = DEFAULT_STEPS, return_decay: bool = False):
    """True where ||G||_inf < gamma (batch axes of sys broadcast against gamma's shape).

    With ``return_decay``, also the spectral radius of the Hamiltonian closed loop over one
    period, (I - G_T X(0))^-1 E_T with X the stabilizing solution (NaN where the test fails).
    It tends to 1 as gamma falls to the norm (like exp(-c sqrt(gamma - norm)) at a generic
    peak), which ``hinfnorm`` uses to place its next levels.

    Returns
    -------
    passed : ndarray of bool, broadcast shape of the batch and ``gamma``
        True where ||G||_inf < gamma (and the system is stable).
    rho : ndarray of float, same shape (only with ``return_decay``)
        Decay of the Hamiltonian closed loop over one period; NaN where the test fails.
    """
    gamma = np.asarray(gamma, dtype=float)
    dmax = feedthrough_bound(sys)
    blocks, ok = period_scattering(sys, gamma, steps)
    one_period = blocks
    ok = ok & (gamma > dmax)
    done = np.zeros(ok.shape, dtype=bool)
    with np.errstate(all="ignore"):
        for _ in range(MAX_DOUBLINGS):
            decay = np.max(np.abs(blocks[0]), axis=(-1, -2))
            done = done | (ok & (decay < _CONVERGED))
            if np.all(done | ~ok):
                break
            blocks, ok_d = star(blocks, blocks)  # horizon 2^k periods -> 2^(k+1)
            ok = ok & (ok_d | done)
        passed = done & ok
        if not return_decay:
            return passed
        E, G = one_period[0], one_period[1]
        n = E.shape[-1]
        psi = _safe_solve(np.eye(n) - G @ blocks[2], E)
        fin = np.all(np.isfinite(psi), axis=(-1, -2)) & passed
        rho = np.max(np.abs(np.linalg.eigvals(np.where(fin[..., None, None], psi, 0.0))), axis=-1)
    return passed, np.where(fin, rho, np.nan)


def feedthrough_bound(sys: LTPSystem, samples: int = 256) -> np.ndarray:
    """sup_t ||D(t)||: a lower bound of the norm; the gamma-test needs gamma above it."""
    if not sys.has_feedthrough:
        return np.zeros(())
    t = np.arange(samples) * sys.period / samples
    return np.max(np.linalg.norm(sys.sample("D", t), ord=2, axis=(-2, -1)), axis=-1)


def hinfnorm(sys: LTPSystem, rtol: float = 1e-6, steps: int = DEFAULT_STEPS, guess=None,
             grid: int | None = None, spread: float | None = None) -> np.ndarray:
    """H-infinity (L2-induced) norm of a stable LTP system, paper eq. (21); inf if unstable.

    Vectorized bisection: each round tests ``grid`` gammas per system at once (geometric grid
    inside the current bracket), shrinking the bracket by a factor grid + 1. A gamma-test costs
    the same alone or in a batch, so a single system uses plain bisection (grid = 1, fewest
    tests) and a batch a grid of 4 (fewer rounds of Python overhead). Works on a batch of
    systems (leading axes of the matrices); every round tests only the systems whose bracket is
    still open (the others leave the batch). ``spread`` (> 1) is the first bracketing ratio
    around ``guess``: a caller that knows the norms are within a few percent of the guess (an
    optimizer's population around its incumbent) passes e.g. 1.05 and saves the wide first
    bracket; it only changes the levels tested, never the result beyond ``rtol``.
    Accuracy: relative ``rtol`` of the bracket, plus the discretization error of ``steps``
    Magnus intervals (see tests and bench/).

    Returns
    -------
    ndarray (*batch)
        ||G||_inf per system to relative accuracy ``rtol`` (midpoint of the final bracket); inf where
        the system is unstable or no passing level was found.
    """
    batch = _batch_shape(sys)
    if grid is None:
        grid = 1 if int(np.prod(batch)) == 1 else 4
    dlo = np.broadcast_to(feedthrough_bound(sys), batch).astype(float)
    if guess is None:
        guess = np.maximum(2.0 * dlo, _scale_guess(sys))
    centre = np.broadcast_to(np.asarray(guess, dtype=float), batch).copy()
    lo, hi = dlo.copy(), np.full(batch, np.inf)
    lo_ok = np.zeros(batch, dtype=bool)  # lo is a level known to fail (or the D bound)
    rho_hi = np.full(batch, np.nan)  # Hamiltonian closed-loop decay at hi
    # Bracket [lo, hi], lo failing and hi passing: grids of ratio 4 around a centre that moves
    # by 4^grid until the test changes (the test is monotone in gamma).
    ratio = (2.0 if grid == 1 else 4.0) if spread is None else float(spread)  # one system: guess within 2x
    factors = ratio ** (np.arange(grid) - grid // 2)
    step = np.full(batch, ratio)
    for _ in range(24):
        bracketed = lo_ok & np.isfinite(hi)
        if bracketed.all():
            break
        todo = ~bracketed
        gam = centre[..., None] * factors
        passed, rho = _test_some(sys, gam, steps, todo)
        anyp, allp = passed.any(-1), passed.all(-1)
        first = np.argmax(passed, axis=-1)
        g_first = np.take_along_axis(gam, first[..., None], -1)[..., 0]
        lower = todo & anyp & (g_first < hi)
        rho_hi = np.where(lower, np.take_along_axis(rho, first[..., None], -1)[..., 0], rho_hi)
        g_prev = np.take_along_axis(gam, np.maximum(first - 1, 0)[..., None], -1)[..., 0]
        hi = np.where(todo & anyp, np.minimum(hi, g_first), hi)
        fail_top = np.where(anyp, g_prev, gam[..., -1])
        has_fail = todo & ~allp
        lo = np.where(has_fail, np.maximum(lo, fail_top), lo)
        lo_ok = lo_ok | has_fail | (todo & allp & (gam[..., 0] <= 1.01 * dlo))
        centre = np.where(todo & ~anyp, centre * step ** grid, np.where(todo & allp, centre / step ** grid, centre))
        step = np.minimum(step * step, 1e4)  # exponential search: any starting guess is reached fast
    bracketed = lo_ok & np.isfinite(hi)
    found_hi = bracketed
    lo = np.maximum(lo, dlo)
    lo = np.maximum(lo, 1e-300)
    # Refinement. Levels come from a model of the Hamiltonian closed-loop decay rho(gamma)
    # of the passing levels: (ln rho)^2 is nearly linear in gamma near the norm (a pair of
    # multipliers leaving the unit circle), so two passing levels predict where it reaches 0,
    # and the two levels tested straddle that prediction. Whenever a prediction is
    # unavailable, implausible or did not halve the bracket, a plain (geometric) bisection
    # step is taken instead, so the bracket always shrinks and the result never depends on
    # the model being right.
    hist = np.full(batch + (2, 2), np.nan)  # last two passing (gamma, (ln rho)^2), newest first
    hist[..., 0, 0], hist[..., 0, 1] = hi, np.log(rho_hi) ** 2
    trust = np.ones(batch, dtype=bool)
    while True:
        active = found_hi & (hi - lo > rtol * hi)
        if not active.any():
            break
        g1, d1, g2, d2 = hist[..., 0, 0], hist[..., 0, 1], hist[..., 1, 0], hist[..., 1, 1]
        with np.errstate(all="ignore"):
            est = g1 - d1 * (g2 - g1) / (d2 - d1)
        plausible = trust & np.isfinite(est) & (d2 > d1) & (est > lo) & (est < hi)
        frac = np.arange(1, grid + 1) / (grid + 1)
        bis = lo[..., None] * (hi / lo)[..., None] ** frac
        delta = rtol / 3.0
        # below the prediction by rtol / 3, and above it by a tenth of the way to hi: the
        # prediction is usually within that, and a passing level close to the norm makes the
        # next prediction much better (its error is quadratic in the distance to the norm)
        above = np.maximum(est * (1.0 + delta), est + 0.1 * (hi - est))
        pred = np.clip(np.stack([est * (1.0 - delta), above], axis=-1), lo[..., None], hi[..., None])
        width = max(grid, 2) if plausible.any() else grid  # no duplicate levels when all bisect
        bis = np.concatenate([bis, np.repeat(bis[..., -1:], width - grid, axis=-1)], axis=-1)
        if width >= 2:
            pred = np.concatenate([pred, np.repeat(pred[..., -1:], width - 2, axis=-1)], axis=-1)
            gam = np.where(plausible[..., None], np.sort(pred, axis=-1), bis)
        else:
            gam = bis
        # one passing level known: probe 3% below it for a second, close one
        probe = np.isfinite(g1) & np.isfinite(d1) & ~np.isfinite(g2) & (0.97 * g1 > lo)
        gam = np.where(probe[..., None], (0.97 * g1)[..., None], gam)
        passed, rho = _test_some(sys, gam, steps, active)
        first = np.where(passed.any(-1), np.argmax(passed, axis=-1), width)
        g_ext = np.concatenate([lo[..., None], gam, hi[..., None]], axis=-1)
        new_lo = np.take_along_axis(g_ext, first[..., None], -1)[..., 0]
        new_hi = np.take_along_axis(g_ext, (first + 1)[..., None], -1)[..., 0]
        shrunk = np.log(new_hi / new_lo) <= 0.25 * np.log(hi / lo)
        trust = np.where(active, ~plausible | shrunk, trust)
        got = active & (first < width)
        rho_first = np.take_along_axis(rho, np.minimum(first, width - 1)[..., None], -1)[..., 0]
        dnew = np.log(rho_first) ** 2
        newer = got & np.isfinite(dnew) & (new_hi < np.where(np.isfinite(g1), g1, np.inf))
        hist[..., 1, :] = np.where(newer[..., None], hist[..., 0, :], hist[..., 1, :])
        hist[..., 0, 0] = np.where(newer, new_hi, g1)
        hist[..., 0, 1] = np.where(newer, dnew, d1)
        lo = np.where(active, new_lo, lo)
        hi = np.where(active, new_hi, hi)
    return np.where(found_hi, 0.5 * (lo + hi), np.inf)


def _test_some(sys, gam, steps, which):
    """_test_grid (with decay) on the systems where ``which`` is True only; the others get
    (False, NaN), which the callers ignore (their bracket is closed)."""
    batch = which.shape
    passed = np.zeros(gam.shape, dtype=bool)
    rho = np.full(gam.shape, np.nan)
    if which.all():
        return _test_grid(sys, gam, steps, decay=True)
    if not which.any():
        return passed, rho
    idx = np.flatnonzero(which.reshape(-1))
    p, r = _test_grid(_subset(sys, batch, idx), gam.reshape((-1,) + gam.shape[-1:])[idx], steps, decay=True)
    passed.reshape((-1,) + gam.shape[-1:])[idx] = p
    rho.reshape((-1,) + gam.shape[-1:])[idx] = r
    return passed, rho


def _subset(sys: LTPSystem, batch: tuple, idx: np.ndarray) -> LTPSystem:
    """The systems ``idx`` (flat positions in ``batch``) of a batched system, as a flat batch."""
    def pick(M):
        if M is None:
            return None
        if callable(M):
            def sub(t, M=M):
                v = np.asarray(M(t), dtype=float)
                v = np.broadcast_to(v, batch + v.shape[-3:]).reshape((-1,) + v.shape[-3:])
                return v[idx]
            return sub
        M = np.asarray(M, dtype=float)
        if M.ndim == 2:
            return M
        return np.broadcast_to(M, batch + M.shape[-2:]).reshape((-1,) + M.shape[-2:])[idx]
    return LTPSystem(pick(sys.A), pick(sys.B), pick(sys.C), pick(sys.D), sys.period)


def _test_grid(sys, gam, steps, decay=False):
    """gamma_test on gam (*batch, g): the batch is expanded so every system sees its own row."""
    g = gam.shape[-1]
    return gamma_test(_expand(sys, g), gam, steps, return_decay=decay)


def _expand(sys: LTPSystem, g: int) -> LTPSystem:
    """Insert a broadcast axis before the time/matrix axes so systems pair with gamma grids."""
    def wrap(M):
        if M is None:
            return None
        if callable(M):
            return lambda t, M=M: np.asarray(M(t))[..., None, :, :, :]
        M = np.asarray(M, dtype=float)
        return M[..., None, :, :]
    return LTPSystem(wrap(sys.A), wrap(sys.B), wrap(sys.C), wrap(sys.D), sys.period)


def _batch_shape(sys: LTPSystem):
    t = np.zeros(1)
    shapes = [sys.sample(n, t).shape[:-3] for n in ("A", "B", "C")]
    return np.broadcast_shapes(*shapes)


def _scale_guess(sys: LTPSystem) -> np.ndarray:
    """Starting level: the H-inf norm of the time-averaged LTI system (often within ~10%),
    else an order of magnitude ||C|| ||B|| / |slowest decay rate| of the mean A."""
    if int(np.prod(_batch_shape(sys))) == 1:
        t = np.arange(64) * sys.period / 64
        mats = [np.asarray(sys.sample(n, t)).mean(axis=-3).reshape(sys.sample(n, t[:1]).shape[-2:])
                for n in ("A", "B", "C", "D")]
        if np.all(np.linalg.eigvals(mats[0]).real < 0):
            g = lti_hinfnorm(*[m.astype(complex) for m in mats], rtol=1e-3)[0]
            if np.isfinite(g) and g > 1e-3 * _magnitude(sys):  # averaging can cancel B or C
                return np.asarray(g)
    return _magnitude(sys)


def _magnitude(sys: LTPSystem) -> np.ndarray:
    """Order of magnitude of the norm: max |B| max |C| / slowest decay rate of the mean A."""
    t = np.arange(16) * sys.period / 16
    A = sys.sample("A", t).mean(axis=-3)
    B = np.linalg.norm(sys.sample("B", t), ord=2, axis=(-2, -1)).max(axis=-1)
    C = np.linalg.norm(sys.sample("C", t), ord=2, axis=(-2, -1)).max(axis=-1)
    rate = np.max(np.linalg.eigvals(A).real, axis=-1)
    rate = np.where(rate < -1e-12, -rate, 1.0 / sys.period)
    return np.maximum(B * C / rate, 1e-12)
