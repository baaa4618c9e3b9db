"""The design problem of paper section 4.1: closed loops, performance outputs, figures of merit.

J(K) = ||G_zTd||_inf with z = [Z x; sigma K x] (paper eqs. 20-22), subject to the closed loop
A + B(t) K being stable (Theorem 2.1). Figures reported in Table 1 (paper eqs. 28-30):
c1 = ||G_{dq,Td}||_inf, c2 = ||G_{m,Td}||_2, rho = max |multiplier|.
Initial gain: LQ on the time-averaged model (``lq.lq_gain``, paper 4.2).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..ltp import DEFAULT_STEPS, LTPSystem, h2norm, hinfnorm, hinfnorm_gradient, spectral_radius
from .model import Z_ATT, AttitudeLTP


def performance_output(K, sigma: float) -> np.ndarray:
    """C_sigma = [Z; sigma K] of paper eq. (20), for one gain or a batch (..., 3, 6) -> (..., 6, 6).

    Parameters
    ----------
    K : array_like (..., 3, 6)
        Gain or batch of gains.
    sigma : float
        Weight of the torque u = K x in the performance output z (paper eq. 20).

    Returns
    -------
    ndarray (..., 6, 6)
        C_sigma per gain: rows Z = [I3 0] over sigma K.
    """
    K = np.asarray(K, dtype=float)
    Z = np.broadcast_to(Z_ATT, K.shape[:-2] + Z_ATT.shape)
    return np.concatenate([Z, sigma * K], axis=-2)


def performance_system(model: AttitudeLTP, K, sigma: float) -> LTPSystem:
    """G_zTd^sigma = [A + B(t) K, B_T, C_sigma, 0] (paper eq. 21).

    Parameters
    ----------
    model : AttitudeLTP
        LTP attitude model (paper eq. 19).
    K : array_like (..., 3, 6)
        Gain or batch of gains.
    sigma : float
        Weight of the torque in z (paper eq. 20).

    Returns
    -------
    LTPSystem
        The closed loop from disturbance torque T_d to z = [dq; sigma K x], period ``model.period``.
    """
    return LTPSystem(model.closed_loop(K), model.BT, performance_output(K, sigma), None, model.period)


def cost_gradient(model: AttitudeLTP, K, sigma: float, steps: int = DEFAULT_STEPS, rtol: float = 1e-10):
    """J(K) of paper eq. (21) and its exact gradient dJ/dK (3x6), by the chain rule through
    A_cl(t) = A + B(t) K and C_sigma = [Z; sigma K] (eqs. 19-20) from :func:`..ltp.hinfnorm_gradient`.

    Parameters
    ----------
    model : AttitudeLTP
        LTP attitude model (paper eq. 19).
    K : array_like (3, 6)
        Gain (any shape with 18 entries).
    sigma : float
        Weight of the torque in z (paper eq. 20).
    steps : int
        Magnus intervals per period.
    rtol : float
        Relative accuracy of the H-inf norm.

    Returns
    -------
    J : float
        ||G_zTd^sigma||_inf on ``steps`` Magnus intervals.
    dJ_dK : ndarray (3, 6)
        Its gradient (of the active peak: J is nonsmooth where several peaks are active).
    grad : HinfGradient
        The node gradients and the worst-case multiplier pair.
    """
    K = np.asarray(K, dtype=float).reshape(3, 6)
    grad = hinfnorm_gradient(performance_system(model, K, sigma), steps=steps, rtol=rtol)
    return grad.J, _gain_gradient(model, sigma, grad.t, grad.dA, grad.dC), grad


def _gain_gradient(model: AttitudeLTP, sigma: float, t, dA, dC) -> np.ndarray:
    """dJ/dK from node gradients: A_cl = A + B(t) K and C_sigma = [Z; sigma K] (eqs. 19-20)."""
    Bn = model.B(np.ravel(t)).reshape(np.shape(t) + (6, 3))  # B(t) at the Magnus nodes
    return np.einsum("knai,knaj->ij", Bn, dA) + sigma * dC[..., 3:, :].sum(axis=(0, 1))


def attitude_system(model: AttitudeLTP, K) -> LTPSystem:
    """T_d -> dq_R = Z x (paper eq. 28).

    Parameters
    ----------
    model : AttitudeLTP
        LTP attitude model (paper eq. 19).
    K : array_like (..., 3, 6)
        Gain or batch of gains.

    Returns
    -------
    LTPSystem
        The closed loop from disturbance torque to attitude error dq (its H-inf norm is c1).
    """
    return LTPSystem(model.closed_loop(K), model.BT, Z_ATT, None, model.period)


def dipole_system(model: AttitudeLTP, K) -> LTPSystem:
    """T_d -> m = S(b)^T K x / |b|^2 (paper eqs. 17, 29).

    Parameters
    ----------
    model : AttitudeLTP
        LTP attitude model (paper eq. 19).
    K : array_like (..., 3, 6)
        Gain or batch of gains.

    Returns
    -------
    LTPSystem
        The closed loop from disturbance torque to commanded dipole m (its H2 norm is c2).
    """
    return LTPSystem(model.closed_loop(K), model.BT, model.dipole_output(K), None, model.period)


def closed_loop_system(model: AttitudeLTP, K) -> LTPSystem:
    """The closed loop of paper eq. 18-19 with the projection law u = K x, as an :class:`LTPSystem`.

    Parameters
    ----------
    model : AttitudeLTP
        LTP attitude model (paper eq. 19).
    K : array_like (..., 3, 6)
        Gain or batch of gains.

    Returns
    -------
    LTPSystem
        Same as :func:`attitude_system`: input T_d, output dq.
    """
    return attitude_system(model, K)


@dataclass
class Figures:
    """J, c1, c2, rho of one gain (paper eqs. 21, 28-30)."""

    J: float
    c1: float
    c2: float
    rho: float
    stable: bool

    def as_dict(self) -> dict:
        """The figures as plain floats (and booleans), as a gains file's provenance stores them.

        Returns
        -------
        dict
            {"J", "c1", "c2", "rho": float, "stable": bool}.
        """
        return {k: (float(v) if not isinstance(v, bool) else v) for k, v in asdict(self).items()}


def figures(model: AttitudeLTP, K, sigma: float, steps: int = DEFAULT_STEPS, rtol: float = 1e-7) -> Figures:
    """All figures of merit of gain K (3x6) for weight sigma.

    Parameters
    ----------
    model : AttitudeLTP
        LTP attitude model (paper eq. 19).
    K : array_like (3, 6)
        Gain (any shape with 18 entries).
    sigma : float
        Weight of the torque in z (paper eq. 20).
    steps : int
        Magnus intervals per period (the H2 norm uses max(8 steps, 1024)).
    rtol : float
        Relative accuracy of the H-inf norms.

    Returns
    -------
    Figures
        J (eq. 21), c1 (eq. 28), c2 (eq. 29, H2), rho (eq. 30) and ``stable``; J, c1, c2 are inf when
        the closed loop is unstable (rho >= 1).
    """
    K = np.asarray(K, dtype=float).reshape(3, 6)
    rho = float(spectral_radius(attitude_system(model, K), steps))
    if not rho < 1.0:
        return Figures(np.inf, np.inf, np.inf, rho, False)
    J = float(hinfnorm(performance_system(model, K, sigma), rtol=rtol, steps=steps))
    c1 = float(hinfnorm(attitude_system(model, K), rtol=rtol, steps=steps))
    # the Gramian quadrature converges more slowly than the H-inf test (bench/): more steps, cheap
    c2 = float(h2norm(dipole_system(model, K), steps=max(8 * steps, 1024)))
    return Figures(J, c1, c2, rho, True)
