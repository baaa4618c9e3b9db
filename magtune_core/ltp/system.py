"""Linear time-periodic (LTP) systems: transition matrices, monodromy, characteristic multipliers.

General-purpose (any LTP system, not only the attitude model). Paper section 2: the
transition matrix phi_A(t, tau) (eq. 3), the monodromy matrix psi_A(tau) = phi_A(tau + T, tau)
(eq. 4) and Theorem 2.1 (exponential stability iff the characteristic multipliers, the
eigenvalues of the monodromy matrix, lie in the open unit disc).

Every matrix may be a constant array of shape (*batch, r, c) or a callable ``t -> array`` of
shape (*batch, len(t), r, c); batch axes (e.g. a population of candidate gains) broadcast, so
one call analyses many systems at once. One period is split into ``steps`` intervals, each
propagated exactly for a frozen Magnus exponent (4th-order Magnus, two Gauss-Legendre nodes):
the fast nutation dynamics (~76 s) live inside the matrix exponential, so the step only has
to resolve the slow orbital-rate variation of the field.

The norms live in their own modules: :mod:`magtune_core.ltp.hinf` (exact H-infinity),
:mod:`magtune_core.ltp.htf` (harmonic transfer function, paper eqs. 8-10) and
:mod:`magtune_core.ltp.h2` (periodic Gramian); :mod:`magtune_core.ltp` re-exports the API.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Union

import numpy as np

from .expm import expm

MatrixLike = Union[np.ndarray, Callable[[np.ndarray], np.ndarray]]

#: Gauss-Legendre nodes on [0, 1] of the 4th-order Magnus integrator.
GAUSS_NODES = np.array([0.5 - np.sqrt(3.0) / 6.0, 0.5 + np.sqrt(3.0) / 6.0])
DEFAULT_STEPS = 64


@dataclass(frozen=True)
class LTPSystem:
    """x' = A(t) x + B(t) u, y = C(t) x + D(t) u with T-periodic matrices (paper eq. 7).

    Parameters
    ----------
    A : ndarray (*batch, n, n) or callable
        State matrix, constant or ``t -> ndarray (*batch, len(t), n, n)``.
    B : ndarray (*batch, n, m) or callable
        Input matrix, constant or ``t -> ndarray (*batch, len(t), n, m)``.
    C : ndarray (*batch, p, n) or callable
        Output matrix, constant or ``t -> ndarray (*batch, len(t), p, n)``.
    D : ndarray (*batch, p, m) or callable, optional
        Feedthrough, constant or callable as above; None (default) means D = 0.
    period : float
        Period T of the matrices (time unit of the model: s for the attitude model).

    Raises
    ------
    ValueError
        If ``period`` is not a positive finite number.
    """

    A: MatrixLike
    B: MatrixLike
    C: MatrixLike
    D: MatrixLike | None = None
    period: float = 1.0

    def __post_init__(self):
        if not (np.isfinite(self.period) and self.period > 0):
            raise ValueError(f"LTPSystem: period must be a positive finite number, got {self.period!r}")

    def sample(self, name: str, t) -> np.ndarray:
        """Matrix ``name`` at times t: shape (*batch, len(t), r, c) (constants broadcast).

        Parameters
        ----------
        name : str
            Which matrix: "A", "B", "C" or "D".
        t : float or array_like (k,)
            Times (time unit of ``period``).

        Returns
        -------
        ndarray (*batch, k, r, c)
            A callable matrix evaluated at ``t``; a constant one as (*batch, 1, r, c), which broadcasts
            against the time axis; D = None as zeros (1, p, m).

        Raises
        ------
        ValueError
            If a callable matrix returns fewer than 3 axes or a time axis (-3) of length other than len(t).
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        M = getattr(self, name)
        if M is None:  # D defaults to zero
            p = self.sample("C", t[:1]).shape[-2]
            m = self.sample("B", t[:1]).shape[-1]
            return np.zeros((1, p, m))
        if callable(M):
            out = np.asarray(M(t), dtype=float)
            if out.ndim < 3 or out.shape[-3] != t.size:
                raise ValueError(f"LTPSystem.{name}(t) must return shape (*batch, len(t), r, c), got {out.shape}")
            return out
        M = np.asarray(M, dtype=float)
        return M[..., None, :, :]

    @property
    def has_feedthrough(self) -> bool:
        """True if D(t) is given and not identically zero (the gamma-test then needs gamma > sup ||D||).

        Returns
        -------
        bool
            True if D is a callable (assumed nonzero) or a constant with a nonzero entry.
        """
        return self.D is not None and (callable(self.D) or np.any(np.asarray(self.D)))


def interval_grid(period: float, steps: int):
    """Interval start times t_k = k h, the step h, and the 2 Gauss nodes of every interval (steps, 2).

    The grid of the 4th-order Magnus integrator (Gauss-Legendre nodes t_k + (1/2 -+ sqrt(3)/6) h).

    Parameters
    ----------
    period : float
        Period T (time unit of the system).
    steps : int
        Number of intervals per period.

    Returns
    -------
    t0 : ndarray (steps,)
        Interval start times k h.
    h : float
        Interval length T / steps.
    nodes : ndarray (steps, 2)
        The two Gauss-Legendre nodes of every interval.
    """
    h = period / steps
    t0 = np.arange(steps) * h
    return t0, h, t0[:, None] + h * GAUSS_NODES


def magnus_exponent(M1: np.ndarray, M2: np.ndarray, h: float) -> np.ndarray:
    """The 4th-order Magnus exponent (h/2)(M1 + M2) - (sqrt(3) h^2 / 12) [M1, M2] of each interval.

    Magnus expansion (Magnus 1954) truncated at 4th order with two Gauss nodes (Iserles & Norsett
    1999; Blanes, Casas, Oteo & Ros 2009): exp(Omega_k) approximates the transition
    matrix phi(t_k + h, t_k) of paper eq. (3) with local error O(h^5).

    Parameters
    ----------
    M1, M2 : ndarray (..., k, k)
        The generator at the two Gauss nodes of each interval.
    h : float
        Interval length.

    Returns
    -------
    ndarray (..., k, k)
        Omega_k per interval.
    """
    return 0.5 * h * (M1 + M2) - (np.sqrt(3.0) / 12.0) * h * h * (M1 @ M2 - M2 @ M1)


def magnus_exponentials(M1: np.ndarray, M2: np.ndarray, h: float) -> np.ndarray:
    """exp of the 4th-order Magnus exponent (:func:`magnus_exponent`) of each interval.

    Parameters
    ----------
    M1, M2 : ndarray (..., k, k)
        The generator at the two Gauss nodes of each interval.
    h : float
        Interval length.

    Returns
    -------
    ndarray (..., k, k)
        The interval transitions phi(t_k + h, t_k) of paper eq. (3) (Magnus 1954, 4th order).
    """
    return expm(magnus_exponent(M1, M2, h))


def generator_at_nodes(fun: Callable[[np.ndarray], np.ndarray], period: float, steps: int):
    """Sample ``fun`` at the Gauss nodes of :func:`interval_grid`: the input of :func:`magnus_exponent`.

    Parameters
    ----------
    fun : callable
        ``t -> ndarray (..., len(t), k, k)`` (or (..., 1, k, k) if time-invariant): the generator.
    period : float
        Period T (time unit of the system).
    steps : int
        Number of intervals per period.

    Returns
    -------
    (M1, M2) : tuple of ndarrays (..., steps, k, k)
        ``fun`` at the first and second Gauss node of every interval.
    h : float
        Interval length."""
    _, h, nodes = interval_grid(period, steps)
    vals = fun(nodes.ravel())  # (..., 2*steps, k, k), ordered (interval, node)
    if vals.shape[-3] == 1:  # time-invariant: broadcast over the nodes
        vals = np.broadcast_to(vals, vals.shape[:-3] + (nodes.size,) + vals.shape[-2:])
    vals = vals.reshape(vals.shape[:-3] + (steps, 2) + vals.shape[-2:])
    return vals[..., 0, :, :], vals[..., 1, :, :], h


def interval_transitions(sys: LTPSystem, steps: int = DEFAULT_STEPS) -> np.ndarray:
    """phi_A(t_{k+1}, t_k) for the ``steps`` intervals of one period: shape (*batch, steps, n, n).

    The transition matrix of paper eqs. (2)-(3), by the 4th-order Magnus expansion (Magnus 1954).

    Parameters
    ----------
    sys : LTPSystem
        The system, possibly batched (leading axes of its matrices).
    steps : int
        Magnus intervals per period.

    Returns
    -------
    ndarray (*batch, steps, n, n)
        phi_A(t_{k+1}, t_k), k = 0..steps-1 (4th-order Magnus, two Gauss nodes per interval).
    """
    M1, M2, h = generator_at_nodes(lambda t: sys.sample("A", t), sys.period, steps)
    return magnus_exponentials(M1, M2, h)


def chain_product(phis: np.ndarray) -> np.ndarray:
    """Ordered product phi_{N-1} ... phi_1 phi_0 over axis -3, by pairwise (tree) reduction.

    (phi(t_N, t_0) from interval transitions, paper eq. 2; the tree keeps the round-off ~log N.)

    Parameters
    ----------
    phis : ndarray (..., N, n, n)
        The factors phi_0 .. phi_{N-1} along axis -3 (N >= 1), earliest first.

    Returns
    -------
    ndarray (..., n, n)
        The product, later factors on the left."""
    while phis.shape[-3] > 1:
        if phis.shape[-3] % 2:  # odd: multiply the last one into its predecessor
            last = phis[..., -1:, :, :] @ phis[..., -2:-1, :, :]
            phis = np.concatenate([phis[..., :-2, :, :], last], axis=-3)
            continue
        phis = phis[..., 1::2, :, :] @ phis[..., 0::2, :, :]
    return phis[..., 0, :, :]


def monodromy(sys: LTPSystem, steps: int = DEFAULT_STEPS) -> np.ndarray:
    """Monodromy matrix psi_A(0) = phi_A(T, 0) (paper eq. 4), shape (*batch, n, n).

    Parameters
    ----------
    sys : LTPSystem
        The system, possibly batched (leading axes of its matrices).
    steps : int
        Magnus intervals per period.

    Returns
    -------
    ndarray (*batch, n, n)
        psi_A(0) = phi_A(T, 0).
    """
    return chain_product(interval_transitions(sys, steps))


def multipliers(sys: LTPSystem, steps: int = DEFAULT_STEPS) -> np.ndarray:
    """Characteristic multipliers: eigenvalues of the monodromy matrix (paper Theorem 2.1).

    Parameters
    ----------
    sys : LTPSystem
        The system, possibly batched (leading axes of its matrices).
    steps : int
        Magnus intervals per period.

    Returns
    -------
    ndarray (*batch, n), complex
        Eigenvalues of the monodromy matrix; ``inf`` for a system whose monodromy overflows
        (a hugely unstable loop, e.g. a gain of 10 per entry: the product of the interval
        transitions exceeds 1e308).
    """
    with np.errstate(over="ignore", invalid="ignore"):
        M = monodromy(sys, steps)
    finite = np.all(np.isfinite(M), axis=(-2, -1))
    if np.all(finite):
        return np.linalg.eigvals(M)
    out = np.full(M.shape[:-1], np.inf, dtype=complex)
    out[finite] = np.linalg.eigvals(M[finite])
    return out


def spectral_radius(sys: LTPSystem, steps: int = DEFAULT_STEPS) -> np.ndarray:
    """rho(psi_A(0)) = max |multiplier| (paper eq. 30); the system is stable iff < 1.

    Parameters
    ----------
    sys : LTPSystem
        The system, possibly batched (leading axes of its matrices).
    steps : int
        Magnus intervals per period.

    Returns
    -------
    ndarray (*batch)
        max |multiplier|.
    """
    return np.max(np.abs(multipliers(sys, steps)), axis=-1)


def is_stable(sys: LTPSystem, steps: int = DEFAULT_STEPS) -> np.ndarray:
    """Uniform exponential stability test of paper Theorem 2.1.

    Parameters
    ----------
    sys : LTPSystem
        The system, possibly batched (leading axes of its matrices).
    steps : int
        Magnus intervals per period.

    Returns
    -------
    ndarray of bool (*batch)
        True where every characteristic multiplier lies in the open unit disc.
    """
    return spectral_radius(sys, steps) < 1.0
