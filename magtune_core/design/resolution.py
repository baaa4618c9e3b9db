"""Enough Magnus steps for the design model at hand, and a stabilizing start gain.

Every norm of the project discretizes one period into ``steps`` intervals with the closed loop
frozen at each midpoint (2nd-order Magnus, :mod:`magtune_core.ltp`). The local error grows with
(h |A + B(t) K|)^3: negligible for the paper's 25 kg m^2 satellite at 64 steps (h = 88 s), but a
12U CubeSat (0.1-0.25 kg m^2) tuned at the same sigma has a ~100x faster closed loop, and 64
steps then give J = 10134 for a gain whose converged J is 33483, and call the LQ start stable
(rho = 2e-22) when it is unstable (rho = 8e5 at 1024 steps). An optimizer run on such a
discretization exploits the error. Hence:

* :func:`resolved_steps`: double ``steps`` until J (and stability) at ``steps`` and ``2 steps``
  agree to ``rtol``; ``magtune analyze`` reports with it, ``magtune tune`` tunes with it;
* :func:`start_gain`: the LQ start of paper 4.2 on the averaged model, or, when that gain does not
  stabilize the LTP model (checked at resolved steps), the LQ gain of a larger weight
  sigma * 10^k (k = 1..4) with the lowest J at ``sigma`` - a less aggressive loop that the
  projection law can realize with the field turning under it.
"""
from __future__ import annotations

import numpy as np

from ..ltp import DEFAULT_STEPS, hinfnorm, spectral_radius
from .lq import lq_gain
from .problem import attitude_system, performance_system

#: Largest step count :func:`resolved_steps` tries (about 30 s per norm on this machine).
MAX_STEPS = 4096


def _worst(models, K, sigma: float, steps: int) -> tuple[float, float]:
    """(max over models of J, max rho) of gain K at ``steps``; J = inf if any loop is unstable."""
    J, rho = 0.0, 0.0
    for m in models:
        r = float(spectral_radius(attitude_system(m, K), steps))
        rho = max(rho, r)
        if not r < 1.0:
            return np.inf, rho
        J = max(J, float(hinfnorm(performance_system(m, K, sigma), rtol=1e-6, steps=steps)))
    return J, rho


def resolved_steps(models, K, sigma: float, steps: int = DEFAULT_STEPS, rtol: float = 1e-3,
                   max_steps: int = MAX_STEPS) -> tuple[int, float]:
    """Smallest steps = ``steps`` * 2^j at which J(steps) and J(2 steps) agree within ``rtol``.

    ``models`` is one AttitudeLTP or a sequence (worst case over them). An unstable result
    (J = inf) never counts as agreement: a stiff, stabilizing gain can look unstable on a coarse
    grid (the sigma = 60 optimum, J = 220, has rho = 1.7e7 at 32 steps; before the Hamiltonian
    intervals were squared in scattering form, ``ltp.hinf.interval_scattering``, no level passed
    below 256-1024 steps for the shipped optima), so the steps are
    doubled up to ``max_steps`` (cheap: an unstable loop costs one monodromy per level). Returns
    ``(steps, J)`` with J at the returned steps; at ``max_steps`` without agreement returns
    ``(max_steps, J)``.

    Parameters
    ----------
    models : AttitudeLTP or list or tuple of AttitudeLTP
        Design model(s); J and stability are the worst over them.
    K : array_like (3, 6)
        Gain (any shape with 18 entries).
    sigma : float
        Weight of the torque in z (paper eq. 20).
    steps : int
        First number of Magnus intervals per period tried.
    rtol : float
        Relative agreement of J at steps and 2 steps.
    max_steps : int
        Largest number of intervals returned.

    Returns
    -------
    (int, float)
        The resolved number of Magnus intervals per period and J (worst over models) there.
    """
    models = (models,) if not isinstance(models, (list, tuple)) else tuple(models)
    K = np.asarray(K, dtype=float).reshape(3, 6)
    J, _ = _worst(models, K, sigma, steps)
    while steps < max_steps:
        J2, _ = _worst(models, K, sigma, 2 * steps)
        if np.isfinite(J) and np.isfinite(J2) and abs(J2 - J) <= rtol * J2:
            return steps, J
        steps, J = 2 * steps, J2
    return steps, J


def start_gain(models, sigma: float, steps: int = DEFAULT_STEPS, rtol: float = 1e-2):
    """The tuner's start: LQ at ``sigma`` if it stabilizes every model, else the best stabilizing LQ
    gain of sigma * 10^k, k = 1..4 (module docstring). Steps are resolved on the chosen gain.

    Parameters
    ----------
    models : AttitudeLTP or list or tuple of AttitudeLTP
        Design model(s); the LQ gains are designed on the first, checked on all.
    sigma : float
        Weight of the torque in z (paper eq. 20).
    steps : int
        First number of Magnus intervals per period tried (:func:`resolved_steps`).
    rtol : float
        Relative agreement of J that resolves the steps.

    Returns
    -------
    (ndarray (3, 6), float, int, float)
        K0, the LQ weight it was designed with, the resolved steps and J(K0) at ``sigma`` there.

    Raises
    ------
    ValueError
        If no LQ gain of sigma .. sigma * 1e4 stabilizes the model(s).
    """
    models = (models,) if not isinstance(models, (list, tuple)) else tuple(models)
    nominal = models[0]
    K = lq_gain(nominal, sigma)
    n, J = resolved_steps(models, K, sigma, steps, rtol)
    if np.isfinite(J):
        return K, sigma, n, J
    best = None
    for k in range(1, 5):
        Kk = lq_gain(nominal, sigma * 10.0**k)
        nk, Jk = resolved_steps(models, Kk, sigma, steps, rtol)
        if np.isfinite(Jk) and (best is None or Jk < best[3]):
            best = (Kk, sigma * 10.0**k, nk, Jk)
    if best is None:
        raise ValueError(f"no LQ gain of sigma {sigma:g} .. {sigma * 1e4:g} stabilizes the LTP model")
    return best
