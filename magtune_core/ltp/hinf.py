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

:func:`hinfnorm` places levels gamma between gamma-tests (:func:`gamma_margins`: the periodic bounded
real lemma, Bittanti & Colaneri 2009, ch. 9) until the bracket is within ``rtol``. Vectorized over a
batch of systems (leading axes of the matrices): every round tests only the systems whose bracket is
still open, as one flat batch of gamma-tests. First a bracket (a failing and a passing level) around
``guess``: ``grid`` levels per system per round (default 1 for a single system, fewest tests; 4 for a
batch, fewer rounds); then one level per system per round, placed from the margins of the passing
levels (see the comment at the refinement in :func:`hinfnorm`), and two in the round that closes the
bracket. ``spread`` (> 1) is the first bracketing ratio around ``guess``: a caller that knows the
norms are within a few percent of the guess (an optimizer's population around its incumbent) passes
e.g. 1.05 and saves the wide first bracket; it only changes the levels tested, never the result
beyond ``rtol``. Accuracy: relative ``rtol`` of the bracket, plus the discretization error of
``steps`` Magnus intervals (see tests and bench/).
"""
from __future__ import annotations

import numpy as np

from . import hinf_levels as L
from .expm import pade13_scaled
from .hinf_kernel import exponents_at, gamma_test_omegas
from .system import DEFAULT_STEPS, LTPSystem, generator_at_nodes, interval_grid, magnus_exponent

MAX_DOUBLINGS = 48
_CONVERGED = 1e-13
#: First chase factor of hinfnorm's refinement: the next level is est + _CHASE (g_1 - est).
_CHASE = 0.05
#: Largest ||exp(Omega / 2^j)||_1 that ``interval_scattering`` still squares as a matrix.
GROWTH = 1e6


def hamiltonian(sys: LTPSystem, gamma, t) -> np.ndarray:
    """The (balanced) H-infinity Hamiltonian at times t: the flow whose scattering form the gamma-test checks.

    The Hamiltonian of the periodic H-infinity Riccati equation of the bounded real lemma (module
    docstring; Bittanti & Colaneri 2009, ch. 9), [[A_g, B R^-1 B^T], [-C^T (I + D R^-1 D^T) C, -A_g^T]],
    with its off-diagonal blocks balanced by p = alpha p' (conjugate points and the test invariant).

    Parameters
    ----------
    sys : LTPSystem
        The system, possibly batched.
    gamma : float or ndarray
        Level(s) > sup ||D||, broadcast against the batch axes of ``sys``.
    t : ndarray (k,)
        Times in [0, T).

    Returns
    -------
    ndarray (*batch, k, 2n, 2n)
        H(t) at every time.
    """
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
    """Scattering blocks (E, G, Hs, F) of a Hamiltonian transition [[P11, P12], [P21, P22]].

    The "standard symplectic" form x1 = E x0 + G p1, p0 = Hs x0 + F p1 of the flow (module docstring),
    in which intervals join by the Redheffer star product (:func:`star`) without forming the growing
    part of the transition.

    Parameters
    ----------
    phi : ndarray (..., 2n, 2n)
        Hamiltonian transition matrices (state x first, costate p second).

    Returns
    -------
    E, G, Hs, F : ndarrays (..., n, n)
        F = P22^-1, G = P12 F, Hs = -F P21, E = P11 + P12 Hs (NaN where P22 is singular).
    """
    n = phi.shape[-1] // 2
    P11, P12, P21, P22 = phi[..., :n, :n], phi[..., :n, n:], phi[..., n:, :n], phi[..., n:, n:]
    F = _safe_solve(P22, np.broadcast_to(np.eye(n), P22.shape))
    G = P12 @ F
    Hs = -F @ P21
    E = P11 + P12 @ Hs
    return E, G, Hs, F


def star(a, b):
    """Redheffer star product of an earlier segment a and a later segment b; also the junction check.

    Joining two scattering segments is one step of the structured doubling algorithm; the junction
    exists iff I - G_a Hs_b is invertible, i.e. no conjugate point of the Riccati equation there
    (bounded real lemma, module docstring).

    Parameters
    ----------
    a : tuple (E, G, Hs, F) of ndarrays (..., n, n)
        Scattering blocks of the earlier segment.
    b : tuple (E, G, Hs, F) of ndarrays (..., n, n)
        Scattering blocks of the later segment (batch axes broadcast against ``a``'s).

    Returns
    -------
    blocks : tuple (E, G, Hs, F) of ndarrays (..., n, n)
        The scattering blocks of the joined segment.
    ok : ndarray of bool (...)
        False where the junction has a conjugate point (an eigenvalue of G_a Hs_b at or beyond 1)
        or the numbers are no longer finite.
    kappa : ndarray (...)
        That largest eigenvalue (how close the junction is to a conjugate point).
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
    kappa = _max_eig_product(Ga, Hb)
    ok = _finite(E, G, Hs, F) & (kappa < 1.0)
    ok = ok & _psd(np.where(ok[..., None, None], Hs, 0.0))
    return (E, G, Hs, F), ok, kappa


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


def interval_scattering(omega: np.ndarray, growth: float = GROWTH):
    """Scattering blocks of exp(Omega) for a stack of Hamiltonian interval exponents, without
    forming exp(Omega) when it is too large to split.

    exp(Omega) is Pade 13 at Omega / 2^s, then squared s times (Higham 2005). A stiff closed loop
    (fast modes, |lambda| h of tens: the converged gains) makes the Hamiltonian flow grow like
    exp(|lambda| h) over an interval, and the scattering blocks, which hold the decaying part,
    are then lost to cancellation: at 64 Magnus steps ||exp(Omega)||_1 reaches 1e36 for the
    sigma = 60 optimum, and at 256 steps 1e19 for sigma = 240, where every level used to fail
    (J = inf). So the squarings run as matrix products only while ||.||_1 stays <= ``GROWTH``;
    the rest are star products of the interval with itself (the doubling of the structured
    doubling algorithm), which never forms the growing part. Where no interval reaches ``GROWTH`` (every gain of the paper's method and
    the LQ starts at 64 steps: ||exp(Omega)||_1 <= 250) the arithmetic is exactly the plain
    exponential's. The star squarings also check conjugate points inside the interval.
    ``GROWTH``: the error bound eps GROWTH^2 is 1e-4 at 1e6, but on the shipped stiff optima J is
    the same to 1e-7 for GROWTH = 1e4, 1e6 and 1e8 (measured), and 1e6 is ~20 % faster than 1e4.
    Tested in tests/ltp/test_hinf_kernel.py (a stiff loop against the truncated HTF).

    Parameters
    ----------
    omega : ndarray (..., 2n, 2n)
        Magnus exponents of the Hamiltonian, one per interval.
    growth : float
        Largest ||exp(Omega / 2^j)||_1 still squared as a matrix (default ``GROWTH``); ``np.inf``: plain exponential.

    Returns
    -------
    blocks : tuple of 4 ndarrays (..., n, n)
        (E, G, Hs, F) of each interval (``scattering``).
    ok : ndarray of bool (...)
        False where the blocks are not finite or a star squaring met a conjugate point.
    kappa : ndarray (...)
        Largest junction eigenvalue of the star squarings (-inf where there were none).
    """
    r, s, finite = pade13_scaled(omega)
    done = np.zeros(s.shape, dtype=int)  # squarings done as matrix products
    live = np.ones(s.shape, dtype=bool)
    for i in range(int(s.max(initial=0))):
        sq = r @ r
        live = live & (i < s) & (np.max(np.sum(np.abs(sq), axis=-2), axis=-1) <= growth)
        r = np.where(live[..., None, None], sq, r)
        done = done + live
    blocks = scattering(np.where(finite[..., None, None], r, np.nan))
    ok = _finite(*blocks)
    kappa = np.full(ok.shape, -np.inf)
    rest = s - done
    for j in range(int(rest.max(initial=0))):
        act = (j < rest) & ok
        squared, ok_s, kap = star(blocks, blocks)
        blocks = tuple(np.where(act[..., None, None], y, x) for x, y in zip(blocks, squared))
        ok = ok & (ok_s | ~act)
        kappa = np.where(act, np.fmax(kappa, kap), kappa)
    return blocks, ok, kappa


def period_scattering(sys: LTPSystem, gamma, steps: int = DEFAULT_STEPS):
    """Scattering blocks of one period of the Hamiltonian flow, where they exist, and the
    largest junction eigenvalue kappa met on the way (``star``).

    The numpy reference of the compiled kernel's period tree (:mod:`.hinf_kernel`): ``steps``
    4th-order Magnus intervals (Magnus 1954; two Gauss nodes) joined pairwise, earlier first.

    Parameters
    ----------
    sys : LTPSystem
        The system, possibly batched.
    gamma : float or ndarray
        Level(s) > sup ||D||, broadcast against the batch axes of ``sys``.
    steps : int
        Magnus intervals per period.

    Returns
    -------
    blocks : tuple (E, G, Hs, F) of ndarrays (*batch, n, n)
        The period's scattering blocks.
    ok : ndarray of bool (*batch)
        False where an interval or a junction failed (a conjugate point, or non-finite numbers).
    kappa : ndarray (*batch)
        Largest junction eigenvalue met.
    """
    M1, M2, h = generator_at_nodes(lambda t: hamiltonian(sys, gamma, t), sys.period, steps)
    with np.errstate(all="ignore"):
        blocks, ok, kappa = interval_scattering(magnus_exponent(M1, M2, h))  # (..., steps, n, n) each
        ok = ok.all(axis=-1)
        kappa = kappa.max(axis=-1)
        while blocks[0].shape[-3] > 1:  # pairwise star products, earlier interval first
            k = blocks[0].shape[-3]
            if k % 2:
                tail, ok_t, kap = star(_take(blocks, slice(-2, -1)), _take(blocks, slice(-1, None)))
                blocks = tuple(np.concatenate([x[..., :-2, :, :], y], axis=-3) for x, y in zip(blocks, tail))
                ok = ok & ok_t[..., 0]
                kappa = np.fmax(kappa, kap[..., 0])
                continue
            blocks, ok_l, kap = star(_take(blocks, slice(0, None, 2)), _take(blocks, slice(1, None, 2)))
            ok = ok & ok_l.all(axis=-1)
            kappa = np.fmax(kappa, kap.max(axis=-1))
    return tuple(x[..., 0, :, :] for x in blocks), ok, kappa


def gamma_test(sys: LTPSystem, gamma, steps: int = DEFAULT_STEPS, return_decay: bool = False):
    """True where ||G||_inf < gamma (batch axes of sys broadcast against gamma's shape).

    The test of the periodic bounded real lemma (module docstring; Bittanti & Colaneri 2009, ch. 9)
    on the norm of paper eq. (21), in numpy (the paper tuner's path; ``hinfnorm`` uses the compiled
    :func:`gamma_margins`).

    With ``return_decay``, also the spectral radius of the Hamiltonian closed loop over one
    period, (I - G_T X(0))^-1 E_T with X the stabilizing solution (NaN where the test fails).
    It tends to 1 as gamma falls to the norm (like exp(-c sqrt(gamma - norm)) at a generic
    peak), which ``hinfnorm`` uses to place its next levels.

    Parameters
    ----------
    sys : LTPSystem
        The system, possibly batched.
    gamma : float or ndarray
        Level(s) tested, broadcast against the batch axes of ``sys``.
    steps : int
        Magnus intervals per period.
    return_decay : bool
        Also return the decay rho of the Hamiltonian closed loop.

    Returns
    -------
    passed : ndarray of bool, broadcast shape of the batch and ``gamma``
        True where ||G||_inf < gamma (and the system is stable).
    rho : ndarray of float, same shape (only with ``return_decay``)
        Decay of the Hamiltonian closed loop over one period; NaN where the test fails.
    """
    if not return_decay:
        return _gamma_test(sys, gamma, steps, margins=False)
    passed, rho, _ = _gamma_test(sys, gamma, steps, margins=True)
    return passed, rho


def gamma_margins(sys: LTPSystem, gamma, steps: int = DEFAULT_STEPS, growth: float = GROWTH):
    """The gamma-test with the two margins that say how far gamma is above the norm (compiled kernel).

    Same test as :func:`gamma_test` (periodic bounded real lemma, Bittanti & Colaneri 2009, ch. 9;
    norm of paper eq. 21), run by :func:`.hinf_kernel.gamma_test_omegas`.

    The test fails at the norm by one of two events (module docstring): a pair of Hamiltonian
    multipliers reaching the unit circle (then the decay rho -> 1, with (ln rho)^2 ~ linear in
    gamma: a frequency peak), or a conjugate point inside the period (then the largest junction
    eigenvalue kappa -> 1, with 1 - kappa ~ linear in gamma: the finite-horizon Riccati solution
    escapes). ``hinfnorm`` extrapolates both to place its levels.

    Parameters
    ----------
    sys : LTPSystem
        The system, possibly batched.
    gamma : float or ndarray
        Level(s) tested, broadcast against the batch axes of ``sys``.
    steps : int
        Magnus intervals per period.
    growth : float
        Largest ||exp(Omega / 2^j)||_1 squared as a matrix (:func:`interval_scattering`); ``np.inf``: plain exponential.

    Returns
    -------
    passed : ndarray of bool
        As :func:`gamma_test`.
    rho : ndarray of float
        Decay of the Hamiltonian closed loop over one period; NaN where the test fails.
    kappa : ndarray of float
        Largest junction eigenvalue of G_a Hs_b over the period tree and the doublings (< 1 where
        the test passes); NaN where the test fails.
    """
    gamma = np.asarray(gamma, dtype=float)
    M1, M2, h = generator_at_nodes(lambda t: hamiltonian(sys, gamma, t), sys.period, steps)
    omega = magnus_exponent(M1, M2, h)
    shape = omega.shape[:-3]
    with np.errstate(all="ignore"):
        passed, rho, kappa = gamma_test_omegas(np.ascontiguousarray(omega.reshape((-1,) + omega.shape[-3:])), True,
                                               float(growth))
    passed = passed.reshape(shape) & (gamma > feedthrough_bound(sys))
    return passed, np.where(passed, rho.reshape(shape), np.nan), np.where(passed, kappa.reshape(shape), np.nan)


def _gamma_test(sys: LTPSystem, gamma, steps: int, margins: bool):
    gamma = np.asarray(gamma, dtype=float)
    dmax = feedthrough_bound(sys)
    blocks, ok, kappa = period_scattering(sys, gamma, steps)
    one_period = blocks
    ok = ok & (gamma > dmax)
    done = np.zeros(ok.shape, dtype=bool)
    with np.errstate(all="ignore"):
        for _ in range(MAX_DOUBLINGS):
            decay = np.max(np.abs(blocks[0]), axis=(-1, -2))
            done = done | (ok & (decay < _CONVERGED))
            if np.all(done | ~ok):
                break
            blocks, ok_d, kap = star(blocks, blocks)  # horizon 2^k periods -> 2^(k+1)
            ok = ok & (ok_d | done)
            kappa = np.where(done, kappa, np.fmax(kappa, kap))
        passed = done & ok
        if not margins:
            return passed
        E, G = one_period[0], one_period[1]
        n = E.shape[-1]
        psi = _safe_solve(np.eye(n) - G @ blocks[2], E)
        fin = np.all(np.isfinite(psi), axis=(-1, -2)) & passed
        rho = np.max(np.abs(np.linalg.eigvals(np.where(fin[..., None, None], psi, 0.0))), axis=-1)
    return passed, np.where(fin, rho, np.nan), np.where(passed, kappa, np.nan)


def feedthrough_bound(sys: LTPSystem, samples: int = 256) -> np.ndarray:
    """sup_t ||D(t)||: a lower bound of the norm; the gamma-test needs gamma above it.

    (R = gamma^2 I - D^T D of the bounded real lemma must be positive definite.)

    Parameters
    ----------
    sys : LTPSystem
        The system, possibly batched.
    samples : int
        Equally spaced times of one period at which D(t) is evaluated.

    Returns
    -------
    ndarray (*batch)
        max over ``samples`` times of one period of the largest singular value of D(t); 0 (shape ())
        without feedthrough.
    """
    if not sys.has_feedthrough:
        return np.zeros(())
    t = np.arange(samples) * sys.period / samples
    return np.max(np.linalg.norm(sys.sample("D", t), ord=2, axis=(-2, -1)), axis=-1)


def hinfnorm(sys: LTPSystem, rtol: float = 1e-6, steps: int = DEFAULT_STEPS, guess=None,
             grid: int | None = None, spread: float | None = None) -> np.ndarray:
    """H-infinity (L2-induced) norm of a stable LTP system, paper eq. (21); inf if unstable.

    Parameters
    ----------
    sys : LTPSystem
        The system, possibly batched (leading axes of its matrices); levels placed as the module docstring describes.
    rtol : float
        Relative width of the final bracket of gamma-tests (:func:`gamma_margins`: periodic bounded real lemma, Bittanti & Colaneri 2009, ch. 9).
    steps : int
        Magnus intervals per period (their discretization error adds to ``rtol``: see tests and bench/).
    guess : float or ndarray (*batch), optional
        Centre of the first bracket (default: max(2 sup ||D||, the time-averaged LTI system's peak gain or else ||B|| ||C|| / decay rate)).
    grid : int, optional
        Levels per system per bracketing round (default 1 for a single system, fewest tests; 4 for a batch, fewer rounds).
    spread : float, optional
        First bracketing ratio (> 1) around ``guess`` (default 1.25 with ``grid`` 1, else 4); never changes the result beyond ``rtol``.

    Returns
    -------
    ndarray (*batch)
        ||G||_inf per system to relative accuracy ``rtol`` (midpoint of the final bracket); inf where
        the system is unstable or no passing level was found.
    """
    sys = _sampled_once(sys, steps)
    batch = _batch_shape(sys)
    poly = exponent_polynomial(sys, steps)
    if poly is not None:
        poly = tuple(np.ascontiguousarray(np.broadcast_to(W, batch + W.shape[-3:])) for W in poly)
    if grid is None:
        grid = 1 if int(np.prod(batch)) == 1 else 4
    dlo = np.broadcast_to(feedthrough_bound(sys), batch).astype(float)
    if guess is None:
        guess = np.maximum(2.0 * dlo, _scale_guess(sys, interval_grid(sys.period, steps)[2].ravel()))
    centre = np.broadcast_to(np.asarray(guess, dtype=float), batch).copy()
    lo, hi = dlo.copy(), np.full(batch, np.inf)
    lo_ok = np.zeros(batch, dtype=bool)  # lo is a level known to fail (or the D bound)
    m_hi = np.full(batch + (2,), np.nan)  # margins at hi: (ln rho)^2 and 1 - kappa (gamma_margins)
    prev = np.full(batch + (3,), np.nan)  # the passing level before hi, with its margins
    # Bracket [lo, hi], lo failing and hi passing: grids of ratio 4 around a centre that moves
    # by 4^grid until the test changes (the test is monotone in gamma).
    ratio = (1.25 if grid == 1 else 4.0) if spread is None else float(spread)  # the step squares: far guesses are reached fast
    factors = ratio ** (np.arange(grid) - grid // 2)
    step = np.full(batch, ratio)
    for _ in range(24):
        bracketed = lo_ok & np.isfinite(hi)
        if bracketed.all():
            break
        todo = ~bracketed
        gam = centre[..., None] * factors
        passed, marg = _test_some(sys, gam, steps, todo, poly)
        anyp, allp = passed.any(-1), passed.all(-1)
        first = np.argmax(passed, axis=-1)
        g_first = np.take_along_axis(gam, first[..., None], -1)[..., 0]
        lower = todo & anyp & (g_first < hi)
        prev = np.where((lower & np.isfinite(hi))[..., None], np.concatenate([hi[..., None], m_hi], axis=-1), prev)
        m_hi = np.where(lower[..., None], np.take_along_axis(marg, first[..., None, None], -2)[..., 0, :], m_hi)
        g_prev = np.take_along_axis(gam, np.maximum(first - 1, 0)[..., None], -1)[..., 0]
        hi = np.where(todo & anyp, np.minimum(hi, g_first), hi)
        fail_top = np.where(anyp, g_prev, gam[..., -1])
        has_fail = todo & ~allp
        lo = np.where(has_fail, np.maximum(lo, fail_top), lo)
        lo_ok = lo_ok | has_fail | (todo & allp & (gam[..., 0] <= 1.01 * dlo))
        centre = np.where(todo & ~anyp, centre * step ** grid, np.where(todo & allp, centre / step ** grid, centre))
        step = np.minimum(step * step, 1e4)  # exponential search: any starting guess is reached fast
    found_hi = lo_ok & np.isfinite(hi)
    lo = np.maximum(np.maximum(lo, dlo), 1e-300)
    # Refinement: chase the norm from above with levels placed by a model of the margins of the
    # passing levels (``predict_norm``: the quadratic through the last three, else the power law
    # of ``margin_zero``). Near the norm the decay margin (ln rho)^2 is linear in gamma to ~1e-3 over
    # a relative distance of 1e-3 (measured on the shipped gains), so the prediction from three
    # nearby passing levels is accurate to ~1 % of their distance. Each round tests one level just
    # above the prediction, est + u with u = c (g_1 - est) (g_1 the nearest passing level; c = 0.05,
    # x4 after a level that failed, i.e. a prediction that was too low, halved back after a pass),
    # which passes ~20x nearer the norm and improves the next prediction. Once u is within half the
    # tolerance, the last round tests est - u and est + u together, closing the bracket. A round
    # whose prediction is unavailable or outside the bracket, and every third round after two model
    # rounds that did not halve the bracket, tests the geometric midpoint instead: the bracket always
    # shrinks and the result never depends on the model being right. Measured (bench/bench_hinf_levels.py):
    # in the tuner's batches 9-10 tests per gain at rtol 1e-4 and 10.5-13 at 1e-6,
    # against 12-13 / 16-19 with the straddling rule used before and 10 / 17 for plain bisection
    # handed the +-5 % bracket for free.
    hist = np.full(batch + (3, 3), np.nan)  # last three passing (gamma, (ln rho)^2, 1 - kappa), newest first
    hist[..., 0, 0], hist[..., 0, 1:] = hi, m_hi
    hist[..., 1, :] = prev
    # the bookkeeping of each round is compiled (hinf_levels: one loop over the systems in scalars)
    N = int(np.prod(batch))
    hist, lo, hi = hist.reshape(N, 3, 3), lo.reshape(N).copy(), hi.reshape(N).copy()
    bad = np.zeros(N, dtype=np.int64)  # consecutive model rounds that did not halve the bracket
    cfac = np.full(N, _CHASE)
    found = np.ascontiguousarray(found_hi.reshape(N))
    gam, need = np.empty((N, 2)), np.empty((N, 2), dtype=bool)
    model, closing = np.empty(N, dtype=bool), np.empty(N, dtype=bool)
    while L.plan_round(hist, lo, hi, cfac, bad, found, float(rtol), L.SCAN_FRAC, gam, need, model, closing):
        passed, marg = _test_some(sys, gam.reshape(batch + (2,)), steps, need.reshape(batch + (2,)), poly)
        L.update_round(hist, lo, hi, cfac, bad, gam, need, passed.reshape(N, 2), marg.reshape(N, 2, 2), model,
                       closing, _CHASE)
    lo, hi = lo.reshape(batch), hi.reshape(batch)
    return np.where(found_hi, 0.5 * (lo + hi), np.inf)


def predict_norm(hist: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The norm predicted from the margins at the last three passing levels (``hinfnorm``'s level model).

    ``hist`` (*batch, 3, 3): rows (gamma, (ln rho)^2, 1 - kappa), nearest the norm first (NaN where
    unknown). Per margin, the zero below gamma_1 of the quadratic through the three points
    (:func:`quadratic_zero`), else of the power law / line of :func:`margin_zero`; the norm is
    predicted at the higher of the margins' zeros (a margin that is not the binding one vanishes
    further down).

    Parameters
    ----------
    hist : ndarray (*batch, 3, 3)
        Rows (gamma, (ln rho)^2, 1 - kappa) of the last three passing levels, nearest the norm first.
    lo : ndarray (*batch)
        Highest level known to fail (lower end of the bracket); the prediction must lie above it.
    hi : ndarray (*batch)
        Lowest level known to pass (upper end of the bracket).

    Returns
    -------
    ndarray (*batch)
        The predicted norm; -inf where no margin gives a usable prediction.
    """
    hist = np.asarray(hist, dtype=float)
    batch = hist.shape[:-2]
    est = L.predict_many(_flat(hist, batch, hist.shape[-2:], float), _flat(lo, batch, (), float),
                         _flat(hi, batch, (), float), L.SCAN_FRAC)
    return est.reshape(batch)


def quadratic_zero(g: np.ndarray, m: np.ndarray, lo: np.ndarray) -> np.ndarray:
    """Zero below g[..., 0] of the quadratic through three (gamma, margin) points, per margin.

    ``g`` (*batch, 3) passing levels nearest the norm first, ``m`` (*batch, 3, q) the margins there.
    Newton form m(x) = m_1 + f_12 (x - g_1) + f_123 (x - g_1)(x - g_2); the root of smaller
    magnitude in x - g_1 (numerically stable form 2c / (-b - sign(b) sqrt(b^2 - 4ac))).

    Parameters
    ----------
    g : ndarray (*batch, 3)
        Passing levels, nearest the norm first.
    m : ndarray (*batch, 3, q)
        The q margins at those levels.
    lo : float or ndarray (*batch)
        Lower bound of the zero (a level known to fail).

    Returns
    -------
    ndarray (*batch, q)
        The zero where it exists, lies below g_1 and above ``lo``, and the margin increases with
        gamma there (m_2 > m_1 > 0); -inf elsewhere.
    """
    return _zeros(g, m, lo, False, L.SCAN_FRAC, power=False)


def margin_zero(g: np.ndarray, m: np.ndarray, lo: np.ndarray, line=True, points: int = 256) -> np.ndarray:
    """Where margins observed at passing levels extrapolate to zero (hinfnorm's level model).

    ``g`` (*batch, k) holds passing levels, nearest the norm first (NaN where unknown), ``m``
    (*batch, k, q) q margins at them (:func:`gamma_margins`). With three levels each margin is
    fitted by m = c (gamma - gamma0)^p (p in [0.25, 2]: 1/2 and 1 are the generic laws of the two
    events, a non-smooth optimum with several active peaks lies in between); with two, by a line
    (p = 1), where ``line`` (*batch) allows it (near the norm only: far from it the margins
    bend). The zero gamma0 of the three-point fit is the root, nearest g[0], of
    ln(m1/m2) ln((g2 - x)/(g3 - x)) = ln(m2/m3) ln((g1 - x)/(g2 - x)) on a log grid of distances
    below g[0] (down to ``lo``).

    Parameters
    ----------
    g : ndarray (*batch, 3)
        Passing levels, nearest the norm first (NaN where unknown; only the first three are read).
    m : ndarray (*batch, 3, q)
        The q margins at those levels.
    lo : float or ndarray (*batch)
        Lower end of the scan (a level known to fail).
    line : bool or ndarray of bool (*batch)
        Whether the two-point line fit is allowed (near the norm only).
    points : int
        Points of the log-spaced scan (distances 1e-9 .. 1 of g[0] - lo below g[0]).

    Returns
    -------
    ndarray (*batch, q)
        The predicted zero per margin; -inf where there is no usable prediction.
    """
    return _zeros(g, m, lo, line, L.SCAN_FRAC if points == L.SCAN_POINTS else np.logspace(-9, 0, points), power=True)


def _zeros(g, m, lo, line, frac, power):
    """quadratic_zero / margin_zero over any batch shape: flattened for :func:`.hinf_levels.zeros_many`."""
    g, m = np.asarray(g, dtype=float), np.asarray(m, dtype=float)
    batch = g.shape[:-1]
    out = L.zeros_many(_flat(g, batch, g.shape[-1:], float), _flat(m, batch, m.shape[-2:], float),
                       _flat(lo, batch, (), float), _flat(line, batch, (), bool), frac, power)
    return out.reshape(batch + m.shape[-1:])


def _flat(v, batch: tuple, inner: tuple, dtype):
    """``v`` broadcast to ``batch + inner``, as a C-contiguous (N, *inner) array (N = the batch
    flattened): the layout of the compiled loops of :mod:`.hinf_levels`."""
    a = np.broadcast_to(np.asarray(v, dtype=dtype), batch + inner)
    return np.ascontiguousarray(a.reshape((-1,) + inner))


def exponent_polynomial(sys: LTPSystem, steps: int = DEFAULT_STEPS):
    """The Magnus exponents of the balanced Hamiltonian as a polynomial in 1/gamma, W0 + W1/g + W2/g^2.

    (4th-order Magnus expansion, Magnus 1954, with two Gauss nodes per interval: Iserles & Norsett 1999.)

    Without feedthrough the balanced Hamiltonian of :func:`hamiltonian` is H(t) = H0(t) + N(t) / gamma,
    with H0 = diag(A, -A^T) and N = [[0, c B B^T], [-C^T C / c, 0]], c = sqrt(max|C^T C| / max|B B^T|)
    (the balancing alpha = gamma c is proportional to gamma). The 4th-order Magnus exponent
    (h/2)(M1 + M2) - (sqrt(3) h^2/12)[M1, M2] of :func:`.system.magnus_exponent` is then quadratic in
    1/gamma, so its three coefficients are computed once per system and every gamma-test of
    :func:`hinfnorm` forms its exponents by two scaled additions instead of sampling and assembling
    the Hamiltonian again (~0.5 ms of a ~1.5 ms test at 64 steps, bench/bench_kernel.py).

    Parameters
    ----------
    sys : LTPSystem
        The system, possibly batched.
    steps : int
        Magnus intervals per period.

    Returns
    -------
    tuple of 3 ndarrays (*batch, steps, 2n, 2n), or None
        (W0, W1, W2); None where the form does not apply (feedthrough, or B B^T or C^T C zero
        everywhere for some system: :func:`hamiltonian` then does not balance).
    """
    if sys.has_feedthrough:
        return None
    A1, A2, h = generator_at_nodes(lambda t: sys.sample("A", t), sys.period, steps)
    B1, B2, _ = generator_at_nodes(lambda t: sys.sample("B", t), sys.period, steps)
    C1, C2, _ = generator_at_nodes(lambda t: sys.sample("C", t), sys.period, steps)
    G1, G2 = B1 @ np.swapaxes(B1, -1, -2), B2 @ np.swapaxes(B2, -1, -2)
    Q1, Q2 = np.swapaxes(C1, -1, -2) @ C1, np.swapaxes(C2, -1, -2) @ C2
    gmax = np.maximum(np.abs(G1).max(axis=(-3, -2, -1)), np.abs(G2).max(axis=(-3, -2, -1)))
    qmax = np.maximum(np.abs(Q1).max(axis=(-3, -2, -1)), np.abs(Q2).max(axis=(-3, -2, -1)))
    if not (np.all(gmax > 0) and np.all(qmax > 0)):
        return None
    c = np.sqrt(qmax / gmax)[..., None, None, None]
    # the products in 6x6 blocks (H0 is block diagonal, N off-diagonal): 1/8 of the 12x12 flops
    T = lambda M: np.swapaxes(M, -1, -2)  # noqa: E731
    k = np.sqrt(3.0) / 12.0 * h * h
    X = A1 @ A2 - A2 @ A1  # [H0_1, H0_2] = diag(X, -X^T)
    d11 = 0.5 * h * (A1 + A2) - k * X
    u12 = 0.5 * h * c * (G1 + G2) - k * c * (A1 @ G2 + G2 @ T(A1) - G1 @ T(A2) - A2 @ G1)
    u21 = -0.5 * h / c * (Q1 + Q2) - k / c * (T(A1) @ Q2 + Q2 @ A1 - Q1 @ A2 - T(A2) @ Q1)
    Y = G1 @ Q2 - G2 @ Q1  # [N_1, N_2] = -diag(Y, -Y^T) (G, Q symmetric: Q1 G2 - Q2 G1 = -Y^T)
    shape = np.broadcast_shapes(d11.shape, u12.shape, u21.shape, Y.shape)
    n = shape[-1]
    W0, W1, W2 = (np.zeros(shape[:-2] + (2 * n, 2 * n)) for _ in range(3))
    W0[..., :n, :n], W0[..., n:, n:] = d11, -T(d11)
    W1[..., :n, n:], W1[..., n:, :n] = u12, u21
    W2[..., :n, :n], W2[..., n:, n:] = k * Y, -k * T(Y)
    return W0, W1, W2


def _margins_from_polynomial(poly, idx: np.ndarray, gamma: np.ndarray, growth: float = GROWTH):
    """:func:`gamma_margins` of the systems ``idx`` (flat batch positions) of an
    :func:`exponent_polynomial` at levels ``gamma`` (same length): (passed, rho, kappa)."""
    W0, W1, W2 = (np.ascontiguousarray(W.reshape((-1,) + W.shape[-3:])) for W in poly)
    ig = 1.0 / np.asarray(gamma, dtype=float)
    omega = exponents_at(W0, W1, W2, np.asarray(idx, dtype=np.int64), ig)
    with np.errstate(all="ignore"):
        passed, rho, kappa = gamma_test_omegas(omega, True, float(growth))
    passed = passed & (np.asarray(gamma) > 0)
    return passed, np.where(passed, rho, np.nan), np.where(passed, kappa, np.nan)


def _sampled_once(sys: LTPSystem, steps: int) -> LTPSystem:
    """``sys`` with its callable matrices evaluated once at the Magnus nodes of ``steps`` intervals.

    Every gamma-test of :func:`hinfnorm` samples A, B, C (D) at the same nodes, and for the attitude
    model (B(t) K from the field model) that sampling was ~0.5 ms of a ~3.5 ms test at 64 steps;
    other times (the feedthrough bound, the starting guess) still call the original matrices."""
    nodes = interval_grid(sys.period, steps)[2].ravel()

    def once(M):
        if not callable(M):
            return M
        at = np.asarray(M(nodes), dtype=float)

        def f(t, M=M, at=at):
            t = np.asarray(t, dtype=float)
            return at if t.shape == nodes.shape and np.array_equal(t, nodes) else M(t)
        return f
    return LTPSystem(once(sys.A), once(sys.B), once(sys.C), once(sys.D), sys.period)


def _test_some(sys, gam, steps, which, poly=None):
    """The margins test of the (system, level) pairs of gam (*batch, g) where ``which`` is True.

    ``which`` is (*batch) (whole rows) or (*batch, g) (single pairs); only those pairs are
    computed, as one flat batch (from ``poly``, the system's :func:`exponent_polynomial`, when
    given). Returns (passed (*batch, g), margins (*batch, g, 2) = ((ln rho)^2, 1 - kappa)); the
    other pairs get (False, NaN), which the callers ignore."""
    batch, g = gam.shape[:-1], gam.shape[-1]
    which = np.broadcast_to(which if which.ndim == gam.ndim else which[..., None], gam.shape)
    passed = np.zeros(gam.shape, dtype=bool)
    marg = np.full(gam.shape + (2,), np.nan)
    if not which.any():
        return passed, marg
    flat = np.flatnonzero(which.reshape(-1))
    if poly is not None:
        p, r, k = _margins_from_polynomial(poly, flat // g, gam.reshape(-1)[flat])
    elif flat.size == gam.size:  # every pair: the systems paired with their rows, no subsetting
        p, r, k = (v.reshape(-1) for v in _test_grid(sys, gam, steps))
    else:
        p, r, k = gamma_margins(_subset(sys, batch, flat // g), gam.reshape(-1)[flat], steps)
    passed.reshape(-1)[flat] = p
    with np.errstate(all="ignore"):
        marg.reshape(-1, 2)[flat] = np.stack([np.log(r) ** 2, 1.0 - k], axis=-1)
    return passed, marg


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


def _test_grid(sys, gam, steps):
    """gamma_margins on gam (*batch, g): the batch is expanded so every system sees its own row."""
    return gamma_margins(_expand(sys, gam.shape[-1]), gam, steps)


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


def _scale_guess(sys: LTPSystem, t: np.ndarray | None = None) -> np.ndarray:
    """Starting level: the peak gain of the time-averaged LTI system over its modal frequencies
    (0, |Im lambda|, |lambda|; one batched solve and SVD), a lower bound of that system's H-inf
    norm and usually within ~25 % of the LTP norm; else an order of magnitude ||C|| ||B|| /
    |slowest decay rate| of the mean A. Only a guess: the bracketing moves from it. The average is
    taken over the times ``t`` (default 64 equally spaced; ``hinfnorm`` passes the Magnus nodes,
    where :func:`_sampled_once` has the matrices already)."""
    if int(np.prod(_batch_shape(sys))) == 1:
        t = np.arange(64) * sys.period / 64 if t is None else t
        A, B, C, D = [(lambda v: v.mean(axis=-3).reshape(v.shape[-2:]))(np.asarray(sys.sample(n, t)))
                      for n in ("A", "B", "C", "D")]
        lam = np.linalg.eigvals(A)
        if np.all(lam.real < 0):
            w = np.concatenate([[0.0], np.abs(lam.imag), np.abs(lam)])
            G = C @ np.linalg.solve(1j * w[:, None, None] * np.eye(A.shape[0]) - A, B.astype(complex)) + D
            g = float(np.linalg.svd(G, compute_uv=False)[:, 0].max())
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
