"""The small dense linear algebra of the compiled gamma-test (ltp/small_linalg.py) against numpy / scipy.

Seeded random matrices (numpy's default_rng), the sizes the kernel uses (6 and 12: the register-row
paths) and others (the generic loops). Tolerances, where not stated at the test:

* products and triangular solves are the textbook sums in another order than BLAS/LAPACK's, so they
  agree to a few ulps of the largest partial sums: 1e-14 relative to sum_k |a_ik| |b_kj| (n <= 12
  terms of ~1e-16 each, with margin);
* LU and Cholesky factors are the same algorithm as getrf / potrf (unblocked: no difference at
  n <= 12 but the summation order), so factors agree to ~cond * eps, checked at 1e-12 on
  well-conditioned matrices, and the pivot sequence is identical (no near-ties in random data);
* eigenvalues: both methods backward stable (error <= c n eps ||A||_2, ~1e-14 at n <= 12), checked at
  1e-10 of max |lambda| (any real defect, a wrong rotation or a missed deflation, errs by far more).
"""
import numpy as np
import pytest
import scipy.linalg

from magtune_core.ltp import small_linalg as SL


def _ill_conditioned(rng, n, cond):
    """A random n x n matrix with singular values spread log-uniformly over [1 / cond, 1]."""
    U, _ = np.linalg.qr(rng.standard_normal((n, n)))
    V, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return (U * np.logspace(0, -np.log10(cond), n)) @ V.T


@pytest.mark.parametrize("n, m", [(6, 6), (6, 12), (12, 12), (5, 7), (1, 3)])
def test_matmul_equals_numpy(n, m):
    """The register-row products (6 and 12 columns) and the generic loop against numpy's @."""
    rng = np.random.default_rng(n * 100 + m)
    a, b = rng.standard_normal((n, n)), rng.standard_normal((n, m))
    out = np.empty((n, m))
    SL._matmul(a, b, out)
    assert np.allclose(out, a @ b, rtol=1e-14, atol=1e-14 * np.abs(a).sum(axis=1).max() * np.abs(b).max())


@pytest.mark.parametrize("n, m", [(6, 6), (6, 12), (12, 12), (5, 7)])
def test_lu_solve_equals_lapack(n, m):
    """LU with partial pivoting (several right-hand sides) against np.linalg.solve, well and badly
    conditioned; a pivot needing a row swap; an exactly singular matrix is reported (LAPACK: info > 0)."""
    rng = np.random.default_rng(7 * n + m)
    for cond in (None, 1e6, 1e11):
        a = rng.standard_normal((n, n)) if cond is None else _ill_conditioned(rng, n, cond)
        if cond is None:
            a[0, 0] = 0.0  # the first pivot must come from another row
        b = rng.standard_normal((n, m))
        lu, piv, x = a.copy(), np.empty(n, dtype=np.int64), b.copy()
        assert SL._lu(lu, piv)
        SL._lu_solve(lu, piv, x)
        ref = np.linalg.solve(a, b)
        # backward stable solves agree to ~cond * eps relative (both to the exact solution)
        tol = 1e-13 * (1.0 if cond is None else cond) * np.linalg.cond(a) / (1.0 if cond is None else cond)
        assert np.abs(x - ref).max() <= max(tol, 1e-13) * np.abs(ref).max()
        assert np.abs(a @ x - b).max() <= 1e-13 * np.abs(a).max() * np.abs(x).max() * n  # small residual
    sing = rng.standard_normal((n, n))
    sing[:, n // 2] = 0.0
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.solve(sing, np.eye(n))
    assert not SL._lu(sing.copy(), np.empty(n, dtype=np.int64))


def test_largest_symmetric_eigenvalue_equals_lapack():
    """Tridiagonalization + implicit QL (and the cyclic Jacobi fallback) against np.linalg.eigvalsh:
    random PSD and indefinite, ill-conditioned, a repeated top eigenvalue, diagonal, tiny and huge scales.

    Tolerance 1e-10 relative to max |lambda|: both methods are backward stable (error <= c n eps ||A||_2,
    ~1e-14 at n <= 12), so agreement is ~1e-14; 1e-10 keeps that margin while any real defect (a wrong
    rotation, a missed deflation) errs by orders of magnitude more. kappa feeds a margin extrapolation
    and the test kappa < 1, where 1e-10 is far below the margins hinfnorm reads."""
    rng = np.random.default_rng(17)
    cases = []
    for n in (1, 2, 3, 6, 12):
        for _ in range(40):
            x = rng.standard_normal((n, n))
            cases += [x @ x.T, x + x.T]
        Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
        cases.append((Q * np.logspace(0, -14, n)) @ Q.T)  # PSD, condition 1e14
        cases.append((Q * np.where(np.arange(n) < 3, 1.0, 0.25)) @ Q.T)  # top eigenvalue repeated (3x)
        cases.append((Q * np.where(np.arange(n) == 0, 1.0, 1.0 - 1e-13)) @ Q.T)  # a cluster
        cases.append(np.diag(rng.standard_normal(n)))
        cases.append(np.zeros((n, n)))
        x = rng.standard_normal((n, n))
        cases += [1e-200 * (x @ x.T), 1e200 * (x @ x.T)]
    for a in cases:
        a = 0.5 * (a + a.T)
        n = a.shape[0]
        lam = np.linalg.eigvalsh(a)
        scale = max(np.abs(lam).max(), 1e-300)
        got = SL._eigmax_sym(a.copy(), np.empty((n, n)), np.empty((4, n)))
        assert abs(got - lam[-1]) <= 1e-10 * scale, (n, got, lam[-1])
        got_j = SL._eigmax_jacobi(a.copy())
        assert abs(got_j - lam[-1]) <= 1e-10 * scale, (n, got_j, lam[-1])
    bad = np.eye(6)
    bad[2, 3] = bad[3, 2] = np.inf
    assert np.isnan(SL._eigmax_sym(bad, np.empty((6, 6)), np.empty((4, 6))))


def test_sturm_count_equals_eigvalsh():
    """The Sturm count that ends _eigmax_sym's QL: eigenvalues above x of a tridiagonal block, against
    np.linalg.eigvalsh (x away from the eigenvalues by 1e-9, far above round-off)."""
    rng = np.random.default_rng(31)
    for _ in range(200):
        n = int(rng.integers(1, 8))
        d, e = rng.standard_normal(n), np.append(rng.standard_normal(n - 1), 0.0)
        l0 = int(rng.integers(0, n))
        T = np.diag(d[l0:]) + np.diag(e[l0:n - 1], 1) + np.diag(e[l0:n - 1], -1)
        lam = np.linalg.eigvalsh(T)
        for x in np.concatenate([rng.uniform(lam[0] - 1, lam[-1] + 1, 5), lam + 1e-9, lam - 1e-9]):
            assert SL._count_above(d, e, l0, x) == int(np.sum(lam > x))




def test_elementwise_helpers_equal_numpy():
    """norm1, finite, copy, trace and the symmetric part against their numpy one-liners (exact: the same
    sums of the same terms up to order, compared with a 1e-15 relative bound where summed)."""
    rng = np.random.default_rng(41)
    for n, m in ((6, 6), (12, 12), (5, 3)):
        a = rng.standard_normal((n, m))
        assert SL._norm1(a) == pytest.approx(np.linalg.norm(a, 1), rel=1e-15)
        assert SL._finite(a)
        dst = np.empty_like(a)
        SL._copy(a, dst)
        assert np.array_equal(dst, a)
        b = a.copy()
        b[n - 1, m - 1] = np.inf
        assert not SL._finite(b)
        assert SL._norm1(b) == np.inf
        b[n - 1, m - 1] = np.nan  # a NaN column is skipped by the max (the kernel tests _finite as well)
        assert not SL._finite(b) and SL._norm1(b) == pytest.approx(np.abs(a[:, :m - 1]).sum(axis=0).max(), rel=1e-15)
    for n in (1, 6, 12):
        a = rng.standard_normal((n, n))
        assert SL._trace(a) == pytest.approx(np.trace(a), rel=1e-15, abs=1e-15 * np.abs(np.diag(a)).sum())
        out = np.empty((n, n))
        SL._sym_into(a, out)
        assert np.array_equal(out, 0.5 * (a + a.T))  # one addition and one exact halving per entry


def test_register_row_products_equal_the_generic_loop():
    """_mm6 / _mm12 (rows in scalars) compute the same sums as the generic loop of _matmul, in the same
    order k = 0, 1, ...: equal to 1 ulp (the compiler may fuse a multiply-add in either, fastmath
    'contract'), so 4e-16 relative to sum |a_ik| |b_kj| is the bound."""
    rng = np.random.default_rng(43)
    for m, f in ((6, SL._mm6), (12, SL._mm12)):
        a, b = rng.standard_normal((9, 7)), rng.standard_normal((7, m))
        out = np.empty((9, m))
        f(a, b, out)
        bound = np.abs(a) @ np.abs(b)
        assert np.all(np.abs(out - a @ b) <= 4e-16 * 7 * bound)


@pytest.mark.parametrize("n", [1, 2, 6, 12])
def test_lu_factors_equal_scipy_lu_factor(n):
    """The packed LU factors and the pivot rows against scipy.linalg.lu_factor (LAPACK getrf)."""
    rng = np.random.default_rng(47 + n)
    a = rng.standard_normal((n, n))
    lu, piv = a.copy(), np.empty(n, dtype=np.int64)
    assert SL._lu(lu, piv)
    lu_ref, piv_ref = scipy.linalg.lu_factor(a)
    assert piv.tolist() == piv_ref.tolist()  # same pivot rows (0-based in both)
    assert np.allclose(lu, lu_ref, rtol=1e-12, atol=1e-12 * np.abs(a).max())


@pytest.mark.parametrize("m", [1, 3, 6, 12])
def test_lu_solve_generic_and_register_paths(m):
    """_lu_solve with 1 and 3 right-hand sides (the generic loops) and 6, 12 (register rows) against
    scipy.linalg.lu_solve on the same factors: both are forward then back substitution, so the
    solutions of a well-conditioned 12x12 agree to ~cond * eps; 1e-12 relative."""
    rng = np.random.default_rng(53 + m)
    a, b = rng.standard_normal((12, 12)) + 4.0 * np.eye(12), rng.standard_normal((12, m))
    lu, piv, x = a.copy(), np.empty(12, dtype=np.int64), b.copy()
    assert SL._lu(lu, piv)
    SL._lu_solve(lu, piv, x)
    ref = scipy.linalg.lu_solve(scipy.linalg.lu_factor(a), b)
    assert np.abs(x - ref).max() <= 1e-12 * np.abs(ref).max()


def test_cholesky_with_shift_equals_scipy():
    """L L' = a + shift I from the lower triangle only (the upper one is never read) against
    scipy.linalg.cholesky(lower=True); the strict upper triangle of L is zeroed. 1e-12 relative to
    sqrt(max |a|) (potrf's algorithm, different summation order, condition <= 1e4 here)."""
    rng = np.random.default_rng(59)
    for n in (1, 6, 12):
        x = rng.standard_normal((n, n))
        a = x @ x.T
        shift = 1e-2 * np.trace(a) / n
        ref = scipy.linalg.cholesky(a + shift * np.eye(n), lower=True)
        lower_only = np.tril(a) + np.triu(np.full((n, n), np.nan), 1)  # garbage above the diagonal
        L = np.full((n, n), 7.0)
        assert SL._cholesky(lower_only, shift, L)
        assert np.allclose(L, ref, rtol=1e-12, atol=1e-12 * np.sqrt(np.abs(a).max()))
        assert np.all(np.triu(L, 1) == 0.0)
        assert not SL._cholesky(-a - shift * np.eye(n), 0.0, L)  # negative definite: the first pivot fails


def test_scale_sym_is_an_exact_power_of_two():
    """_scale_sym: t = 2^-e a symmetrized from the lower triangle, max |t| in [0.5, 1), returns 2^-e
    (exact, so the eigenvalue /sc of _eigmax_sym loses nothing); 0 for a = 0, NaN if not finite."""
    rng = np.random.default_rng(61)
    for scale in (1e-200, 1e-3, 1.0, 7.0, 1e200):
        a = scale * rng.standard_normal((6, 6))
        t = np.empty((6, 6))
        sc = SL._scale_sym(a, t)
        low = np.tril(a)
        sym = low + np.tril(a, -1).T
        assert np.frexp(sc)[0] == 0.5  # a power of two
        assert np.array_equal(t, sym * sc)
        assert 0.5 <= np.abs(t).max() < 1.0
    assert SL._scale_sym(np.zeros((3, 3)), np.empty((3, 3))) == 0.0
    bad = np.eye(3)
    bad[2, 0] = np.nan
    assert np.isnan(SL._scale_sym(bad, np.empty((3, 3))))


def test_eigmax_sym_keeps_its_input_and_matches_scipy_eigh():
    """_eigmax_sym reads a's lower triangle and leaves a unchanged (the kernel reuses it); against
    scipy.linalg.eigh(eigvals_only) on seeded PSD products like the kernel's L' Ga L (rank ~3 of 6)."""
    rng = np.random.default_rng(67)
    for _ in range(50):
        y = rng.standard_normal((6, 3))
        a = y @ y.T * 10.0 ** rng.uniform(-3, 3)
        keep = a.copy()
        got = SL._eigmax_sym(a, np.empty((6, 6)), np.empty((4, 6)))
        assert np.array_equal(a, keep)
        ref = scipy.linalg.eigh(a, eigvals_only=True)[-1]
        assert abs(got - ref) <= 1e-10 * ref
