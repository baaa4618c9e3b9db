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
the slightly shifted block). So pass/fail agrees except within round-off of the norm itself
(``tests/ltp/test_hinf_kernel.py`` compares the two). Compiled on first use, cached on disk (``cache=True``).

Hand-written linear algebra. numba's ``np.linalg`` wrappers copy, check and allocate on every call,
which for 6x6 and 12x12 matrices costs more than the arithmetic (one Pade-13 exponential took ~25 us,
one star product ~14.5 us). So the hot path is plain loops on work arrays allocated once per call of
:func:`gamma_test_omegas`: the small dense kernels of :mod:`.small_linalg` (register-row matrix
products, LU with partial pivoting, Cholesky, the largest eigenvalue of a symmetric matrix by
Householder + implicit QL: backward stable, error ~ eps ||.|| = eps kappa for the PSD L' Ga L), the
Pade-13 sums in the order of :func:`.expm.pade13_scaled` (one pass each) and the star product's two
solves as one (n, 2n) right-hand side. Measured against the library-call version (git 4091808,
``bench/bench_kernel.py``, both in one process on a shared 2-core machine): a full test is ~2.9-3.5x
faster (sigma = 120 at 512 intervals: ~21-37 -> ~7-10 ms with the load), Pade-13 ~2.8x (now mostly
its six 12x12 products at scalar speed), a star product ~3.7x, kappa ~3.9x. A failing interval or
junction ends the test at once (the result, False / NaN / NaN, cannot change after it). Only the
rare paths keep ``np.linalg``: kappa for an Hb that is not PSD to round-off, and the decay rho (one
solve and one ``eigvals`` per system). Where the library version raised (a singular Pade
denominator, a non-finite L' Ga L in ``eigvalsh``) this one returns NaN, i.e. the test fails.

Threads: a single system's intervals and the pairs of each tree level are
independent, so :func:`_one_threads` splits them over numba's threads (``prange``; bit-identical to
:func:`_one`): ~1.9x on 2 cores for the test, ~1.45x for a whole single-gain J (bench/bench_kernel.py),
whose remaining time is the Python level placement of :func:`.hinf.hinfnorm`. Batches stay in one
thread per process (the tuner's worker processes are faster than threads there).
"""
from __future__ import annotations

import threading

import numba
import numpy as np
from numba import njit, prange

from .expm import _B13, _THETA13  # the same Pade-13 coefficients and scaling threshold
from .small_linalg import _FM, _cholesky, _eigmax_sym, _finite, _lu, _lu_solve, _matmul, _norm1, _sym_into, _trace

_CONVERGED = 1e-13
_MAX_DOUBLINGS = 48
_PSD_RTOL = 1e-9
_GROWTH = 1e6  # largest ||exp||_1 squared as a matrix (hinf.interval_scattering)
_NW_PADE = 8  # (2n, 2n) work arrays of _pade_into
_NW_STAR = 8  # (n, n) work arrays of _star_into / _scattering_into
_NW_WIDE = 6  # (n, 2n) work arrays of _star_into


# ---------------------------------------------------------------- the gamma-test

@njit(cache=True, fastmath=_FM)
def _pade_into(a, r, w, piv):
    """r = exp(a / 2^s) by Pade 13 as :func:`.expm.pade13_scaled`; returns s. r is NaN and s = 0 if a is
    not finite (or, never met, the Pade denominator is singular). w: (_NW_PADE, n, n) work arrays."""
    n = a.shape[0]
    norm1 = _norm1(a)
    if not np.isfinite(norm1):
        r[:, :] = np.nan
        return 0
    s = 0
    if norm1 > _THETA13:
        s = int(np.ceil(np.log2(norm1 / _THETA13)))
    sc = 2.0 ** -s
    b = _B13
    A, A2, A4, A6, T, U1, U, V = w[0], w[1], w[2], w[3], w[4], w[5], w[6], w[7]
    nn = n * n  # the elementwise sums run over flat views (loops long enough to vectorize)
    wf = w.reshape(w.shape[0], nn)
    Af, A2f, A4f, A6f, Tf, U1f, Uf, Vf = wf[0], wf[1], wf[2], wf[3], wf[4], wf[5], wf[6], wf[7]
    af, rf = a.reshape(nn), r.reshape(nn)
    for t in range(nn):
        Af[t] = af[t] * sc
    _matmul(A, A, A2)
    _matmul(A2, A2, A4)
    _matmul(A4, A2, A6)
    for t in range(nn):  # the sums of expm.pade13_scaled, in its order (the identity terms last)
        Tf[t] = b[13] * A6f[t] + b[11] * A4f[t] + b[9] * A2f[t]
    _matmul(A6, T, U1)
    for t in range(nn):
        U1f[t] = U1f[t] + b[7] * A6f[t] + b[5] * A4f[t] + b[3] * A2f[t]
    for i in range(n):
        U1[i, i] += b[1]
    _matmul(A, U1, U)
    for t in range(nn):
        Tf[t] = b[12] * A6f[t] + b[10] * A4f[t] + b[8] * A2f[t]
    _matmul(A6, T, V)
    for t in range(nn):
        Vf[t] = Vf[t] + b[6] * A6f[t] + b[4] * A4f[t] + b[2] * A2f[t]
    for i in range(n):
        V[i, i] += b[0]
    for t in range(nn):
        Tf[t] = Vf[t] - Uf[t]
        rf[t] = Vf[t] + Uf[t]
    if not _lu(T, piv):
        r[:, :] = np.nan
        return 0
    _lu_solve(T, piv, r)
    return s


@njit(cache=True)
def _pade_scaled(a):
    """(exp(a / 2^s) by Pade 13, s) as :func:`.expm.pade13_scaled`; NaN and s = 0 if a is not finite."""
    n = a.shape[0]
    r = np.empty((n, n))
    s = _pade_into(np.ascontiguousarray(a), r, np.empty((_NW_PADE, n, n)), np.empty(n, dtype=np.int64))
    return r, s


@njit(cache=True)
def _psd(x, L):
    """x >= 0 up to round-off: Cholesky of x + (_PSD_RTOL tr(x) / n) I succeeds (no eigenproblem).
    The shift is at most _PSD_RTOL lambda_max, the tolerance of :func:`.hinf._psd`. L: (n, n) work."""
    n = x.shape[0]
    return _cholesky(x, _PSD_RTOL * abs(_trace(x)) / n + 1e-300, L)


@njit(cache=True)
def _kappa_into(Ga, Hb, w, wv):
    """Largest eigenvalue of Ga Hb (both symmetric >= 0) as that of L' Ga L, L L' = Hb + delta I.

    delta = 1e-14 tr(Hb) makes a semidefinite Hb factorable and raises kappa by at most
    delta lambda_max(Ga), far below the margins hinfnorm reads. One Cholesky and one symmetric
    eigenproblem instead of the two eigenproblems of Hb^1/2 Ga Hb^1/2 (:func:`.hinf._max_eig_product`);
    an Hb that is not >= 0 to round-off takes that route (np.linalg). w: (>= 4, n, n), wv: (4, n) work."""
    n = Hb.shape[0]
    Hs, Gs, L, M = w[0], w[1], w[2], w[3]
    _sym_into(Hb, Hs)
    _sym_into(Ga, Gs)
    if not _cholesky(Hs, 1e-14 * abs(_trace(Hs)) + 1e-300, L):
        lam, V = np.linalg.eigh(Hs)
        Hh = (V * np.sqrt(np.maximum(lam, 0.0))) @ V.T
        return np.linalg.eigvalsh(Hh @ Gs @ Hh)[-1]
    _matmul(Gs, L, M)  # Gs L, then the lower triangle of L' (Gs L) (L lower triangular) into Gs
    for i in range(n):
        for j in range(i + 1):
            v = 0.0
            for k in range(i, n):
                v += L[k, i] * M[k, j]
            Gs[i, j] = v
    return _eigmax_sym(Gs, Hs, wv)


@njit(cache=True)
def _kappa(Ga, Hb):
    """Largest eigenvalue of Ga Hb (symmetric >= 0) as the kernel computes it (allocating wrapper)."""
    n = Hb.shape[0]
    return _kappa_into(np.ascontiguousarray(Ga), np.ascontiguousarray(Hb), np.empty((4, n, n)), np.empty((4, n)))


@njit(cache=True)
def _star_into(Ea, Ga, Ha, Fa, Eb, Gb, Hb, Fb, E, G, H, F, w, ww, wv, piv):
    """Redheffer star product (earlier a, later b) as :func:`.hinf.star` into E, G, H, F (which may alias
    the inputs): (ok, kappa); on failure E, G, H, F are left unspecified. w: (_NW_STAR, n, n),
    ww: (_NW_WIDE, n, 2n), wv: (4, n) work arrays. The two right-hand sides Ea, Ga Fb share one
    (n, 2n) solve, and the products by Ga, Fa, Eb, Fa Hb are each one (n, n) x (n, 2n) product."""
    n = Ea.shape[0]
    kappa = np.inf
    if not (_finite(Ga) and _finite(Hb)):
        return False, kappa
    kappa = _kappa_into(Ga, Hb, w, wv)
    S, FaHb, P = w[4], w[5], w[6]
    B, GB, X, FB, EX, FX = ww[0], ww[1], ww[2], ww[3], ww[4], ww[5]
    for i in range(n):
        for j in range(n):
            B[i, j] = Hb[i, j]
            B[i, n + j] = Fb[i, j]
    _matmul(Ga, B, GB)  # [Ga Hb | Ga Fb]
    for i in range(n):
        for j in range(n):
            S[i, j] = (1.0 if i == j else 0.0) - GB[i, j]
            X[i, j] = Ea[i, j]
            X[i, n + j] = GB[i, n + j]
    if not (_finite(S) and _finite(X)):  # (np.linalg.solve raised on a non-finite right-hand side)
        return False, kappa
    if not _lu(S, piv):  # singular junction: a conjugate point exactly there
        return False, kappa
    _lu_solve(S, piv, X)  # [S^-1 Ea | S^-1 Ga Fb]
    _matmul(Fa, B, FB)  # [Fa Hb | Fa Fb]
    _matmul(Eb, X, EX)
    for i in range(n):
        for j in range(n):
            FaHb[i, j] = FB[i, j]
    _matmul(FaHb, X, FX)
    for i in range(n):
        for j in range(n):
            P[i, j] = Ha[i, j] + FX[i, j]
    for i in range(n):  # the inputs are no longer read (but Gb, elementwise): write the outputs
        for j in range(n):
            E[i, j] = EX[i, j]
            G[i, j] = Gb[i, j] + EX[i, n + j]
            H[i, j] = 0.5 * (P[i, j] + P[j, i])
            F[i, j] = FB[i, n + j] + FX[i, n + j]
    ok = _finite(E) and _finite(G) and _finite(H) and _finite(F) and kappa < 1.0
    if ok:
        ok = _psd(H, P)
    return ok, kappa


@njit(cache=True)
def _star(Ea, Ga, Ha, Fa, Eb, Gb, Hb, Fb):
    """Redheffer star product (earlier a, later b) as :func:`.hinf.star`: blocks, ok, kappa (allocating wrapper)."""
    n = Ea.shape[0]
    E, G, H, F = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    c = np.ascontiguousarray
    ok, kappa = _star_into(c(Ea), c(Ga), c(Ha), c(Fa), c(Eb), c(Gb), c(Hb), c(Fb), E, G, H, F,
                           np.empty((_NW_STAR, n, n)), np.empty((_NW_WIDE, n, 2 * n)), np.empty((4, n)),
                           np.empty(n, dtype=np.int64))
    return E, G, H, F, ok, kappa


@njit(cache=True)
def _scattering_into(phi, E, G, Hs, F, w, piv):
    """Scattering blocks (E, G, Hs, F) of one Hamiltonian transition; False if P22 is singular or the
    blocks are not finite. w: (>= 5, n, n) work arrays."""
    n = E.shape[0]
    if not _finite(phi):
        return False
    P11, P12, P21, P22, T = w[0], w[1], w[2], w[3], w[4]
    for i in range(n):
        for j in range(n):
            P11[i, j] = phi[i, j]
            P12[i, j] = phi[i, n + j]
            P21[i, j] = phi[n + i, j]
            P22[i, j] = phi[n + i, n + j]
            F[i, j] = 1.0 if i == j else 0.0
    if not _lu(P22, piv):
        return False
    _lu_solve(P22, piv, F)
    _matmul(P12, F, G)
    _matmul(F, P21, T)
    for i in range(n):
        for j in range(n):
            Hs[i, j] = -T[i, j]
    _matmul(P12, Hs, E)
    for i in range(n):
        for j in range(n):
            E[i, j] = P11[i, j] + E[i, j]
    return _finite(E) and _finite(G) and _finite(Hs) and _finite(F)


@njit(cache=True)
def _interval_into(a, growth, E, G, H, F, r, r2, wp, w, ww, wv, piv):
    """Scattering blocks of exp(a) for one interval into E, G, H, F, squared as a matrix while
    ||.||_1 <= growth and then in scattering form (star products), as :func:`.hinf.interval_scattering`:
    (ok, kappa). r, r2: (2n, 2n) work; wp, w, ww, wv: work arrays of _pade_into and _star_into."""
    s = _pade_into(a, r, wp, piv)
    k = 0
    while k < s:
        _matmul(r, r, r2)
        if not _norm1(r2) <= growth:
            break
        r, r2 = r2, r
        k += 1
    ok = _scattering_into(r, E, G, H, F, w, piv)
    kappa = -np.inf
    for _ in range(s - k):
        if not ok:
            break
        okk, kap = _star_into(E, G, H, F, E, G, H, F, E, G, H, F, w, ww, wv, piv)
        ok = ok and okk
        kappa = max(kappa, kap)
    return ok, kappa


@njit(cache=True)
def _join_last_two(E, G, H, F, m, w, ww, wv, piv):
    """Star product of intervals m - 2 and m - 1 into slot m - 2 (an odd level of the tree): (ok, kappa)."""
    a, b = m - 2, m - 1
    return _star_into(E[a], G[a], H[a], F[a], E[b], G[b], H[b], F[b], E[a], G[a], H[a], F[a], w, ww, wv, piv)


@njit(cache=True)
def _one(omega, margins, growth, E, G, H, F, r, r2, wp, w, ww, wv, piv):
    """Gamma-test of one system from its Magnus exponents omega (steps, 2n, 2n): (passed, rho, kappa).
    E, G, H, F: (steps, n, n) and the rest work arrays (:func:`gamma_test_omegas`)."""
    steps = omega.shape[0]
    kappa = -np.inf
    for k in range(steps):
        okk, kap = _interval_into(omega[k], growth, E[k], G[k], H[k], F[k], r, r2, wp, w, ww, wv, piv)
        if not okk:  # the test has failed: nothing after this can change (False, NaN, NaN)
            return False, np.nan, np.nan
        kappa = max(kappa, kap)
    # pairwise tree over the period, earlier interval first (the pairing of hinf.period_scattering)
    m = steps
    while m > 1:
        if m % 2:
            okt, kap = _join_last_two(E, G, H, F, m, w, ww, wv, piv)
            if not okt:
                return False, np.nan, np.nan
            kappa = max(kappa, kap)
            m -= 1
            continue
        for i in range(m // 2):
            a, b = 2 * i, 2 * i + 1
            okt, kap = _star_into(E[a], G[a], H[a], F[a], E[b], G[b], H[b], F[b], E[i], G[i], H[i], F[i], w, ww, wv, piv)
            if not okt:
                return False, np.nan, np.nan
            kappa = max(kappa, kap)
        m //= 2
    return _close(E[0], G[0], H[0], F[0], kappa, margins, w, ww, wv, piv)


@njit(cache=True)
def _close(Ek, Gk, Hk, Fk, kappa, margins, w, ww, wv, piv):
    """The end of a gamma-test from the period's blocks (overwritten): doublings until E has decayed,
    then the decay rho. (passed, rho, kappa) as :func:`_one`."""
    n = Ek.shape[0]
    E1, G1 = Ek.copy(), Gk.copy()
    done = False
    for _ in range(_MAX_DOUBLINGS):
        small = True
        for i in range(n):
            for j in range(n):
                if not abs(Ek[i, j]) < _CONVERGED:  # as np.max(np.abs(Ek)) < _CONVERGED (NaN: not small)
                    small = False
        if small:
            done = True
            break
        okd, kap = _star_into(Ek, Gk, Hk, Fk, Ek, Gk, Hk, Fk, Ek, Gk, Hk, Fk, w, ww, wv, piv)  # 2^k -> 2^(k+1) periods
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
def _gamma_test_serial(omega, margins, growth=_GROWTH):
    """:func:`gamma_test_omegas` in one thread, the systems one after the other: (passed, rho, kappa)."""
    N, steps, n2 = omega.shape[0], omega.shape[1], omega.shape[2]
    n = n2 // 2
    passed = np.zeros(N, dtype=np.bool_)
    rho = np.full(N, np.nan)
    kappa = np.full(N, np.nan)
    # the interval blocks and the work arrays, allocated once for all systems
    E = np.empty((steps, n, n))
    G = np.empty((steps, n, n))
    H = np.empty((steps, n, n))
    F = np.empty((steps, n, n))
    r = np.empty((n2, n2))
    r2 = np.empty((n2, n2))
    wp = np.empty((_NW_PADE, n2, n2))
    w = np.empty((_NW_STAR, n, n))
    ww = np.empty((_NW_WIDE, n, n2))
    wv = np.empty((4, n))
    piv = np.empty(n2, dtype=np.int64)
    for i in range(N):
        p, rh, k = _one(np.ascontiguousarray(omega[i]), margins, growth, E, G, H, F, r, r2, wp, w, ww, wv, piv)
        passed[i] = p
        if p:
            rho[i] = rh
            kappa[i] = k
    return passed, rho, kappa


@njit(cache=True)
def _work(n):
    """The work arrays of one gamma-test of an n-state system (r, r2, wp, w, ww, wv, piv of :func:`_one`)."""
    n2 = 2 * n
    return (np.empty((n2, n2)), np.empty((n2, n2)), np.empty((_NW_PADE, n2, n2)), np.empty((_NW_STAR, n, n)),
            np.empty((_NW_WIDE, n, n2)), np.empty((4, n)), np.empty(n2, dtype=np.int64))


@njit(cache=True, parallel=True)
def _one_threads(omega, margins, growth, threads):
    """:func:`_one` with its intervals and each level of its tree split over ``threads`` threads (one
    system: the single-gain J of ``magtune analyze``). Every interval and junction is the same
    arithmetic as in :func:`_one` (same pairing; each level writes a second buffer, so no pair reads a
    slot another pair writes), and the max over junctions does not depend on their order: the result
    is bit-identical. A failed interval or junction ends its thread's share, not the others'."""
    steps, n = omega.shape[0], omega.shape[1] // 2
    E, G, H, F = np.empty((steps, n, n)), np.empty((steps, n, n)), np.empty((steps, n, n)), np.empty((steps, n, n))
    E2, G2, H2, F2 = np.empty_like(E), np.empty_like(E), np.empty_like(E), np.empty_like(E)
    ok = np.ones(threads, dtype=np.bool_)
    kap = np.full(threads, -np.inf)
    for t in prange(threads):
        r, r2, wp, w, ww, wv, piv = _work(n)
        for k in range(t, steps, threads):
            okk, kk = _interval_into(omega[k], growth, E[k], G[k], H[k], F[k], r, r2, wp, w, ww, wv, piv)
            if not okk:
                ok[t] = False
                break
            kap[t] = max(kap[t], kk)
    if not ok.all():
        return False, np.nan, np.nan
    kappa = kap.max()
    r, r2, wp, w, ww, wv, piv = _work(n)
    m = steps
    while m > 1:
        if m % 2:  # odd: the last two joined in place, as in _one
            okt, kk = _join_last_two(E, G, H, F, m, w, ww, wv, piv)
            if not okt:
                return False, np.nan, np.nan
            kappa = max(kappa, kk)
            m -= 1
            continue
        for t in prange(threads):
            r_, r2_, wp_, w_, ww_, wv_, piv_ = _work(n)
            for i in range(t, m // 2, threads):
                a, b = 2 * i, 2 * i + 1
                okt, kk = _star_into(E[a], G[a], H[a], F[a], E[b], G[b], H[b], F[b], E2[i], G2[i], H2[i], F2[i],
                                     w_, ww_, wv_, piv_)
                if not okt:
                    ok[t] = False
                    break
                kap[t] = max(kap[t], kk)
        if not ok.all():
            return False, np.nan, np.nan
        kappa = max(kappa, kap.max())
        E, G, H, F, E2, G2, H2, F2 = E2, G2, H2, F2, E, G, H, F
        m //= 2
    return _close(E[0], G[0], H[0], F[0], kappa, margins, w, ww, wv, piv)


@njit(cache=True)
def exponents_at(W0, W1, W2, idx, ig):
    """Magnus exponents W0 + ig (W1 + ig W2) of the systems ``idx`` of an exponent polynomial
    (:func:`.hinf.exponent_polynomial`, flat batch (N, steps, 2n, 2n)) at 1/gamma = ``ig``: the
    gamma-test's input gathered and formed in one pass (numpy took ~0.13 ms per single-gain level at
    64 steps in copies and temporaries, 1/5 of the test). Same operations in the same order as the
    numpy expression, no FMA: bit-identical to it.

    Parameters
    ----------
    W0, W1, W2 : ndarray (N, steps, 2n, 2n)
        The coefficients of the 4th-order Magnus exponents (Magnus 1954) in 1/gamma.
    idx : ndarray of int64 (k,)
        Which systems.
    ig : ndarray (k,)
        1/gamma for each.

    Returns
    -------
    ndarray (k, steps, 2n, 2n)
        The exponents, the input of :func:`gamma_test_omegas`.
    """
    out = np.empty((idx.shape[0],) + W0.shape[1:])
    for k in range(idx.shape[0]):
        i, g = idx[k], ig[k]
        for s in range(W0.shape[1]):
            for a in range(W0.shape[2]):
                for b in range(W0.shape[3]):
                    out[k, s, a, b] = W0[i, s, a, b] + g * (W1[i, s, a, b] + g * W2[i, s, a, b])
    return out


def gamma_test_omegas(omega, margins, growth=_GROWTH):
    """The gamma-test of every system of omega (N, steps, 2n, 2n) (Magnus exponents of the Hamiltonian).

    The periodic bounded real lemma's test (Bittanti & Colaneri 2009, ch. 9; see :mod:`.hinf`) of
    ||G||_inf < gamma, the norm of paper eq. (21), compiled.

    ``growth``: the largest ||exp(Omega / 2^j)||_1 squared as a matrix before the squarings go on in
    scattering form (:func:`.hinf.interval_scattering`); ``np.inf`` is the plain exponential (the
    arithmetic before issue 9's stiff gains; ``bench/bench_tuner.py`` compares the two).

    Threads: a single system (``magtune analyze``, the tuner's incumbent checks) has its intervals and
    junctions split over numba's threads (``numba.set_num_threads``: all cores by default; 1 in the
    tuner's worker processes), in the main thread only; the result is bit-identical to one thread's
    (tests/ltp/test_hinf_kernel.py). A batch runs in one thread: the tuner spreads its populations
    over worker processes, which was faster (bench/bench_kernel.py: 26 ms/gain with 2 processes
    against 32 with 2 threads at 256 steps; the processes also share the Python around the kernel).

    Parameters
    ----------
    omega : ndarray (N, steps, 2n, 2n)
        Magnus exponents of the Hamiltonian at one level gamma per system (e.g. :func:`exponents_at`).
    margins : bool
        Also compute the decay rho (kappa is computed either way).
    growth : float
        Largest ||exp(Omega / 2^j)||_1 squared as a matrix (see above; default 1e6).

    Returns
    -------
    passed : ndarray of bool (N,)
        True where the test passes: ||G||_inf < gamma.
    rho : ndarray (N,)
        Decay of the Hamiltonian closed loop over one period (NaN where failed or not asked).
    kappa : ndarray (N,)
        Largest junction eigenvalue (NaN where failed).
    """
    omega = np.ascontiguousarray(omega, dtype=float)
    # numba's default (workqueue) threading layer must not be entered by two Python threads at once
    # (it aborts the process): other threads (e.g. a Dask worker's) take the serial kernel
    threads = numba.get_num_threads() if threading.current_thread() is threading.main_thread() else 1
    if threads == 1 or omega.shape[0] != 1 or omega.shape[1] < 4 * threads:
        return _gamma_test_serial(omega, margins, growth)
    p, rh, k = _one_threads(omega[0], margins, growth, threads)
    return np.array([p]), np.array([rh if p else np.nan]), np.array([k if p else np.nan])


def compile_all(n: int = 6, steps: int = 8) -> None:
    """Compile (or load from numba's on-disk cache) every entry point of the kernel, serial and threaded.

    Why: the first gamma-test of a new install otherwise pauses ~70 s to compile (~46 s serial,
    ~24 s threaded); ``scripts/bootstrap.sh`` calls this once per change of this file (or of
    :mod:`.small_linalg`, whose routines these entry points compile with them), so that
    compilation happens at install time, as a C extension's would. The inputs are a stable
    n-state Hamiltonian's exponents (any values of the right types compile the same code).

    Parameters
    ----------
    n : int
        State dimension of the dummy system (the Hamiltonian is 2n x 2n).
    steps : int
        Magnus intervals of the dummy system.
    """
    a = -np.eye(n)
    ham = np.zeros((2 * n, 2 * n))
    ham[:n, :n], ham[n:, n:], ham[:n, n:], ham[n:, :n] = a, -a.T, 0.1 * np.eye(n), -0.1 * np.eye(n)
    omega = np.ascontiguousarray(np.broadcast_to(ham / steps, (1, steps, 2 * n, 2 * n)))
    exponents_at(omega, omega, omega, np.zeros(1, dtype=np.int64), np.ones(1))
    for margins in (True, False):
        _gamma_test_serial(omega, margins, _GROWTH)
        _one_threads(omega[0], margins, _GROWTH, 2)
