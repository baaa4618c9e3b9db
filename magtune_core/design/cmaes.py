"""Converging tuner: CMA-ES on J(K) with batched populations, local restarts and a certified stop.

Why CMA-ES (``--method cma``, the default of ``magtune tune``): J(K) = ||G_zTd^sigma(K)||_inf
(paper eq. 21) is nonsmooth where several frequency peaks are active (the usual situation at an
H-inf optimum) and flat along some directions of the 18 gain entries; the paper's randomized
search (``--method paper``, eqs. 23-25) keeps a fixed-shape step and stops when 99.5 % of its
isotropic draws are worse, which happens well before the optimum when the cost is a narrow
valley. CMA-ES (Hansen 2016, "The CMA Evolution Strategy: A Tutorial"; the ``cma`` package)
learns the valley's shape (covariance) and step size, uses only the ranking of J (so the
bisection accuracy ``rtol`` and inf for unstable gains are harmless) and evaluates a whole
population per generation, which is one batched Riccati gamma-test bisection (``objective``).

The algorithm (docs/tuning.md; the decisions and their measurements: docs/decisions.md):

1. coordinates: K = K0 + S * x, x0 = 0. Under a hold constraint (the default of ``magtune tune``)
   the first run's S_ij is the **feasible range** of entry ij (:func:`feasible_scale`: how far it
   can move alone before the loop fails stability or the hold constraint), step
   ``feasible_sigma0``; otherwise (the paper's unconstrained problem, where the ranges can be
   unbounded) S is :func:`gain_scale` (max(|K0_ij|, 0.1 max_i |K0_ij|): each column of K has its
   own unit, dq in rad, dw in rad/s), step ``sigma0``. Why: the optimum's entries are 3-300x the LQ
   start's, and the LQ gain leaves the coupling entries at ~1e-16, so in K0-scaled units the
   optimum is ~300 steps away and the search spends most of its budget travelling; the feasible
   ranges are of the optimum's size (measured at sigma = 60: 90-s runs 10.8-20.5 % above the best
   known J with K0-scaled, ~1-3 % with feasible-scaled coordinates; bench/README.md);
2. a run is stopped when its best J has not improved by more than ``rtol_stall`` (relative) over
   ``stall`` generations, or by the cma package's own criteria (tolx, tolfun, conditioning);
3. **local restarts** from the best gain so far, with a fresh covariance, in coordinates
   re-centred on it and rescaled to its entries (S = gain_scale(K_best)): a step is always
   relative to the gain at hand, however far the search has moved from the start (the sigma = 60
   optimum has entries 3-35x the LQ start's, ~400 LQ-scaled units away). A restart after a run
   that still improved J by more than ``travel_rtol`` takes the first run's step ``sigma0`` (the
   search is still travelling along the valley); otherwise the smaller step ``restart_sigma``
   (a fresh, isotropic population tests the incumbent's neighbourhood in every direction again);
4. **certified stop**: when ``certify`` consecutive restarts each fail to improve the best J by
   more than ``rtol_certify`` (relative), i.e. no population of ``certify`` x (run length) draws
   with relative perturbations of ``restart_sigma`` (5 %) of the incumbent's entries found a
   better gain, a **coordinate poll** follows: each entry alone moved by +- d of its scale (36 gains,
   one batch), moving to the best while J improves, d halved from ``poll_step`` (5 %) down to
   ``poll_min`` (0.1 %). If the poll improved J by no more than ``rtol_certify`` in all, the result is
   declared converged; otherwise the restarts go on from the polled gain. Why the poll: at sigma = 120
   two restarts "certified" J = 315.37 while a Nelder-Mead from it found 313.80 (-0.5 %) and a
   coordinate poll -0.1 % within 300 evaluations: in a narrow, kinked valley isotropic draws rarely
   improve, moves of single entries do. ``max_evals`` bounds the work (``converged`` is then False).

5. **ranking resolution**: each generation's J are computed to a relative accuracy of
   ``rtol_spread`` x (median - best) / best of the previous generation, between ``rtol`` and
   ``rtol_max``: a widely spread population needs fewer bisection levels per gain, and near
   the optimum the accuracy tightens to ``rtol``; the returned J is re-evaluated at the
   objective's own accuracy.

6. **resolution watch**: the start's Magnus steps may stop resolving the closed loop as the gains
   stiffen, and an optimizer then exploits the discretization error (J at 64 steps far below J
   at 512: seen on the 12U example). Every ``resolution_every`` generations and at the end of
   every run the incumbent's J is recomputed at twice the steps; if it differs by more than
   ``resolution_rtol`` the objective's steps are doubled (up to ``max_steps``) and the search
   goes on, on the finer grid. Before a certified stop the check is made at the certificate's own
   tolerance ``rtol_certify`` (2e-4, 10x stricter): a certificate to 2e-4 on a grid whose error is
   1e-3 would certify the grid's error (measured at sigma = 240: a poll "improved" J by 0.07 % at
   256 steps with a gain 0.04 % worse at 512). At ``max_steps``, where the grid can no longer be
   doubled, the certificate is issued only if J at twice the steps agrees to that tolerance;
   otherwise the run ends with ``stop = "unresolved"`` (not converged).

Every random draw comes from ``numpy.random.default_rng(seed)`` (passed to cma as its ``randn``;
the package's global seeding is switched off), so a seed gives the same gains.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .tuner import TuneResult


@dataclass(frozen=True)
class CmaSettings:
    """Settings of :func:`tune_cma` (defaults: what converges at sigma = 60, 120, 240; bench/)."""

    popsize: int = 8  # smaller populations adapt faster along the curved valley (bench: J at 4,000 evaluations)
    sigma0: float = 0.3  # first run's step, in units of the per-entry scale S
    restart_sigma: float = 0.05  # local restarts' step (relative radius of the certified neighbourhood)
    travel_rtol: float = 0.01  # a run that improved J by more than this is followed by a restart with sigma0
    rescale: bool = True  # restarts re-centre and rescale the coordinates on the incumbent
    stall: int = 40  # generations without an improvement > rtol_stall that end a run
    rtol_stall: float = 1e-5
    certify: int = 2  # consecutive non-improving restarts that certify convergence
    rtol_certify: float = 2e-4
    max_evals: int = 30000
    steps: int = 64  # Magnus intervals per period in every norm evaluation
    rtol: float = 1e-5  # relative accuracy of each J near convergence (ranking resolution)
    rtol_max: float = 1e-3  # ... and while the population's J are widely spread (rtol_spread x spread)
    rtol_spread: float = 0.05
    workers: int = 1
    resolution_every: int = 25  # generations between checks that ``steps`` still resolves the incumbent
    resolution_rtol: float = 2e-3  # ... J at 2 x steps within this (relative), else steps are doubled
    max_steps: int = 1024
    poll_step: float = 0.05  # coordinate poll of the certificate: first relative step per entry ...
    poll_min: float = 1e-3  # ... halved down to this
    start_scale: str = "feasible"  # first run's coordinates under a hold constraint: "feasible" or "gain" (S of K0)
    feasible_sigma0: float = 0.05  # first run's step in feasible-range units (bench: 0.03 / 0.05 / 0.1)


def gain_scale(K0: np.ndarray) -> np.ndarray:
    """Per-entry scale S of the search coordinates: max(|K0_ij|, 0.1 max_i |K0_ij|) (3, 6).

    Parameters
    ----------
    K0 : ndarray (3, 6)
        Gain the coordinates are centred on (any shape with 18 entries; reshaped to (3, 6)).

    Returns
    -------
    ndarray (3, 6)
        The scale S of K = K0 + S * x; zero entries (an all-zero K0) fall back to max(max |K0|, 1e-12).
    """
    a = np.abs(np.asarray(K0, dtype=float).reshape(3, 6))
    col = a.max(axis=0, keepdims=True)
    S = np.maximum(a, 0.1 * col)
    return np.where(S > 0, S, max(float(a.max()), 1e-12))


def feasible_scale(feasible, K0: np.ndarray, decades: tuple = (-4.0, 4.0), points: int = 57) -> np.ndarray:
    """Per-entry scale of the first run's coordinates: how far each entry of K0 can move alone, up or
    down (the larger), before ``feasible`` (closed-loop stability and the hold constraint) fails.

    Why: the optimum's entries are 3-300x the LQ start's and the LQ gain has (numerically) zero
    coupling entries, so coordinates scaled to K0 put the optimum hundreds of steps away; the
    feasible range is what bounds the optimum when the hold constraint is active (J keeps falling
    along the segment LQ -> optimum up to the boundary; bench/README.md). Moves are on a
    geometric grid ``max |K0| x 10^decades`` (``points`` values); an entry that is feasible at every
    move gets the grid's end, one that fails at the first gets its first value.

    Parameters
    ----------
    feasible : callable
        Batched test ``feasible(Ks)``: Ks ndarray (n, 3, 6) -> array of bool (n,) (e.g. ``HinfObjective.feasible``).
    K0 : ndarray (3, 6)
        Start gain whose entries are moved one at a time.
    decades : tuple of float
        Decade exponents (low, high) of the move grid relative to max |K0|.
    points : int
        Number of moves on the geometric grid.

    Returns
    -------
    ndarray (3, 6)
        The scale S of K = K0 + S * x for the first run.
    """
    K0 = np.asarray(K0, dtype=float).reshape(3, 6)
    moves = float(np.abs(K0).max() or 1.0) * np.logspace(decades[0], decades[1], points)
    E = np.eye(18).reshape(18, 1, 3, 6) * moves[None, :, None, None]  # (18, points, 3, 6)
    R = np.empty((2, 18))
    for k, sign in enumerate((1.0, -1.0)):
        ok = np.asarray(feasible((K0 + sign * E).reshape(-1, 3, 6))).reshape(18, points)
        first_bad = np.where(ok.all(axis=1), points, np.argmin(ok, axis=1))
        R[k] = moves[np.maximum(first_bad - 1, 0)]
    return R.max(axis=0).reshape(3, 6)


def tune_cma(objective, K0: np.ndarray, sigma: float, seed: int = 0, settings: CmaSettings = CmaSettings(),
             progress=None, on_best=None) -> TuneResult:
    """Minimize ``objective`` (batched J, e.g. :class:`~magtune_core.design.objective.HinfObjective`) from K0.

    CMA-ES runs with local restarts around the incumbent; consecutive non-improving restarts,
    then a coordinate poll of every entry, certify the optimum (``settings.certify``) on a
    Magnus grid that resolves J to the certificate's tolerance. ``progress(evaluations, J_best,
    generation, step, restart)`` is called after each generation and ``on_best(K, J)`` whenever
    the best gain improves (e.g. to checkpoint a long run).

    Parameters
    ----------
    objective : HinfObjective or callable
        Batched J: ``objective(Ks, guess=, spread=, rtol=)`` -> ndarray (n,), with ``evaluations`` (and optionally
        ``steps``, ``feasible``, ``hold``).
    K0 : ndarray (3, 6)
        Start gain (e.g. the LQ gain); must stabilize the loop.
    sigma : float
        Disturbance-to-noise ratio of the objective, recorded in the result.
    seed : int
        Seed of ``numpy.random.default_rng`` (every random draw of the search).
    settings : CmaSettings
        Population, steps, stopping and certificate settings.
    progress : callable or None
        ``progress(evaluations, J_best, generation, step, restart)`` after each generation.
    on_best : callable or None
        ``on_best(K, J)`` whenever the best gain improves.

    Returns
    -------
    TuneResult
        Best gain and its J (re-evaluated), K0 and J0, generations, history rows
        (evaluations, J_best, generation, step, restart; during the coordinate poll ``step`` is
        its relative step d), wall time, ``converged`` (the certified stop fired), ``method`` =
        "cma", ``evaluations``, ``tuned_steps`` and ``stop`` ("certified", "budget", "unresolved" or
        "interrupted": KeyboardInterrupt raised by ``progress`` ends the search with the best gain).

    Raises
    ------
    ValueError
        If K0 is not stabilizing (infinite J; raised by the search's set-up).
    """
    t0 = time.perf_counter()
    search = _Search(objective, K0, settings, np.random.default_rng(seed), progress, on_best)
    interrupted = False
    try:  # Ctrl-C / SIGTERM (the CLI maps it) ends the search and keeps the best gain so far
        while not search.step():
            pass
    except KeyboardInterrupt:
        interrupted = True
    K, best_J = search.best_K, search.best_J
    # re-evaluated at the objective's accuracy; after an interrupt the ranking value is kept (the
    # worker pool may be gone; the caller recomputes the figures anyway)
    J = best_J if interrupted else float(objective(K[None], guess=best_J, spread=1.01)[0])
    stop = ("certified" if search.converged else "interrupted" if interrupted else "unresolved" if search.unresolved
            else "budget")
    return TuneResult(K, J, search.Kstart, search.J0, sigma, seed, search.gen_total, settings, search.history,
                      time.perf_counter() - t0, search.converged, method="cma", evaluations=search.evals,
                      tuned_steps=getattr(objective, "steps", None), stop=stop)


class _Search:
    """The state of one :func:`tune_cma` search: incumbent, search coordinates (K = K0 + S x),
    restart and certificate counters, history."""

    def __init__(self, objective, K0, s: CmaSettings, rng, progress, on_best):
        self.obj, self.s, self.rng, self.progress, self.on_best = objective, s, rng, progress, on_best
        self.K0 = self.Kstart = np.asarray(K0, dtype=float).reshape(3, 6)
        self.ev0 = objective.evaluations
        self.J0 = float(objective(self.K0[None])[0])
        if not np.isfinite(self.J0):
            raise ValueError("tune_cma: the initial gain is not stabilizing (infinite H-inf norm)")
        feasible = getattr(objective, "feasible", None)
        if s.start_scale == "feasible" and feasible is not None and getattr(objective, "hold", None) is not None:
            self.S, self.step0 = feasible_scale(feasible, self.K0), s.feasible_sigma0
        else:
            self.S, self.step0 = gain_scale(self.K0), s.sigma0
        # best_K = K0 + S * best_x, kept whole for an interrupt
        self.best_x, self.best_J, self.best_K = np.zeros(18), self.J0, self.K0
        self.history, self.gen_total, self.restart, self.fails = [], 0, 0, 0
        self.run_best_start_J = self.J0  # best J when the current restart began
        self.converged = self.unresolved = False

    @property
    def evals(self) -> int:
        """Evaluations of this search so far."""
        return self.obj.evaluations - self.ev0

    def _record(self, step: float) -> None:
        self.history.append((self.evals, self.best_J, self.gen_total, step, self.restart))
        if self.progress is not None:
            self.progress(self.evals, self.best_J, self.gen_total, step, self.restart)

    def _improve(self, K, J: float) -> None:
        self.best_K, self.best_J = K, float(J)
        if self.on_best is not None:
            self.on_best(self.best_K, self.best_J)

    def poll(self) -> None:
        """Coordinate poll (compass search): each of the 18 entries +- d of its scale, as one batch of
        36; move to the best point while it improves J, else halve d, from ``poll_step`` down to
        ``poll_min``. Isotropic CMA-ES restarts miss such single-entry moves in a narrow valley
        (measured at sigma = 120: two certified restarts found nothing, a poll then found -0.1 %)."""
        s = self.s
        E = np.concatenate([np.eye(18), -np.eye(18)]).reshape(36, 3, 6)
        d = s.poll_step
        while d >= s.poll_min and self.evals < s.max_evals:
            Ks = self.best_K + d * gain_scale(self.best_K) * E
            J = self.obj(Ks, guess=self.best_J, spread=1.05, rtol=s.rtol)
            i = int(np.argmin(J))
            if J[i] < self.best_J * (1 - s.rtol_stall):
                self.best_K, self.best_J = Ks[i], float(J[i])
                self.best_x = ((self.best_K - self.K0) / self.S).ravel()  # the CMA coordinates of the new incumbent
                if self.on_best is not None:
                    self.on_best(self.best_K, self.best_J)
            else:
                d /= 2
            self.gen_total += 1
            self._record(d)

    def cma_run(self) -> None:
        """One CMA-ES run from the incumbent, until it stalls (``stall`` generations without an
        improvement > ``rtol_stall``) or the budget is spent; every ``resolution_every``
        generations the Magnus grid is checked against the incumbent."""
        import cma

        s = self.s
        run_best = self.best_J
        opts = {"popsize": s.popsize, "seed": np.nan, "verbose": -9, "randn": lambda lam, n: self.rng.standard_normal((lam, n)),
                "tolfun": 0.0, "tolfunhist": 0.0, "tolflatfitness": 10 ** 9, "tolx": 1e-9, "maxiter": 10 ** 9,
                "CMA_diagonal": False}
        es = cma.CMAEvolutionStrategy(self.best_x.copy(), self.step0, opts)
        guess, spread = self.best_J, 1.5 if self.restart == 0 else 1.1
        rtol = s.rtol_max if self.restart == 0 else s.rtol
        last_gain = 0  # generation of the last improvement > rtol_stall in this run
        gen = 0
        while not es.stop():
            X = np.asarray(es.ask())
            Ks = self.K0 + self.S * X.reshape(-1, 3, 6)
            J = self.obj(Ks, guess=guess, spread=spread, rtol=rtol)
            fin = np.isfinite(J)
            worst = J[fin].max() if fin.any() else 10 * self.best_J
            f = np.where(fin, J, 10 * worst * (1 + np.linalg.norm(X - self.best_x, axis=1)))  # ranked below every stable gain
            es.tell(list(X), list(f))
            gen += 1
            self.gen_total += 1
            i = int(np.argmin(J))
            if J[i] < self.best_J:
                if J[i] < run_best * (1 - s.rtol_stall):
                    last_gain = gen
                    run_best = J[i]
                self.best_x = X[i].copy()
                self._improve(self.K0 + self.S * X[i].reshape(3, 6), J[i])
            if fin.any():
                guess = float(np.median(J[fin]))
                spread = float(np.clip(J[fin].max() / J[fin].min(), 1.02, 1.5))
                # ranking resolution: a small fraction of the spread of the better half (CMA-ES
                # uses only ranks, and ranks closer than that are noise-level to it anyway)
                rel = (np.median(J[fin]) - J[fin].min()) / J[fin].min()
                rtol = float(np.clip(s.rtol_spread * rel, s.rtol, s.rtol_max))
            J2 = _refine_steps(self.obj, self.best_K, self.best_J, s) if gen % s.resolution_every == 0 else None
            if J2 is not None:  # the grid was refined: the incumbent's J on the finer grid
                self.best_J = J2
                run_best, last_gain, guess, spread = self.best_J, gen, self.best_J, 1.1
            self._record(float(es.sigma))
            if gen - last_gain >= s.stall or self.evals >= s.max_evals:
                break

    def certify(self) -> bool | None:
        """After ``certify`` non-improving restarts: poll every entry, refine the grid to the
        certificate's tolerance; True: certified (or unresolved at max_steps), stop; False: the
        budget is spent; None: search on."""
        s = self.s
        start_J = self.best_J
        self.poll()
        # the certificate's tolerance holds only on a grid resolved to it: at the 1e-3 level
        # the search otherwise exploits the discretization error (sigma = 240: -0.07 % at
        # 256 steps was +0.04 % at 512)
        J2 = _refine_steps(self.obj, self.best_K, self.best_J, s, rtol=min(s.resolution_rtol, s.rtol_certify))
        if J2 is not None:
            self.best_J, self.fails = J2, 0
        elif start_J - self.best_J <= s.rtol_certify * start_J:
            # at max_steps the grid cannot be refined: certify only if it resolves J anyway
            self.unresolved = not _resolved_at_max(self.obj, self.best_K, self.best_J, s)
            self.converged = not self.unresolved
            return True
        else:
            self.fails = 0  # the poll moved the incumbent by more than rtol_certify: search on
        return False if self.evals >= s.max_evals else None

    def step(self) -> bool:
        """One CMA-ES run and its bookkeeping (grid check, certificate, next restart); True: stop."""
        s = self.s
        self.cma_run()
        J2 = _refine_steps(self.obj, self.best_K, self.best_J, s)
        if J2 is not None:
            self.best_J = J2
            self.fails = -1  # the grid changed: the restarts so far certify nothing
        evals = self.evals
        if self.restart > 0:
            improved = self.run_best_start_J - self.best_J > s.rtol_certify * self.run_best_start_J
            self.fails = 0 if improved else self.fails + 1
        if self.fails >= s.certify and self.certify() is not None:
            return True
        if evals >= s.max_evals:
            return True
        self.restart += 1
        travelled = self.run_best_start_J - self.best_J > s.travel_rtol * self.run_best_start_J
        self.step0 = s.sigma0 if travelled else s.restart_sigma
        self.run_best_start_J = self.best_J
        if s.rescale:  # coordinates relative to the incumbent's entries
            self.K0 = self.best_K
            self.S, self.best_x = gain_scale(self.K0), np.zeros(18)
        return False


def _refine_steps(objective, K: np.ndarray, J: float, s: CmaSettings, rtol: float | None = None) -> float | None:
    """Double ``objective.steps`` when J(K) at twice the steps differs from J by more than
    ``rtol`` (relative; default ``s.resolution_rtol``).

    Returns
    -------
    float or None
        J(K) on the doubled grid if the steps were doubled (the caller's incumbent J from now on),
        None if the grid still resolves K (or the objective has no ``steps``).
    """
    steps = getattr(objective, "steps", None)
    if steps is None or steps >= s.max_steps or not np.isfinite(J):
        return None
    J2 = _j_doubled(objective, K, J)
    if np.isfinite(J2) and abs(J2 - J) <= (s.resolution_rtol if rtol is None else rtol) * J2:
        return None
    objective.steps = 2 * steps
    return J2


def _resolved_at_max(objective, K, J: float, s: CmaSettings) -> bool:
    """At ``max_steps`` (where :func:`_refine_steps` no longer doubles): whether J(K) at twice the steps
    is within ``rtol_certify`` of J, i.e. whether a certificate on this grid certifies J and not the
    grid's error. True below ``max_steps`` (the refinement has checked it) or without ``steps``."""
    steps = getattr(objective, "steps", None)
    if steps is None or steps < s.max_steps or not np.isfinite(J):
        return True
    J2 = _j_doubled(objective, K, J)
    return bool(np.isfinite(J2) and abs(J2 - J) <= min(s.resolution_rtol, s.rtol_certify) * J2)


def _j_doubled(objective, K, J: float) -> float:
    """J(K) on twice ``objective.steps`` (the objective's steps are left as they were)."""
    steps = objective.steps
    objective.steps = 2 * steps
    try:
        return float(objective(np.asarray(K)[None], guess=J, spread=1.05)[0])
    finally:
        objective.steps = steps
