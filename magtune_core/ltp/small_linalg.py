"""Small dense linear algebra for the compiled gamma-test (numba, no allocation): moved out of :mod:`.hinf_kernel`.

Why hand-written. numba's ``np.linalg`` wrappers copy, check and allocate on every call, which for
the 6x6 and 12x12 matrices of the gamma-test (n = 6: 12x12 Hamiltonian exponents, 6x6 scattering
blocks) costs more than the arithmetic: ``np.linalg.solve`` of a 12x12 took ~7 us, a 6x6 ``eigvalsh``
~4.7 us, a 12x12 ``@`` ~0.8 us. So these are plain loops on caller-provided work arrays:

* :func:`_matmul` (with :func:`_mm6` / :func:`_mm12`): matrix products with each output row held in
  scalars (numba leaves LLVM's SLP vectorizer off, and a 6- or 12-long inner loop is too short for the
  loop vectorizer);
* :func:`_lu` / :func:`_lu_solve` (with :func:`_subst6` / :func:`_subst12`): LU with partial pivoting
  (LAPACK getrf/getrs's algorithm; singular means an exactly zero pivot, as there);
* :func:`_cholesky`: LAPACK potrf's algorithm (fails on a pivot <= 0 or NaN);
* :func:`_eigmax_sym`: the largest eigenvalue of a symmetric matrix by Householder tridiagonalization
  and implicit QL (EISPACK tql1), stopped by a Sturm count (:func:`_count_above`) once the top
  eigenvalue is found (backward stable: error ~ eps ||.||); cyclic Jacobi (:func:`_eigmax_jacobi`) as a
  fallback;
* elementwise helpers: :func:`_norm1`, :func:`_finite`, :func:`_copy`, :func:`_trace`, :func:`_sym_into`,
  :func:`_scale_sym`.

The code is :mod:`.hinf_kernel`'s as it was (same operations in the same order, same ``fastmath``
flags and ``cache=True``), so the norms it computes are unchanged bit for bit. Tested against
numpy / scipy in ``tests/ltp/test_small_linalg.py``.

Cache note: numba's on-disk cache of a function is invalidated by a change of *its own* source file
only, and :mod:`.hinf_kernel`'s cached functions contain this module's code (inlined at their
compilation). After editing this file, clear ``magtune_core/ltp/__pycache__/hinf_kernel.*`` (or touch
``hinf_kernel.py``) so that the kernel is recompiled.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

_JACOBI_SWEEPS = 50  # the fallback eigensolver (cyclic Jacobi) converges quadratically: 5-8 sweeps at n = 6
_QL_TOP_SHIFTS = 2  # QL steps of _eigmax_sym shifted above the spectrum (then Wilkinson-type)
_DEFLATE = 1e-16  # off-diagonal deflated by the QL of _eigmax_sym (matrix scaled to max |a_ij| ~ 1)
_FM = {"contract"}  # fused multiply-add allowed; no reassociation, NaN and inf semantics kept


# ---------------------------------------------------------------- small dense kernels (no allocation)

@njit(cache=True)
def _norm1(a):
    """Largest column sum of |a|. An inf entry gives inf, but a column with a NaN is skipped (its sum is
    NaN and ``max(n1, nan)`` keeps n1): callers that must reject NaN test :func:`_finite` as well."""
    n1 = 0.0
    for j in range(a.shape[1]):
        c = 0.0
        for i in range(a.shape[0]):
            c += abs(a[i, j])
        n1 = max(n1, c)
    return n1


@njit(cache=True)
def _finite(x):
    """True if every entry of the 2-d x is finite."""
    for i in range(x.shape[0]):
        for j in range(x.shape[1]):
            if not np.isfinite(x[i, j]):
                return False
    return True


@njit(cache=True)
def _copy(src, dst):
    """dst[:] = src for 2-d arrays of one shape."""
    for i in range(src.shape[0]):
        for j in range(src.shape[1]):
            dst[i, j] = src[i, j]


@njit(cache=True)
def _trace(x):
    """Trace of the square x."""
    t = 0.0
    for i in range(x.shape[0]):
        t += x[i, i]
    return t


@njit(cache=True)
def _sym_into(x, out):
    """out = (x + x') / 2."""
    n = x.shape[0]
    for i in range(n):
        for j in range(n):
            out[i, j] = 0.5 * (x[i, j] + x[j, i])


@njit(cache=True, fastmath=_FM)
def _mm6(a, b, out):
    """out = a @ b for b with 6 columns: each row of out accumulated in 6 scalars (registers)."""
    n, m = a.shape
    for i in range(n):
        c0, c1, c2, c3, c4, c5 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        for k in range(m):
            x = a[i, k]
            c0, c1, c2, c3, c4, c5 = c0 + x * b[k, 0], c1 + x * b[k, 1], c2 + x * b[k, 2], c3 + x * b[k, 3], c4 + x * b[k, 4], c5 + x * b[k, 5]
        out[i, 0], out[i, 1], out[i, 2], out[i, 3], out[i, 4], out[i, 5] = c0, c1, c2, c3, c4, c5


@njit(cache=True, fastmath=_FM)
def _mm12(a, b, out):
    """out = a @ b for b with 12 columns: each row of out accumulated in 12 scalars (registers)."""
    n, m = a.shape
    for i in range(n):
        c0, c1, c2, c3, c4, c5 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        c6, c7, c8, c9, c10, c11 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        for k in range(m):
            x = a[i, k]
            c0, c1, c2, c3, c4, c5 = c0 + x * b[k, 0], c1 + x * b[k, 1], c2 + x * b[k, 2], c3 + x * b[k, 3], c4 + x * b[k, 4], c5 + x * b[k, 5]
            c6, c7, c8, c9, c10, c11 = c6 + x * b[k, 6], c7 + x * b[k, 7], c8 + x * b[k, 8], c9 + x * b[k, 9], c10 + x * b[k, 10], c11 + x * b[k, 11]
        out[i, 0], out[i, 1], out[i, 2], out[i, 3], out[i, 4], out[i, 5] = c0, c1, c2, c3, c4, c5
        out[i, 6], out[i, 7], out[i, 8], out[i, 9], out[i, 10], out[i, 11] = c6, c7, c8, c9, c10, c11


@njit(cache=True, fastmath=_FM)
def _subst6(lu, b):
    """b <- U^-1 L^-1 b for 6 right-hand sides (rows of b in scalars), after the row swaps."""
    n = lu.shape[0]
    for i in range(n):  # unit lower triangle
        c0, c1, c2, c3, c4, c5 = b[i, 0], b[i, 1], b[i, 2], b[i, 3], b[i, 4], b[i, 5]
        for k in range(i):
            x = lu[i, k]
            c0, c1, c2, c3, c4, c5 = c0 - x * b[k, 0], c1 - x * b[k, 1], c2 - x * b[k, 2], c3 - x * b[k, 3], c4 - x * b[k, 4], c5 - x * b[k, 5]
        b[i, 0], b[i, 1], b[i, 2], b[i, 3], b[i, 4], b[i, 5] = c0, c1, c2, c3, c4, c5
    for i in range(n - 1, -1, -1):  # upper triangle
        c0, c1, c2, c3, c4, c5 = b[i, 0], b[i, 1], b[i, 2], b[i, 3], b[i, 4], b[i, 5]
        for k in range(i + 1, n):
            x = lu[i, k]
            c0, c1, c2, c3, c4, c5 = c0 - x * b[k, 0], c1 - x * b[k, 1], c2 - x * b[k, 2], c3 - x * b[k, 3], c4 - x * b[k, 4], c5 - x * b[k, 5]
        x = 1.0 / lu[i, i]
        b[i, 0], b[i, 1], b[i, 2], b[i, 3], b[i, 4], b[i, 5] = c0 * x, c1 * x, c2 * x, c3 * x, c4 * x, c5 * x


@njit(cache=True, fastmath=_FM)
def _subst12(lu, b):
    """b <- U^-1 L^-1 b for 12 right-hand sides (rows of b in scalars), after the row swaps."""
    n = lu.shape[0]
    for i in range(n):  # unit lower triangle
        c0, c1, c2, c3, c4, c5 = b[i, 0], b[i, 1], b[i, 2], b[i, 3], b[i, 4], b[i, 5]
        c6, c7, c8, c9, c10, c11 = b[i, 6], b[i, 7], b[i, 8], b[i, 9], b[i, 10], b[i, 11]
        for k in range(i):
            x = lu[i, k]
            c0, c1, c2, c3, c4, c5 = c0 - x * b[k, 0], c1 - x * b[k, 1], c2 - x * b[k, 2], c3 - x * b[k, 3], c4 - x * b[k, 4], c5 - x * b[k, 5]
            c6, c7, c8, c9, c10, c11 = c6 - x * b[k, 6], c7 - x * b[k, 7], c8 - x * b[k, 8], c9 - x * b[k, 9], c10 - x * b[k, 10], c11 - x * b[k, 11]
        b[i, 0], b[i, 1], b[i, 2], b[i, 3], b[i, 4], b[i, 5] = c0, c1, c2, c3, c4, c5
        b[i, 6], b[i, 7], b[i, 8], b[i, 9], b[i, 10], b[i, 11] = c6, c7, c8, c9, c10, c11
    for i in range(n - 1, -1, -1):  # upper triangle
        c0, c1, c2, c3, c4, c5 = b[i, 0], b[i, 1], b[i, 2], b[i, 3], b[i, 4], b[i, 5]
        c6, c7, c8, c9, c10, c11 = b[i, 6], b[i, 7], b[i, 8], b[i, 9], b[i, 10], b[i, 11]
        for k in range(i + 1, n):
            x = lu[i, k]
            c0, c1, c2, c3, c4, c5 = c0 - x * b[k, 0], c1 - x * b[k, 1], c2 - x * b[k, 2], c3 - x * b[k, 3], c4 - x * b[k, 4], c5 - x * b[k, 5]
            c6, c7, c8, c9, c10, c11 = c6 - x * b[k, 6], c7 - x * b[k, 7], c8 - x * b[k, 8], c9 - x * b[k, 9], c10 - x * b[k, 10], c11 - x * b[k, 11]
        x = 1.0 / lu[i, i]
        b[i, 0], b[i, 1], b[i, 2], b[i, 3], b[i, 4], b[i, 5] = c0 * x, c1 * x, c2 * x, c3 * x, c4 * x, c5 * x
        b[i, 6], b[i, 7], b[i, 8], b[i, 9], b[i, 10], b[i, 11] = c6 * x, c7 * x, c8 * x, c9 * x, c10 * x, c11 * x



@njit(cache=True, fastmath=_FM)
def _matmul(a, b, out):
    """out = a @ b (out must not alias a or b); rows in registers for 6 or 12 columns."""
    p = b.shape[1]
    if p == 12:
        _mm12(a, b, out)
    elif p == 6:
        _mm6(a, b, out)
    else:
        n, m = a.shape
        for i in range(n):
            for j in range(p):
                out[i, j] = 0.0
            for k in range(m):
                x = a[i, k]
                for j in range(p):
                    out[i, j] += x * b[k, j]


@njit(cache=True, fastmath=_FM)
def _lu(a, piv):
    """LU with partial pivoting of the square a in place (LAPACK getrf's algorithm); False if singular
    (an exactly zero pivot, where getrf reports info > 0)."""
    n = a.shape[0]
    for k in range(n):
        p = k
        big = abs(a[k, k])
        for i in range(k + 1, n):
            v = abs(a[i, k])
            if v > big:
                big = v
                p = i
        piv[k] = p
        if big == 0.0:
            return False
        if p != k:
            for j in range(n):
                t = a[k, j]
                a[k, j] = a[p, j]
                a[p, j] = t
        inv = 1.0 / a[k, k]
        for i in range(k + 1, n):
            a[i, k] *= inv
            x = a[i, k]
            for j in range(k + 1, n):
                a[i, j] -= x * a[k, j]
    return True


@njit(cache=True, fastmath=_FM)
def _lu_solve(lu, piv, b):
    """b <- A^-1 b in place for the factorization (lu, piv) of :func:`_lu` (LAPACK getrs)."""
    n = lu.shape[0]
    m = b.shape[1]
    for k in range(n):
        p = piv[k]
        if p != k:
            for j in range(m):
                t = b[k, j]
                b[k, j] = b[p, j]
                b[p, j] = t
    if m == 12:
        _subst12(lu, b)
        return
    if m == 6:
        _subst6(lu, b)
        return
    for i in range(1, n):  # unit lower triangle
        for k in range(i):
            x = lu[i, k]
            for j in range(m):
                b[i, j] -= x * b[k, j]
    for i in range(n - 1, -1, -1):  # upper triangle
        for k in range(i + 1, n):
            x = lu[i, k]
            for j in range(m):
                b[i, j] -= x * b[k, j]
        x = 1.0 / lu[i, i]
        for j in range(m):
            b[i, j] *= x


@njit(cache=True, fastmath=_FM)
def _cholesky(a, shift, L):
    """L L' = a + shift I from a's lower triangle (LAPACK potrf's algorithm); False on a pivot <= 0 or NaN."""
    n = a.shape[0]
    for j in range(n):
        d = a[j, j] + shift
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return False
        d = np.sqrt(d)
        L[j, j] = d
        inv = 1.0 / d
        for i in range(j + 1, n):
            v = a[i, j]
            for k in range(j):
                v -= L[i, k] * L[j, k]
            L[i, j] = v * inv
        for i in range(j):
            L[i, j] = 0.0
    return True


@njit(cache=True)
def _scale_sym(a, t):
    """t = 2^-e a, symmetric from a's lower triangle, with max |t_ij| in [0.5, 1) (exact; t may be a).
    Returns 2^-e; 0 if a = 0, NaN if a is not finite."""
    n = a.shape[0]
    big = 0.0
    for i in range(n):
        for j in range(i + 1):
            x = a[i, j]
            if not np.isfinite(x):
                return np.nan
            big = max(big, abs(x))
    if big == 0.0:
        return 0.0
    sc = math.ldexp(1.0, -math.frexp(big)[1])
    for i in range(n):
        for j in range(i + 1):
            x = a[i, j] * sc
            t[i, j] = x
            t[j, i] = x
    return sc


@njit(cache=True)
def _eigmax_jacobi(a):
    """Largest eigenvalue of the symmetric a (lower triangle read, a overwritten) by cyclic Jacobi on a
    scaled to max |a_ij| ~ 1 (:func:`_scale_sym`); NaN if a is not finite. Stops when the off-diagonal
    part is below 1e-16 of the diagonal (Frobenius). The fallback of :func:`_eigmax_sym`."""
    n = a.shape[0]
    sc = _scale_sym(a, a)
    if not sc > 0.0:  # NaN (not finite) or 0 (a = 0)
        return np.nan if np.isnan(sc) else 0.0
    for _ in range(_JACOBI_SWEEPS):
        off = 0.0
        dia = 0.0
        for i in range(n):
            dia += a[i, i] * a[i, i]
            for j in range(i):
                off += a[i, j] * a[i, j]
        if not off > 1e-32 * dia:  # converged (the eigenvalues move by <= ||off||_F), or NaN
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = a[p, q]
                if apq == 0.0:
                    continue
                theta = (a[q, q] - a[p, p]) / (2.0 * apq)
                if abs(theta) > 1e150:
                    t = 0.5 / theta
                else:
                    t = 1.0 / (abs(theta) + np.sqrt(theta * theta + 1.0))
                    if theta < 0.0:
                        t = -t
                c = 1.0 / np.sqrt(t * t + 1.0)
                s = t * c
                tau = s / (1.0 + c)
                a[p, p] -= t * apq
                a[q, q] += t * apq
                a[p, q] = 0.0
                a[q, p] = 0.0
                for r in range(n):
                    if r != p and r != q:
                        arp = a[r, p]
                        arq = a[r, q]
                        a[r, p] = arp - s * (arq + tau * arp)
                        a[r, q] = arq + s * (arp - tau * arq)
                        a[p, r] = a[r, p]
                        a[q, r] = a[r, q]
    top = a[0, 0]
    for i in range(1, n):
        top = max(top, a[i, i])
    return top / sc


@njit(cache=True)
def _count_above(d, e, l0, x):
    """Number of eigenvalues above x of the symmetric tridiagonal (d[l0:], e[l0:-1]) (Sturm: positive
    pivots of the LDL' factorization of T - x I; a zero pivot replaced by a tiny one)."""
    n = d.shape[0]
    q = d[l0] - x
    above = 1 if q > 0.0 else 0
    for i in range(l0 + 1, n):
        if q == 0.0:
            q = 1e-300
        q = d[i] - x - e[i - 1] * e[i - 1] / q
        if q > 0.0:
            above += 1
    return above


@njit(cache=True, fastmath=_FM)
def _eigmax_sym(a, t, wv):
    """Largest eigenvalue of the symmetric a (lower triangle read; a kept) by Householder tridiagonalization and
    implicit QL (EISPACK tql1: backward stable, error ~ n eps ||a||); NaN if a is not finite.

    a is first scaled by a power of two to max |a_ij| in [0.5, 1) (exact, into t), so ||a||_2 >= 1/2, the
    rotations cannot overflow, and an off-diagonal below _DEFLATE = 1e-16 deflates: that moves the
    eigenvalues by <= 2e-16 ||a||_2, the size of the rounding errors, and spares the iterations that
    would resolve the small eigenvalues (L' Ga L has rank ~3) to full relative accuracy. The first
    eigenvalue is sought with the shift above the spectrum (Gershgorin) for _QL_TOP_SHIFTS steps, so that
    it tends to be the top one; a Sturm count of the rest then ends the iteration if nothing lies above
    it (5.3 instead of 11.3 QL steps on the junctions of the shipped sigma = 120 gain). t: (n, n) work,
    wv: (>= 4, n) work. Cyclic Jacobi on a if QL has not converged in 30 steps per eigenvalue."""
    n = a.shape[0]
    sc = _scale_sym(a, t)
    if not sc > 0.0:  # NaN (not finite) or 0 (a = 0)
        return np.nan if np.isnan(sc) else 0.0
    d, e, v, p = wv[0], wv[1], wv[2], wv[3]
    for k in range(n - 2):  # Householder: t <- H t H, zeroing column k below the subdiagonal
        s2 = 0.0
        for i in range(k + 2, n):
            s2 += t[i, k] * t[i, k]
        x0 = t[k + 1, k]
        d[k] = t[k, k]
        if s2 == 0.0:
            e[k] = x0
            continue
        s2 += x0 * x0
        alpha = np.sqrt(s2)
        if x0 > 0.0:
            alpha = -alpha
        e[k] = alpha
        v[k + 1] = x0 - alpha
        for i in range(k + 2, n):
            v[i] = t[i, k]
        beta = 1.0 / (s2 - alpha * x0)  # 2 / v'v
        vp = 0.0
        for i in range(k + 1, n):
            y = 0.0
            for j in range(k + 1, n):
                y += t[i, j] * v[j]
            p[i] = beta * y
            vp += v[i] * p[i]
        kk = 0.5 * beta * vp
        for i in range(k + 1, n):
            p[i] -= kk * v[i]
        for i in range(k + 1, n):
            for j in range(k + 1, i + 1):
                y = t[i, j] - v[i] * p[j] - p[i] * v[j]
                t[i, j] = y
                t[j, i] = y
    if n >= 2:
        d[n - 2] = t[n - 2, n - 2]
        e[n - 2] = t[n - 1, n - 2]
    d[n - 1] = t[n - 1, n - 1]
    e[n - 1] = 0.0
    ub = d[0] + abs(e[0])  # Gershgorin: no eigenvalue above ub
    for i in range(1, n):
        ub = max(ub, d[i] + abs(e[i - 1]) + abs(e[i]))
    for l in range(n):  # implicit QL (tqli), eigenvalues only
        if l == 1 and _count_above(d, e, 1, d[0] + 4.0 * _DEFLATE) == 0:
            return d[0] / sc  # the first eigenvalue found is the top one, to round-off
        it = 0
        while True:
            m = l
            while m < n - 1:
                if abs(e[m]) <= _DEFLATE:
                    break
                m += 1
            if m == l:
                break
            it += 1
            if it > 30:
                return _eigmax_jacobi(a)
            if l == 0 and it <= _QL_TOP_SHIFTS:  # shift above the spectrum: d[0] tends to the top eigenvalue
                g = d[m] - ub
            else:  # the tqli (Wilkinson-type) shift from the leading 2x2 block
                g = (d[l + 1] - d[l]) / (2.0 * e[l])
                r = np.sqrt(g * g + 1.0)
                g = d[m] - d[l] + e[l] / (g + (r if g >= 0.0 else -r))
            s = 1.0
            c = 1.0
            q = 0.0
            i = m - 1
            under = False
            while i >= l:
                f = s * e[i]
                b = c * e[i]
                r = np.sqrt(f * f + g * g)
                e[i + 1] = r
                if r == 0.0:  # underflow: deflate and restart
                    d[i + 1] -= q
                    e[m] = 0.0
                    under = True
                    break
                ri = 1.0 / r
                s = f * ri
                c = g * ri
                g = d[i + 1] - q
                r = (d[i] - g) * s + 2.0 * c * b
                q = s * r
                d[i + 1] = g + q
                g = c * r - b
                i -= 1
            if under:
                continue
            d[l] -= q
            e[l] = g
            e[m] = 0.0
    top = d[0]
    for i in range(1, n):
        top = max(top, d[i])
    return top / sc
