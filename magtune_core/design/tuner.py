"""Randomized H-infinity tuning of the constant gain K (paper section 4.2, eqs. 23-25).

From a stabilizing K(i), draw N candidates K_j = K(i) + mu (eta_j + dK/|dK|), eta_j ~ N(0, I_18),
dK = K(i) - K(i-1) (eq. 23; no drift term on the first step). The rejection ratio
r = P{J(K_j) > J(K(i))} (eq. 25) only needs, per candidate, whether its norm beats the
incumbent's: one gamma-test at gamma = J(K(i)) each, all candidates in one batch. Only the
candidates that pass enter a batched "tournament" bisection that finds the argmin (eq. 24)
without computing every norm. mu adapts with r (step 6); the run stops when r >= r_max (step 7).

Decisions where the paper is silent (docs/decisions.md, "The paper's tuner kept as published"):
* a candidate that is not stabilizing has J = inf (it fails the gamma-test, which implies
  closed-loop stability since (C_sigma, A) is detectable);
* when no candidate beats the incumbent (r = 1), K(i) is kept: the paper's step 5 would
  accept the best candidate even if worse, which can only raise J on the last step;
* mu is multiplied by ``mu_up`` when r falls and divided by it when r rises; when the best
  candidate is not stabilizing (step 5 "else"), mu is divided by it and the draw repeated;
* ``patience`` (default 1, the paper's rule) > 1 asks for that many consecutive iterations
  with r >= r_max, mu shrinking by ``mu_up`` after each, before stopping. With the paper's
  fixed mu = 1e-3 the literal rule can stop after 2 iterations at sigma = 240 (the gains are
  small there, so mu is a large step); see docs/table1.md for the spread it causes.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from ..base.workers import worker_pool
from ..ltp import DEFAULT_STEPS, gamma_test, hinfnorm, spectral_radius
from .lq import lq_gain
from .model import AttitudeLTP
from .objective import one_thread_per_worker
from .problem import attitude_system, performance_system


@dataclass(frozen=True)
class TunerSettings:
    """Paper settings by default: N = 540, r_max = 0.995, mu = 1e-3 (section 4.2)."""

    samples: int = 540
    r_max: float = 0.995
    mu: float = 1e-3
    mu_up: float = 1.5
    max_iter: int = 300
    mu_min: float = 1e-9
    steps: int = DEFAULT_STEPS  # Magnus intervals per period in every norm evaluation
    rtol: float = 1e-6  # relative bracket of the argmin's norm
    workers: int = 1
    patience: int = 1  # stop at the patience-th consecutive r >= r_max (1 = the paper's step 7)


@dataclass
class TuneResult:
    """Outcome of a tuning run (paper 4.2 or CMA-ES): the best gain and its J, the start, the record."""

    K: np.ndarray
    J: float
    K0: np.ndarray
    J0: float
    sigma: float
    seed: int
    iterations: int
    settings: TunerSettings
    history: list = field(default_factory=list)  # (iteration, J, r, mu, better) per step
    seconds: float = 0.0
    converged: bool = False
    method: str = "paper"
    evaluations: int = 0  # gains evaluated (paper: candidates gamma-tested; cma: full J evaluations)
    tuned_steps: int | None = None  # Magnus steps at the end of the run (cma: the resolution watch may double them)
    stop: str | None = None  # cma: why the search ended: "certified", "budget", "unresolved" or "interrupted"

    def provenance(self) -> dict:
        """The run's record for a gains file: method, seed, iterations, settings, convergence, evaluations.

        Returns
        -------
        dict
            method, seed, iterations, evaluations, converged, J_initial, tuner (settings without workers),
            and tuned_steps / stop when set.
        """
        s = asdict(self.settings)
        s.pop("workers")
        out = {"method": self.method, "seed": int(self.seed), "iterations": int(self.iterations),
               "evaluations": int(self.evaluations), "converged": bool(self.converged),
               "J_initial": float(self.J0), "tuner": {k: (float(v) if isinstance(v, float) else v) for k, v in s.items()}}
        if self.tuned_steps is not None:
            out["tuned_steps"] = int(self.tuned_steps)
        if self.stop is not None:
            out["stop"] = self.stop
        return out


class CandidateEvaluator:
    """Batched gamma-tests of candidate gains, optionally spread over worker processes."""

    def __init__(self, model: AttitudeLTP, sigma: float, steps: int, workers: int = 1):
        self.model, self.sigma, self.steps, self.workers = model, sigma, steps, workers
        self._pool = worker_pool(workers, initializer=one_thread_per_worker) if workers > 1 else None

    def close(self):
        """Shut the worker pool down (pending evaluations cancelled)."""
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)

    def passes(self, Ks: np.ndarray, gammas: np.ndarray) -> np.ndarray:
        """||G_zTd(K_j)||_inf < gamma_g for candidates (n, 3, 6) and levels (n, g) -> bool (n, g).

        Parameters
        ----------
        Ks : ndarray (n, 3, 6)
            Candidate gains.
        gammas : ndarray (n, g)
            Levels tested per candidate.

        Returns
        -------
        ndarray of bool (n, g)
            True where the candidate's norm is below the level (the gamma-test passes).
        """
        if self._pool is None or len(Ks) < 2 * self.workers:
            return _passes(self.model, self.sigma, self.steps, Ks, gammas)
        parts = np.array_split(np.arange(len(Ks)), self.workers)
        futs = [self._pool.submit(_passes, self.model, self.sigma, self.steps, Ks[p], gammas[p]) for p in parts]
        return np.concatenate([f.result() for f in futs])


def _passes(model, sigma, steps, Ks, gammas):
    g = gammas.shape[-1]
    sys = performance_system(model, np.repeat(Ks, g, axis=0), sigma)
    return gamma_test(sys, gammas.reshape(-1), steps).reshape(len(Ks), g)


def tournament(ev: CandidateEvaluator, Ks: np.ndarray, upper: float, rtol: float):
    """Index and norm bracket of argmin_j J(K_j) among candidates known to satisfy J < upper.

    Batched bisection on a shared level: each round tests a geometric grid of levels on the
    surviving candidates; those passing at the lowest level any of them passes survive.

    Parameters
    ----------
    ev : CandidateEvaluator
        Batched gamma-tests.
    Ks : ndarray (n, 3, 6)
        Candidates, each known to have J < ``upper``.
    upper : float
        Upper bound of their norms (the incumbent's J).
    rtol : float
        Relative width of the final bracket.

    Returns
    -------
    (index, lo, hi) : tuple
        Position in ``Ks`` of the best candidate and the bracket [lo, hi] of its J.
    """
    alive = np.arange(len(Ks))
    hi, lo, lo_ok = upper, 0.9 * upper, False
    while True:
        if lo_ok and hi - lo <= rtol * hi:
            break
        g = int(np.clip(256 // len(alive), 1, 8))
        levels = lo * (hi / lo) ** (np.arange(1, g + 1) / (g + 1))
        p = ev.passes(Ks[alive], np.broadcast_to(levels, (len(alive), g)))
        anyp = p.any(axis=0)
        if not anyp.any():
            lo, lo_ok = levels[-1], True
            continue
        first = int(np.argmax(anyp))
        if first == 0 and not lo_ok:
            hi = levels[0]
            alive = alive[p[:, 0]]
            lo = max(lo - (upper - lo), 0.5 * lo)  # the best may lie below the initial guess
            continue
        hi = levels[first]
        if first > 0:
            lo, lo_ok = levels[first - 1], True
        alive = alive[p[:, first]]
    return int(alive[0]), lo, hi


def tune(model: AttitudeLTP, sigma: float, seed: int = 0, settings: TunerSettings = TunerSettings(),
         K0=None, progress=None) -> TuneResult:
    """Run the randomized algorithm of paper section 4.2 from the LQ gain (or K0).

    Parameters
    ----------
    model : AttitudeLTP
        Design model.
    sigma : float
        Weight of the torque in z (paper eq. 20).
    seed : int
        Seed of ``numpy.random.default_rng`` (the candidate draws).
    settings : TunerSettings
        N, r_max, mu and stopping settings.
    K0 : array_like (3, 6) or None
        Start gain; None: :func:`~.lq.lq_gain`.
    progress : callable or None
        ``progress(iteration, J, r, mu, n_better)`` after each iteration.

    Returns
    -------
    TuneResult
        The best gain K and its J, the start K0 and J0, iterations, history, wall time, ``converged`` (r >= r_max ``patience`` times).

    Raises
    ------
    ValueError
        If the start gain is not stabilizing (infinite H-inf norm)."""
    t_start = time.perf_counter()
    s = settings
    rng = np.random.default_rng(seed)
    K = lq_gain(model, sigma) if K0 is None else np.asarray(K0, dtype=float).reshape(3, 6)
    J = float(hinfnorm(performance_system(model, K, sigma), rtol=s.rtol, steps=s.steps))
    if not np.isfinite(J):
        raise ValueError("tune: the initial gain is not stabilizing (infinite H-inf norm)")
    K0_, J0 = K.copy(), J
    mu, r_prev, dK = s.mu, None, None
    history = []
    ev = CandidateEvaluator(model, sigma, s.steps, s.workers)
    converged = False
    it = strikes = evaluations = 0
    try:
        while it < s.max_iter and mu > s.mu_min:
            drift = 0.0 if dK is None or not np.any(dK) else dK / np.linalg.norm(dK)
            eta = rng.standard_normal((s.samples, 3, 6))
            Ks = K + mu * (eta + drift)  # eq. (23)
            better = ev.passes(Ks, np.full((s.samples, 1), J))[:, 0]
            evaluations += s.samples
            r = 1.0 - better.mean()  # eq. (25): fraction of candidates worse than K(i)
            if better.any():
                idx = np.flatnonzero(better)
                j, _, hi = tournament(ev, Ks[idx], J, s.rtol)  # eq. (24)
                Kbest = Ks[idx[j]]
                if not spectral_radius(attitude_system(model, Kbest), s.steps) < 1.0:  # step 5
                    mu /= s.mu_up
                    continue
                dK, K, J = Kbest - K, Kbest, float(hi)
            else:
                dK = None
            it += 1
            history.append((it, J, float(r), mu, int(better.sum())))
            if progress is not None:
                progress(it, J, r, mu, int(better.sum()))
            if r >= s.r_max:  # step 7
                strikes += 1
                if strikes >= s.patience:
                    converged = True
                    break
                mu /= s.mu_up  # patience > 1: retry at a smaller step before giving up
                r_prev = r
                continue
            strikes = 0
            if r_prev is not None:  # step 6
                mu = mu / s.mu_up if r > r_prev else (mu * s.mu_up if r < r_prev else mu)
            r_prev = r
    finally:
        ev.close()
    J = float(hinfnorm(performance_system(model, K, sigma), rtol=1e-8, steps=s.steps, guess=J))
    return TuneResult(K, J, K0_, J0, sigma, seed, it, s, history, time.perf_counter() - t_start, converged,
                      method="paper", evaluations=evaluations)
