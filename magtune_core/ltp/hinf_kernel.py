"""Compiled gamma-test (numba): the scattering / star-product test of :mod:`.hinf` for one system at a time.

Why compiled code. Profiled at 64 Magnus steps, one numpy gamma-test costs ~8 ms for a single gain
(~50 numpy calls per star product, ~15 products: call overhead) and ~4 ms per gain in a batch of 500
(the 64 Pade-13 exponentials of 12x12 matrices and the star products of 6x6 blocks, every one a pass
over memory through numpy temporaries). The same arithmetic as one compiled loop per system is several
times cheaper in both cases, and ``hinfnorm`` needs ~10-15 tests per J(K).

The kernel follows the numpy gamma-test of :mod:`.hinf` step by step (same interval blocks,
:func:`.hinf.interval_scattering`, with the same Pade-13 scaling as :func:`.expm.expm` and the same
switch to squaring in scattering form; same pairwise tree over the period with the same pairing, same
doubling, same conjugate-point, PSD and decay tests). Two things differ: the floating-point summation
order of the matrix products, and the star product's eigenproblems, replaced by Cholesky
factorizations (kappa as the top eigenvalue of L' Ga L with L L' = Hb, the PSD test as a Cholesky of
the slightly shifted block: 15 us per star product instead of 27 us). So pass/fail agrees except within
round-off of the norm itself (``tests/ltp/test_hinf_kernel.py`` compares the two). Compiled on first use, cached on disk (``cache=True``).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .expm import _B13, _THETA13  # the same Pade-13 coefficients and scaling threshold

_CONVERGED = 1e-13
_MAX_DOUBLINGS = 48
_PSD_RTOL = 1e-9
_GROWTH = 1e6  # largest ||exp||_1 squared as a matrix (hinf.interval_scattering)


@njit(cache=True)
def _norm1(a):
    n1 = 0.0
    for j in range(a.shape[1]):
        c = 0.0
        for i in range(a.shape[0]):
            c += abs(a[i, j])
        n1 = max(n1, c)
    return n1


@njit(cache=True)
def _pade_scaled(a):
    """(exp(a / 2^s) by Pade 13, s) as :func:`.expm.pade13_scaled`; NaN and s = 0 if a is not finite."""
    n = a.shape[0]
    norm1 = _norm1(a)
    if not np.isfinite(norm1):
        return np.full((n, n), np.nan), 0
    s = 0
    if norm1 > _THETA13:
        s = int(np.ceil(np.log2(norm1 / _THETA13)))
    a = a * (2.0 ** -s)
    b = _B13
    eye = np.eye(n)
    a2 = a @ a
    a4 = a2 @ a2
    a6 = a4 @ a2
    u = a @ (a6 @ (b[13] * a6 + b[11] * a4 + b[9] * a2) + b[7] * a6 + b[5] * a4 + b[3] * a2 + b[1] * eye)
    v = a6 @ (b[12] * a6 + b[10] * a4 + b[8] * a2) + b[6] * a6 + b[4] * a4 + b[2] * a2 + b[0] * eye
    return np.ascontiguousarray(np.linalg.solve(v - u, v + u)), s


@njit(cache=True)
def _finite(x):
    return np.all(np.isfinite(x))


@njit(cache=True)
def _sym(x):
    return 0.5 * (x + x.T)


@njit(cache=True)
def _trace(x):
    t = 0.0
    for i in range(x.shape[0]):
        t += x[i, i]
    return t


@njit(cache=True)
def _psd(x):
    """x >= 0 up to round-off: Cholesky of x + (_PSD_RTOL tr(x) / n) I succeeds (no eigenproblem).
    The shift is at most _PSD_RTOL lambda_max, the tolerance of :func:`.hinf._psd`."""
    n = x.shape[0]
    try:
        np.linalg.cholesky(x + (_PSD_RTOL * abs(_trace(x)) / n + 1e-300) * np.eye(n))
    except Exception:
        return False
    return True


@njit(cache=True)
def _kappa(Ga, Hb):
    """Largest eigenvalue of Ga Hb (both symmetric >= 0) as that of L' Ga L, L L' = Hb + delta I.

    delta = 1e-14 tr(Hb) makes a semidefinite Hb factorable and raises kappa by at most
    delta lambda_max(Ga), far below the margins hinfnorm reads. One Cholesky and one symmetric
    eigenproblem instead of the two eigenproblems of Hb^1/2 Ga Hb^1/2 (:func:`.hinf._max_eig_product`);
    an Hb that is not >= 0 to round-off takes that route."""
    n = Hb.shape[0]
    H = _sym(Hb)
    try:
        L = np.linalg.cholesky(H + (1e-14 * abs(_trace(H)) + 1e-300) * np.eye(n))
    except Exception:
        lam, V = np.linalg.eigh(H)
        Hh = (V * np.sqrt(np.maximum(lam, 0.0))) @ V.T
        return np.linalg.eigvalsh(Hh @ _sym(Ga) @ Hh)[-1]
    return np.linalg.eigvalsh(L.T @ _sym(Ga) @ L)[-1]


@njit(cache=True)
def _star(Ea, Ga, Ha, Fa, Eb, Gb, Hb, Fb):
    """Redheffer star product (earlier a, later b) as :func:`.hinf.star`: blocks, ok, kappa."""
    n = Ea.shape[0]
    kappa = np.inf
    nanm = np.full((n, n), np.nan)
    if not (_finite(Ga) and _finite(Hb)):
        return nanm, nanm, nanm, nanm, False, kappa
    kappa = _kappa(Ga, Hb)
    S = np.eye(n) - Ga @ Hb
    if not _finite(S):
        return nanm, nanm, nanm, nanm, False, kappa
    rhs = np.empty((n, 2 * n))
    rhs[:, :n] = Ea
    rhs[:, n:] = Ga @ Fb
    try:
        X = np.linalg.solve(S, rhs)  # one LU for both right-hand sides
    except Exception:  # singular junction: a conjugate point exactly there
        return nanm, nanm, nanm, nanm, False, kappa
    SinvEa = np.ascontiguousarray(X[:, :n])
    SinvGaFb = np.ascontiguousarray(X[:, n:])
    E = Eb @ SinvEa
    G = Gb + Eb @ SinvGaFb
    FaHb = Fa @ Hb
    H = _sym(Ha + FaHb @ SinvEa)
    F = Fa @ Fb + FaHb @ SinvGaFb
    ok = _finite(E) and _finite(G) and _finite(H) and _finite(F) and kappa < 1.0
    if ok:
        ok = _psd(H)
    return E, G, H, F, ok, kappa


@njit(cache=True)
def _scattering(phi, n):
    """Scattering blocks (E, G, Hs, F) of one Hamiltonian transition; ok False if P22 is singular."""
    P11 = np.ascontiguousarray(phi[:n, :n])
    P12 = np.ascontiguousarray(phi[:n, n:])
    P21 = np.ascontiguousarray(phi[n:, :n])
    P22 = np.ascontiguousarray(phi[n:, n:])
    nanm = np.full((n, n), np.nan)
    if not _finite(phi):
        return nanm, nanm, nanm, nanm, False
    try:
        F = np.linalg.solve(P22, np.eye(n))
    except Exception:
        return nanm, nanm, nanm, nanm, False
    G = P12 @ F
    Hs = -F @ P21
    E = P11 + P12 @ Hs
    return E, G, Hs, F, _finite(E) and _finite(G) and _finite(Hs) and _finite(F)


@njit(cache=True)
def _interval(a, n, growth):
    """Scattering blocks of exp(a) for one interval, squared as a matrix while ||.||_1 <= growth and
    then in scattering form (star products), as :func:`.hinf.interval_scattering`: (E, G, Hs, F, ok, kappa)."""
    r, s = _pade_scaled(a)
    k = 0
    while k < s:
        sq = r @ r
        if not _norm1(sq) <= growth:
            break
        r = sq
        k += 1
    E, G, H, F, ok = _scattering(r, n)
    E, G, H, F = np.ascontiguousarray(E), np.ascontiguousarray(G), np.ascontiguousarray(H), np.ascontiguousarray(F)
    kappa = -np.inf
    for _ in range(s - k):
        if not ok:
            break
        E, G, H, F, okk, kap = _star(E, G, H, F, E, G, H, F)
        E, G, H, F = np.ascontiguousarray(E), np.ascontiguousarray(G), np.ascontiguousarray(H), np.ascontiguousarray(F)
        ok = ok and okk
        kappa = max(kappa, kap)
    return E, G, H, F, ok, kappa


@njit(cache=True)
def _one(omega, margins, growth):
    """Gamma-test of one system from its Magnus exponents omega (steps, 2n, 2n): (passed, rho, kappa)."""
    steps, n = omega.shape[0], omega.shape[1] // 2
    E = np.empty((steps, n, n))
    G = np.empty((steps, n, n))
    H = np.empty((steps, n, n))
    F = np.empty((steps, n, n))
    ok = True
    kappa = -np.inf
    for k in range(steps):
        e, g, h, f, okk, kap = _interval(np.ascontiguousarray(omega[k]), n, growth)
        E[k], G[k], H[k], F[k] = e, g, h, f
        ok = ok and okk
        kappa = max(kappa, kap)
    # pairwise tree over the period, earlier interval first (the pairing of hinf.period_scattering)
    m = steps
    while m > 1 and ok:
        if m % 2:
            e, g, h, f, okt, kap = _star(E[m - 2], G[m - 2], H[m - 2], F[m - 2], E[m - 1], G[m - 1], H[m - 1], F[m - 1])
            E[m - 2], G[m - 2], H[m - 2], F[m - 2] = e, g, h, f
            ok = ok and okt
            kappa = max(kappa, kap)
            m -= 1
            continue
        for i in range(m // 2):
            e, g, h, f, okt, kap = _star(E[2 * i], G[2 * i], H[2 * i], F[2 * i],
                                         E[2 * i + 1], G[2 * i + 1], H[2 * i + 1], F[2 * i + 1])
            E[i], G[i], H[i], F[i] = e, g, h, f
            ok = ok and okt
            kappa = max(kappa, kap)
        m //= 2
    if not ok:
        return False, np.nan, np.nan
    E1, G1 = E[0].copy(), G[0].copy()
    Ek, Gk, Hk, Fk = E[0].copy(), G[0].copy(), H[0].copy(), F[0].copy()
    done = False
    for _ in range(_MAX_DOUBLINGS):
        if np.max(np.abs(Ek)) < _CONVERGED:
            done = True
            break
        Ek, Gk, Hk, Fk, okd, kap = _star(Ek, Gk, Hk, Fk, Ek, Gk, Hk, Fk)  # horizon 2^k -> 2^(k+1) periods
        kappa = max(kappa, kap)
        if not okd:
            return False, np.nan, np.nan
    if not done:
        return False, np.nan, np.nan
    if not margins:
        return True, np.nan, kappa
    try:
        psi = np.linalg.solve(np.eye(n) - G1 @ Hk, E1)
    except Exception:
        return True, np.nan, kappa
    if not _finite(psi):
        return True, np.nan, kappa
    return True, np.max(np.abs(np.linalg.eigvals(psi.astype(np.complex128)))), kappa


@njit(cache=True)
def gamma_test_omegas(omega, margins, growth=_GROWTH):
    """The gamma-test of every system of omega (N, steps, 2n, 2n) (Magnus exponents of the Hamiltonian).

    ``growth``: the largest ||exp(Omega / 2^j)||_1 squared as a matrix before the squarings go on in
    scattering form (:func:`.hinf.interval_scattering`); ``np.inf`` is the plain exponential (the
    arithmetic before issue 9's stiff gains; ``bench/bench_tuner.py`` compares the two).

    Returns
    -------
    passed : ndarray of bool (N,)
    rho : ndarray (N,)
        Decay of the Hamiltonian closed loop over one period (NaN where failed or not asked).
    kappa : ndarray (N,)
        Largest junction eigenvalue (NaN where failed).
    """
    N = omega.shape[0]
    passed = np.zeros(N, dtype=np.bool_)
    rho = np.full(N, np.nan)
    kappa = np.full(N, np.nan)
    for i in range(N):
        p, r, k = _one(omega[i], margins, growth)
        passed[i] = p
        if p:
            rho[i] = r
            kappa[i] = k
    return passed, rho, kappa
