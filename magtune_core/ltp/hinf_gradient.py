"""Exact gradient of the LTP H-infinity norm (paper eq. 21) with respect to A(t), B(t), C(t).

At gamma = ||G||_inf two characteristic multipliers of the Hamiltonian flow of
:func:`.hinf.hamiltonian` collide on the unit circle at exp(j omega* T) (omega* the worst-case
frequency, modulo 2 pi / T): below the norm they sit on the circle, above it they leave it as a
pair (lambda, 1 / conj(lambda)). On the pair's invariant subspace the monodromy restricts to a
2x2 matrix Mr with Delta = tr(Mr)^2 - 4 det(Mr) = (lambda_1 - lambda_2)^2, which changes sign
(after removing the phase exp(2 j omega* T)) exactly at the norm, linearly in gamma. So the norm
is the zero of Delta(gamma, p) and, by the implicit function theorem,

    dJ/dp = -Re(dDelta/dp conj(dDelta/dgamma)) / |dDelta/dgamma|^2.

Why Delta and not one multiplier: near the collision each multiplier's derivative blows up like
(gamma - J)^-1/2 and the ratio of two of them is wrong by ~1e-2 at gamma = J (1 + 1e-8) on the
shipped gains (measured); Delta is smooth through the collision, so the gradient evaluated at a
level gamma slightly above the norm is off only by O(gamma - J).

How, without the monodromy (whose entries overflow for stiff loops, see :func:`.hinf.interval_scattering`):

* every Magnus interval is cut into m equal sub-steps with ||Omega / m||_1 <= ``theta`` (the same
  product, exactly), each in scattering form; prefix and suffix star products over the period give
  the period's scattering blocks, whose pencil [[E, 0], [-Hs, I]] z = lambda [[I, -G], [0, F]] z
  has the monodromy's multipliers (z = [x0; p0]), and the two-point formula gives the state of any
  solution at every sub-step boundary from (x0, p at T) with bounded arithmetic only;
* the left invariant subspace is J X (X the right one; J the symplectic unit): the flow is
  symplectic, so no adjoint sweep is needed;
* d exp(Omega) is taken through the adjoint Frechet derivative, d(y^H exp(Omega) x) =
  <L(Omega^T, conj(y) x^T), dOmega> (one 4n x 4n exponential per interval), then through the
  4th-order Magnus exponent (:func:`.system.magnus_exponent`) to the generator at its two Gauss
  nodes, and through the Hamiltonian's blocks to A, B, C.

The result is the exact derivative of the *discretized* norm (the one :func:`.hinf.hinfnorm`
computes on ``steps`` intervals), checked against central differences and, for an LTI system,
against the singular-vector formula at the peak frequency (tests/ltp/test_hinf_gradient.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from .expm import expm
from .hinf import hinfnorm, interval_scattering, star
from .system import DEFAULT_STEPS, LTPSystem, generator_at_nodes, interval_grid, magnus_exponent

#: Largest ||Omega / m||_1 of a sub-step (the flow grows by at most ~e^theta across one).
THETA = 16.0
_C2 = np.sqrt(3.0) / 12.0


@dataclass(frozen=True)
class HinfGradient:
    """dJ/d(system matrices) at the Magnus nodes, J = ||G||_inf on ``steps`` intervals.

    ``dA`` (steps, 2, n, n), ``dB`` (steps, 2, n, m), ``dC`` (steps, 2, p, n): the derivative of J
    with respect to the matrix values at the two Gauss nodes ``t`` (steps, 2) of every interval;
    for a constant matrix, the gradient is the sum over all nodes. The gradient is taken at the
    level ``J`` (hinfnorm's value, within its rtol of the norm); ``J_newton``: one Newton step on
    Delta from it (a sharper estimate of the norm); ``multipliers``: the colliding pair, whose angle is
    omega* T modulo 2 pi.
    """

    J: float
    J_newton: float
    dA: np.ndarray
    dB: np.ndarray
    dC: np.ndarray
    t: np.ndarray
    multipliers: np.ndarray


def _T(X):
    return np.swapaxes(X, -1, -2)


def _identity(n: int, batch: tuple):
    eye = np.broadcast_to(np.eye(n), batch + (n, n)).copy()
    return eye, np.zeros(batch + (n, n)), np.zeros(batch + (n, n)), eye.copy()


def _exclusive_scan(blocks, reverse: bool = False):
    """Star products S_0 * ... * S_{k-1} (k = 0..N; identity first), or S_k * ... * S_{N-1} with
    ``reverse`` (identity last): Hillis-Steele doubling, log2(N) batched star products."""
    n, N = blocks[0].shape[-1], blocks[0].shape[0]
    acc = tuple(b.copy() for b in blocks)
    d = 1
    while d < N:
        joined, _, _ = star(tuple(x[:-d] for x in acc), tuple(x[d:] for x in acc))
        if reverse:
            acc = tuple(np.concatenate([y, x[-d:]]) for x, y in zip(acc, joined))
        else:
            acc = tuple(np.concatenate([x[:d], y]) for x, y in zip(acc, joined))
        d *= 2
    eye = _identity(n, (1,))
    if reverse:
        return tuple(np.concatenate([x, e]) for x, e in zip(acc, eye))
    return tuple(np.concatenate([e, x]) for x, e in zip(acc, eye))


def _two_point(a, b, x0, p_end):
    """State [x; p] at the junction of segment a (starting at x0) and segment b (ending at p_end)."""
    Ea, Ga, _, _ = a
    _, _, Hb, Fb = b
    Fp = np.einsum("...ij,...j->...i", Fb, p_end)
    rhs = np.einsum("...ij,...j->...i", Ea, x0) + np.einsum("...ij,...j->...i", Ga, Fp)
    x = np.linalg.solve(np.eye(Ea.shape[-1]) - Ga @ Hb, rhs[..., None])[..., 0]
    return np.concatenate([x, np.einsum("...ij,...j->...i", Hb, x) + Fp], axis=-1)


def _frechet_adjoint(Om, W):
    """L(Om^T, W): <W, L(Om, E)> = <L(Om^T, W), E> for the bilinear pairing (real and imaginary parts apart)."""
    n = Om.shape[-1]

    def one(Wr):
        big = np.zeros(Om.shape[:-2] + (2 * n, 2 * n))
        big[..., :n, :n] = big[..., n:, n:] = _T(Om)
        big[..., :n, n:] = Wr
        return expm(big)[..., :n, n:]

    out = one(W.real)
    return out + 1j * one(W.imag) if np.any(W.imag) else out


def _colliding_pair(lam: np.ndarray) -> np.ndarray:
    """Indices of the two multipliers that collide: among the four nearest the unit circle, the
    two nearest each other (a complex collision has its conjugate pair equally near the circle;
    a collision on the real axis is itself a conjugate pair)."""
    with np.errstate(all="ignore"):
        dist = np.abs(np.log(np.abs(lam)))
    dist = np.where(np.isfinite(dist), dist, np.inf)
    near = np.argsort(dist)[:4]
    pairs = [(i, j) for a, i in enumerate(near) for j in near[a + 1:]]
    return np.array(min(pairs, key=lambda ij: abs(lam[ij[0]] - lam[ij[1]]) + dist[ij[0]] + dist[ij[1]]))


def _flow(sys: LTPSystem, gamma: float, steps: int, theta: float) -> dict:
    """The Hamiltonian flow at level gamma in scattering form: node matrices, Magnus exponents,
    sub-step powers, prefix / suffix segments and the period's pencil (see the module docstring)."""
    A1, A2, h = generator_at_nodes(lambda t: sys.sample("A", t), sys.period, steps)
    B1, B2, _ = generator_at_nodes(lambda t: sys.sample("B", t), sys.period, steps)
    C1, C2, _ = generator_at_nodes(lambda t: sys.sample("C", t), sys.period, steps)
    if A1.ndim != 3 or B1.ndim != 3 or C1.ndim != 3:
        raise ValueError("hinfnorm_gradient: one system at a time (no batch axes)")
    An, Bn, Cn = np.stack([A1, A2], 1), np.stack([B1, B2], 1), np.stack([C1, C2], 1)  # (steps, 2, ., .)
    n = An.shape[-1]
    BB, CC = Bn @ _T(Bn), _T(Cn) @ Cn
    alpha = gamma * np.sqrt(np.abs(CC).max() / np.abs(BB).max())  # the balancing of hinf.hamiltonian
    H = np.zeros(An.shape[:2] + (2 * n, 2 * n))
    H[..., :n, :n], H[..., :n, n:] = An, alpha * BB / gamma**2
    H[..., n:, :n], H[..., n:, n:] = -CC / alpha, -_T(An)
    M1, M2 = H[:, 0], H[:, 1]
    Om = magnus_exponent(M1, M2, h)
    m = int(2 ** max(0, int(np.ceil(np.log2(np.abs(Om).sum(axis=-2).max() / theta)))))
    Osub = Om / m
    with np.errstate(all="ignore"):
        sub, ok, _ = interval_scattering(Osub)
        powers = [_identity(n, (steps,))]  # sub^j, j = 0..m: the segments inside every interval
        for _ in range(m):
            powers.append(star(powers[-1], sub)[0])
        pre, suf = _exclusive_scan(powers[m]), _exclusive_scan(powers[m], reverse=True)
    E, G, Hs, F = (x[-1] for x in pre)
    if not (ok.all() and all(np.all(np.isfinite(x)) for x in (E, G, Hs, F))):
        raise ArithmeticError("hinfnorm_gradient: the scattering blocks are not finite at this level")
    eye, zero = np.eye(n), np.zeros((n, n))
    P_a = np.block([[E, zero], [-Hs, eye]])
    P_b = np.block([[eye, -G], [zero, F]])
    _, _, nodes = interval_grid(sys.period, steps)
    return dict(n=n, m=m, h=h, gamma=gamma, alpha=alpha, Bn=Bn, Cn=Cn, BB=BB, M1=M1, M2=M2, Osub=Osub,
                powers=powers, pre=pre, suf=suf, P_a=P_a, P_b=P_b, lam=sla.eigvals(P_a, P_b), t=nodes)


def _pair_level(f: dict, pair: np.ndarray):
    """Collision level of the multiplier pair ``pair`` (one Newton step on Delta from f's gamma) and
    its gradient with respect to A, B, C at the nodes: (level, dA, dB, dC)."""
    n, m, h, gamma, alpha = f["n"], f["m"], f["h"], f["gamma"], f["alpha"]
    powers, pre, suf, M1, M2 = f["powers"], f["pre"], f["suf"], f["M1"], f["M2"]
    steps = M1.shape[0]
    def select(a, b):  # the two of the QZ's own eigenvalues nearest the pair (a near-double pair moves by ~sqrt(eps))
        with np.errstate(all="ignore"):
            lam = np.atleast_1d(a / b)
        d = np.minimum(np.abs(lam - pair[0]), np.abs(lam - pair[1]))
        out = np.zeros(lam.shape, dtype=bool)
        out[np.argsort(np.where(np.isfinite(d), d, np.inf))[:2]] = True
        return out

    S, Tm, _, _, _, Z = sla.ordqz(f["P_a"].astype(complex), f["P_b"].astype(complex), sort=select, output="complex")
    X = Z[:, :2]  # right invariant subspace of the pair: Psi X = X Mr
    Mr = np.linalg.solve(Tm[:2, :2], S[:2, :2])
    X_end = X @ Mr
    R = []  # the two basis solutions at every sub-step boundary, (steps, m + 1, 2n) each
    for j in range(2):
        bounds = _two_point(pre, suf, np.broadcast_to(X[:n, j], (steps + 1, n)),
                            np.broadcast_to(X_end[n:, j], (steps + 1, n)))
        x_start, p_end = bounds[:-1, :n], bounds[1:, n:]
        R.append(np.stack([_two_point(powers[i], powers[m - i], x_start, p_end) for i in range(m + 1)], axis=1))
    R = np.stack(R, axis=-1)  # (steps, m + 1, 2n, 2)
    eye, zero = np.eye(n), np.zeros((n, n))
    Jsym = np.block([[zero, eye], [-eye, zero]])
    Minv = np.linalg.inv(Mr)
    # left solutions: Y^H (flow after the sub-step) = (J R_next Mr^-1)^H, with Y = J X (symplectic flow)
    Lft = np.einsum("ab,kjbc,cd->kjad", Jsym, R[:, 1:], Minv)
    N0inv = np.linalg.inv((Jsym @ X).conj().T @ X)
    # dDelta = 2 tr(Mr) tr(D) - 4 det(Mr) tr(Mr^-1 D), D = N0^-1 (Y_i^H dPsi X_j): weights of the (i, j) pairings
    w = (2 * np.trace(Mr) * N0inv - 4 * np.linalg.det(Mr) * (Minv @ N0inv)).T
    W = np.einsum("ij,ksai,ksbj->kab", w, Lft.conj(), R[:, :-1])  # sum over sub-steps and pairings
    P = _frechet_adjoint(f["Osub"], W) / m  # dDelta / dOmega_k
    g1 = 0.5 * h * P - _C2 * h * h * (P @ _T(M2) - _T(M2) @ P)
    g2 = 0.5 * h * P - _C2 * h * h * (_T(M1) @ P - P @ _T(M1))
    gH = np.stack([g1, g2], axis=1)  # dDelta / dH at the nodes, (steps, 2, 2n, 2n)
    d_gamma = np.sum(gH[..., :n, n:] * (-2.0 * alpha * f["BB"] / gamma**3))
    Rg = -(gH * np.conj(d_gamma)).real / abs(d_gamma) ** 2  # d level / dH: implicit function theorem
    Bn, Cn = f["Bn"], f["Cn"]
    dA = Rg[..., :n, :n] - _T(Rg[..., n:, n:])
    dB = (alpha / gamma**2) * (Rg[..., :n, n:] + _T(Rg[..., :n, n:])) @ Bn
    dC = -(1.0 / alpha) * Cn @ (Rg[..., n:, :n] + _T(Rg[..., n:, :n]))
    Delta = np.trace(Mr) ** 2 - 4 * np.linalg.det(Mr)
    level = gamma - float((Delta * np.conj(d_gamma)).real / abs(d_gamma) ** 2)
    return level, dA, dB, dC


def hinfnorm_gradient(sys: LTPSystem, steps: int = DEFAULT_STEPS, rtol: float = 1e-10,
                      theta: float = THETA) -> HinfGradient:
    """Gradient of ||G||_inf (paper eq. 21) with respect to A(t), B(t), C(t) at the Magnus nodes.

    One stable system without feedthrough (no batch axes). J is computed by :func:`.hinf.hinfnorm`
    to ``rtol`` (the gradient's relative error is ~ (gamma - J) / J times the curvature: ~4e-5 at
    rtol 1e-8 on the shipped gains, measured; keep rtol <= 1e-9).

    Parameters
    ----------
    sys : LTPSystem
        One stable system without feedthrough (no batch axes).
    steps : int
        Magnus intervals per period (the gradient is that of the norm discretized on them).
    rtol : float
        Relative tolerance of :func:`.hinf.hinfnorm` for J, the level at which the gradient is taken.
    theta : float
        Largest ||Omega / m||_1 of a sub-step (each Magnus interval is cut into m equal sub-steps).

    Returns
    -------
    HinfGradient
        J, the node gradients dA, dB, dC and the colliding multiplier pair.

    Raises
    ------
    ValueError
        If ``sys`` has a feedthrough D (:attr:`.LTPSystem.has_feedthrough`) or is unstable (J = inf).
    ArithmeticError
        If the scattering blocks of the Hamiltonian flow at level J are not finite.
    """
    if sys.has_feedthrough:
        raise ValueError("hinfnorm_gradient: systems with feedthrough D are not supported")
    J = float(hinfnorm(sys, rtol=rtol, steps=steps))
    if not np.isfinite(J):
        raise ValueError("hinfnorm_gradient: the system is unstable (J = inf)")
    f = _flow(sys, J, steps, theta)
    pair = f["lam"][_colliding_pair(f["lam"])]
    level, dA, dB, dC = _pair_level(f, pair)
    return HinfGradient(J, level, dA, dB, dC, f["t"], pair)
