"""Feasibility restoration (phase 1): a start gain that meets the hard requirements when no
scaling of the LQ start does.

Why: scaling a gain down buys hold margin but slows the held loop's decay, so under a design spec
with a decay bound (hold margin 4 and |multiplier| <= 0.05 at every Ts of 1-30 s) no scaling of the
paper's LQ start is feasible at 30 s (sigma = 60: margin 4 needs the scale <= 0.6, where the held
loop's multiplier is 0.25). The requirements are cheap to evaluate (held-loop spectral radii and the
linear dipole peak, no H-inf norm), so CMA-ES minimizes their total violation first (the classical
phase 1 of constrained optimization, e.g. Nocedal & Wright, Numerical Optimization, sec. 15.4) and
the tuner then minimizes J from the first feasible gain.
"""
from __future__ import annotations

import numpy as np

from .cmaes import gain_scale


def violation(screen, Ks) -> np.ndarray:
    """Total violation of the hard requirements of ``screen`` (a ``requirements.FlightScreen``) per
    gain: the sum over the checked periods of log rho(margin K) above 0 and log rho(K) above
    log max_multiplier, plus log(peak / budget) above 0 of the dipole; 0 exactly when feasible
    (up to the strict inequalities, which ``screen`` itself decides).

    Parameters
    ----------
    screen : FlightScreen
        Held loops, hold margin, multiplier bound, dipole loops, case and budget of one model.
    Ks : array_like (n, 3, 6)
        Gains (any shape with a multiple of 18 entries).

    Returns
    -------
    ndarray (n,)
        >= 0; inf where a product is not finite.
    """
    from .dipole import peak_dipole
    from .requirements import hold_ends

    Ks = np.asarray(Ks, dtype=float).reshape(-1, 3, 6)
    v = np.zeros(len(Ks))
    with np.errstate(divide="ignore", invalid="ignore"):
        for loop in screen.loops:
            for g, bound in hold_ends(screen.top or screen.gain_margin, screen.max_multiplier):
                v += np.maximum(0.0, np.log(loop.spectral_radius(g * Ks) / bound))
        for loop, scales in screen.points:
            for g in scales:
                v += np.maximum(0.0, np.log(loop.spectral_radius(g * Ks)))
        for loop in screen.dipole_loops:
            v += np.maximum(0.0, np.log(peak_dipole(loop, Ks, screen.case).max(axis=-1) / screen.budget))
    return np.where(np.isnan(v), np.inf, v)


def restore(screens, K0, seed: int = 0, max_evals: int = 2000, popsize: int = 12, sigma0: float = 0.3,
            stall: int = 25):
    """A gain meeting every screen of ``screens`` (one per model), by CMA-ES on the summed
    :func:`violation` in coordinates K = K0 + S x (S: :func:`.cmaes.gain_scale` of K0), from x = 0;
    given up when the best violation has not fallen by 1 % in ``stall`` generations (an
    infeasible requirement set is then named by the caller without a long search).

    Parameters
    ----------
    screens : sequence of FlightScreen
        One screen per model; a gain must pass all.
    K0 : array_like (3, 6)
        Start gain (centre of the coordinates).
    seed : int
        Seed of the cma package (``seed + 1``).
    max_evals : int
        Budget of gain evaluations.
    popsize : int
        CMA-ES population size.
    sigma0 : float
        Initial step in units of the per-entry scale S.
    stall : int
        Generations without a 1 % fall of the best violation that end the search.

    Returns
    -------
    (ndarray (3, 6) or None, int)
        The first feasible gain found (None if none within ``max_evals``) and the evaluations spent.
    """
    import cma

    K0 = np.asarray(K0, dtype=float).reshape(3, 6)
    S = gain_scale(K0).ravel()
    es = cma.CMAEvolutionStrategy(np.zeros(18), sigma0, {"seed": int(seed) + 1, "popsize": popsize,
                                                         "verbose": -9, "maxfevals": max_evals})
    evals, best, since = 0, np.inf, 0
    while not es.stop() and evals < max_evals and since < stall:
        X = np.asarray(es.ask())
        Ks = (K0.ravel() + X * S).reshape(-1, 3, 6)
        v = sum(violation(s, Ks) for s in screens)
        evals += len(Ks)
        ok = np.flatnonzero(v == 0.0)
        for i in ok[np.argsort(v[ok])]:
            if all(s(Ks[i:i + 1])[0] for s in screens):
                return Ks[i], evals
        since = 0 if v.min() < 0.99 * best else since + 1
        best = min(best, float(v.min()))
        es.tell(list(X), list(np.where(np.isfinite(v), v, 1e6)))
    return None, evals
