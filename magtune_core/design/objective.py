"""The tuning objective J(K) = max over design models of ||G_zTd^sigma(K)||_inf, batched.

Paper eq. (21) for one model; for several models (issue 11: robust tuning over field models)
the worst case over them. Every optimizer of :mod:`magtune_core.design` calls an objective as
``J = objective(Ks)`` with a population ``Ks`` of shape (n, 3, 6) and gets J of shape (n,), so
the evaluation is one batched Riccati gamma-test bisection per model (``ltp.hinfnorm``), not n
separate ones, and is spread over ``workers`` processes when asked.

Conventions (docs/numerics.md, tested in tests/design/test_objective.py):

* a gain whose closed loop is not exponentially stable (max |characteristic multiplier| >= 1
  for any model, paper Theorem 2.1 / eq. 30) gets J = inf; it is screened by the cheap
  monodromy test first, so unstable candidates cost no bisection;
* with a hold constraint (``hold=HoldConstraint(ts, gain_margin)``, design/sampled.py; the default
  of ``magtune tune``) a gain whose sample-and-hold loop at ts is unstable with the gain times
  gain_margin also gets J = inf, screened after the monodromy test and before any bisection;
* J is computed to relative accuracy ``rtol`` (bracket of the bisection) with ``steps`` Magnus
  intervals per period; ``evaluations`` counts gains evaluated (one gain against every model
  counts once), the unit of the benchmarks.

The parts of a population go to the local worker pool or, given an ``executor`` (e.g. a Dask
cluster's, built by ``studies.cluster``), to it; the split is the same for the same number of
parts, and each gain's J does not depend on where it is computed, so a tune on a cluster of N
workers gives the gain of a local ``workers=N`` tune with the same seed. The objective's
constants (models and screens: 7 MB pickled under the default design spec, mostly the held
loops' interval maps) reach each worker once, when it starts (the local pool's initializer;
an executor's ``share``), not with every part: sent with every part they cost ~20 ms of an
~80-ms generation of the tuner (8.9 ms to pickle, 3.9 ms to unpickle, and the pipe; bench/README.md).
"""
from __future__ import annotations

import uuid
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..base.workers import worker_pool
from ..ltp import DEFAULT_STEPS, hinfnorm, spectral_radius
from .model import AttitudeLTP
from .problem import attitude_system, performance_system


def one_thread_per_worker() -> None:
    """Worker initializer: BLAS/OpenMP pools and numba's threads (the compiled gamma-test) use one
    thread per worker process (the workers are the parallelism), and Ctrl-C is left to the parent (a
    tuner keeps its best gain on an interrupt; the workers end when the parent shuts the pool down,
    or with the parent whatever kills it: :func:`magtune_core.base.workers.worker_pool`)."""
    import signal

    import numba
    from threadpoolctl import threadpool_limits

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threadpool_limits(limits=1)
    numba.set_num_threads(1)


#: The constants of the objectives whose pool this worker process belongs to, by key; filled only in
#: pool workers, by :func:`_start_worker` (a read-only cache of what the parent sent at start).
_IN_WORKER: dict = {}


@dataclass(frozen=True)
class _WorkerConstants:
    """Stands for an objective's (models, screens) in a job sent to its local pool: the workers
    received them when they started (:func:`_start_worker`), so a part carries only this key."""

    key: str


def _start_worker(key: str, shared) -> None:
    """Local pool initializer: :func:`one_thread_per_worker`, then keep the objective's constants."""
    one_thread_per_worker()
    _IN_WORKER[key] = shared


def _constants(shared):
    """(models, screens) of a job: as sent, or this worker's copy when a key was sent."""
    return _IN_WORKER[shared.key] if isinstance(shared, _WorkerConstants) else shared


def model_feasible(model: AttitudeLTP, Ks: np.ndarray, steps: int, hold=None) -> np.ndarray:
    """Whether each gain (n, 3, 6) is feasible on one model: the continuous-time closed loop is
    exponentially stable (max |multiplier| < 1, Theorem 2.1) and, with ``hold`` (a screen of this
    model: ``HoldConstraint.screen`` or ``Requirements.screen``), meets the hold and dipole
    requirements. The screen of :func:`model_norms`.

    Parameters
    ----------
    model : AttitudeLTP
        Design model.
    Ks : ndarray (n, 3, 6)
        Gains (any shape with a multiple of 18 entries).
    steps : int
        Magnus intervals per period of the monodromy.
    hold : callable or None
        Screen of this model: Ks (m, 3, 6) -> ndarray of bool (m,); None: stability only.

    Returns
    -------
    ndarray of bool (n,)
        True where J(K) is finite on this model.
    """
    Ks = np.asarray(Ks, dtype=float).reshape(-1, 3, 6)
    if len(Ks) == 0:
        return np.zeros(0, dtype=bool)
    with np.errstate(all="ignore"):
        rho = spectral_radius(attitude_system(model, Ks), steps)
    ok = np.isfinite(rho) & (rho < 1.0)
    if hold is not None and ok.any():
        ok[ok] = hold(Ks[ok])
    return ok


def model_norms(model: AttitudeLTP, sigma: float, Ks: np.ndarray, steps: int, rtol: float,
                guess=None, spread: float | None = None, hold=None) -> np.ndarray:
    """||G_zTd^sigma(K)||_inf for a batch of gains (n, 3, 6) on one model; inf where unstable.

    ``hold`` (a screen of this model, :func:`model_feasible`): gains that fail it are
    infeasible too (inf), screened after the continuous-time test and before any bisection.

    Parameters
    ----------
    model : AttitudeLTP
        Design model.
    sigma : float
        Weight of the torque in z (paper eq. 20).
    Ks : ndarray (n, 3, 6)
        Gains (any shape with a multiple of 18 entries).
    steps : int
        Magnus intervals per period.
    rtol : float
        Relative accuracy of each norm.
    guess : float or array_like (n,) or None
        Starting level of the bisection per gain; non-finite or non-positive entries take the largest usable one.
    spread : float or None
        Expected ratio of the norms to ``guess`` (used only with a guess).
    hold : callable or None
        Screen of this model (see :func:`model_feasible`).

    Returns
    -------
    ndarray (n,)
        The H-inf norm per gain (relative accuracy ``rtol``), inf where the closed loop is unstable.
    """
    Ks = np.asarray(Ks, dtype=float).reshape(-1, 3, 6)
    out = np.full(len(Ks), np.inf)
    if len(Ks) == 0:
        return out
    ok = model_feasible(model, Ks, steps, hold)
    if not ok.any():
        return out
    g = None
    if guess is not None:  # a starting level per gain; unusable entries take the largest usable one
        g = np.broadcast_to(np.asarray(guess, dtype=float), (len(Ks),))[ok]
        good = np.isfinite(g) & (g > 0)
        g = np.where(good, g, g[good].max()) if good.any() else None
    out[ok] = hinfnorm(performance_system(model, Ks[ok], sigma), rtol=rtol, steps=steps, guess=g, grid=1,
                       spread=spread if g is not None else None)
    return out


def _norms_job(shared, sigma, Ks, steps, rtol, guess, spread):
    """Worker body: the (n, n_models) matrix of norms of one slice of the population; ``shared`` =
    (models, their screens or None), the objective's constants (or their key, :func:`_constants`)."""
    models, holds = _constants(shared)
    cols = [model_norms(m, sigma, Ks, steps, rtol, None if guess is None else guess[:, i], spread,
                        None if holds is None else holds[i])
            for i, m in enumerate(models)]
    return np.stack(cols, axis=-1)


def _feasible_job(shared, Ks, steps):
    """Worker body of :meth:`HinfObjective.feasible`: every model's screen, in turn, on the gains
    still feasible (n,)."""
    models, holds = _constants(shared)
    ok = np.ones(len(Ks), dtype=bool)
    for i, m in enumerate(models):
        if ok.any():
            ok[ok] = model_feasible(m, Ks[ok], steps, None if holds is None else holds[i])
    return ok


class HinfObjective:
    """J(K) = max over ``models`` of ||G_zTd^sigma(K)||_inf (paper eq. 21), for batches of gains.

    Parameters
    ----------
    models : AttitudeLTP or sequence of AttitudeLTP
        One design model (paper) or several (robust design: the worst case counts).
    sigma : float
        Control-effort weight of z = [Z x; sigma K x] (paper eq. 20).
    steps : int
        Magnus intervals per period of every norm evaluation.
    rtol : float
        Relative accuracy of each norm (bisection bracket).
    workers : int
        Processes the population is split over (1 = in this process). Workers have their BLAS
        pinned to one thread; use the objective as a context manager or call :meth:`close`.
    hold : HoldConstraint or Requirements, optional
        Hard requirements (design/sampled.py, design/requirements.py): a gain whose sample-and-hold
        loop fails the gain margin (at ``hold.ts``, or at every checked period of a Requirements)
        or, for Requirements, exceeds the dipole budget on any model is infeasible (J = inf), like
        a continuous-time unstable one. None: the paper's problem.
    executor : object, optional
        Where the parts of a population run instead of the local pool: anything with
        ``submit(fn, *args)`` returning a future with ``.result()``, an int ``workers`` (the number
        of parts, replacing ``workers``) and optionally ``share(obj)``, a handle to ``obj`` sent
        once and passed in its place (the models and screens; ``studies.cluster.ClusterExecutor``
        for a Dask cluster). The caller owns it; :meth:`close` leaves it open.

    Calling the objective with ``Ks`` (n, 3, 6) returns J (n,); :meth:`per_model` returns the
    (n, n_models) matrix and :meth:`worst` the index of the model attaining the max.
    """

    def __init__(self, models: AttitudeLTP | Sequence[AttitudeLTP], sigma: float, steps: int = DEFAULT_STEPS,
                 rtol: float = 1e-4, workers: int = 1, hold=None, executor=None):
        self.models = (models,) if isinstance(models, AttitudeLTP) else tuple(models)
        if not self.models:
            raise ValueError("HinfObjective: at least one model is needed")
        self.sigma, self.steps, self.rtol = float(sigma), int(steps), float(rtol)
        self.executor = executor
        self.workers = max(1, int(executor.workers if executor is not None else workers))
        self.evaluations = 0
        self._pool, self._key = None, None
        self.hold = hold
        self._holds = None if hold is None else [hold.screen(m) for m in self.models]
        self._shared = (self.models, self._holds)
        self._remote = None  # the executor's handle of _shared, made on first use

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        """Shut the worker pool down (pending evaluations cancelled)."""
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None
        self._remote = None

    def _get_pool(self):
        """The executor given, else the local pool of ``workers`` processes (started on first use)."""
        if self.executor is not None:
            return self.executor
        if self._pool is None:
            self._key = uuid.uuid4().hex
            self._pool = worker_pool(self.workers, initializer=_start_worker, initargs=(self._key, self._shared))
        return self._pool

    def _shared_handle(self):
        """(models, screens) as the pool's jobs take them: their key for the local pool (each worker
        has them from its start), the executor's handle (sent once) when it shares, else as is."""
        if self.executor is None:
            return _WorkerConstants(self._key)
        share = getattr(self.executor, "share", None)
        if share is None:
            return self._shared
        if self._remote is None:
            self._remote = share(self._shared)
        return self._remote

    def per_model(self, Ks, guess=None, spread: float | None = None, rtol: float | None = None) -> np.ndarray:
        """||G_zTd||_inf of each gain on each model.

        ``guess`` (scalar, (n,) or (n, n_models)) is a starting level for the bisection (e.g. the
        incumbent's J) and ``spread`` how far from it the norms are expected (ratio, e.g. 1.05);
        both only affect speed. ``rtol`` overrides the objective's accuracy for this call (an
        optimizer that only ranks a widely spread population asks for less).

        Parameters
        ----------
        Ks : array_like (n, 3, 6)
            Gains (any shape with a multiple of 18 entries); counted in ``evaluations``.
        guess : float or array_like (n,) or (n, n_models) or None
            Starting level of the bisection.
        spread : float or None
            Expected ratio of the norms to ``guess``.
        rtol : float or None
            Relative accuracy for this call; None: the objective's ``rtol``.

        Returns
        -------
        ndarray (n, n_models)
            The norm per gain and model; inf where that closed loop is unstable.
        """
        Ks = np.asarray(Ks, dtype=float).reshape(-1, 3, 6)
        n, nm = len(Ks), len(self.models)
        self.evaluations += n
        if guess is not None:
            guess = np.broadcast_to(np.asarray(guess, dtype=float).reshape((-1, nm) if np.ndim(guess) == 2 else (-1, 1)),
                                    (n, nm))
        rtol = self.rtol if rtol is None else float(rtol)
        return self._split(n, lambda p, shared: (_norms_job, shared, self.sigma, Ks[p], self.steps, rtol,
                                                 None if guess is None else np.ascontiguousarray(guess[p]), spread))

    def __call__(self, Ks, guess=None, spread: float | None = None, rtol: float | None = None) -> np.ndarray:
        """J per gain: the max over models of the norm (n,); inf where any closed loop is unstable.

        Parameters
        ----------
        Ks : array_like (n, 3, 6)
            Gains.
        guess : float or array_like or None
            Starting level of the bisection (see :meth:`per_model`).
        spread : float or None
            Expected ratio of the norms to ``guess``.
        rtol : float or None
            Relative accuracy for this call; None: the objective's ``rtol``.

        Returns
        -------
        ndarray (n,)
            J(K) for each gain of ``Ks`` (n, 3, 6).
        """
        return self.per_model(Ks, guess, spread, rtol).max(axis=-1)

    def feasible(self, Ks) -> np.ndarray:
        """Whether J(K) is finite, without computing it (stability and hold constraint on every model;
        ~1 ms per gain, no bisection): what the tuner's feasible-range coordinates are measured with
        (``cmaes.feasible_scale``, ~2,000 gains), split over the ``workers`` like :meth:`per_model`.

        Parameters
        ----------
        Ks : array_like (n, 3, 6)
            Gains (any shape with a multiple of 18 entries); not counted in ``evaluations``.

        Returns
        -------
        ndarray of bool (n,)
            True where every model's loop is stable and meets the hold constraint.
        """
        Ks = np.asarray(Ks, dtype=float).reshape(-1, 3, 6)
        return self._split(len(Ks), lambda p, shared: (_feasible_job, shared, Ks[p], self.steps))

    def _split(self, n: int, call) -> np.ndarray:
        """``call(p, shared)`` = (job, *args) for the gains at indices p: run in this process for one
        worker or a small batch, else one part per worker of the pool (or executor); the parts'
        results concatenated (n, ...)."""
        if self.workers == 1 or n < 2 * self.workers:
            job, *args = call(np.arange(n), self._shared)
            return job(*args)
        pool, shared = self._get_pool(), self._shared_handle()
        futs = [pool.submit(*call(p, shared)) for p in np.array_split(np.arange(n), self.workers)]
        return np.concatenate([f.result() for f in futs], axis=0)

    def worst(self, Ks) -> np.ndarray:
        """Index (into ``models``) of the model with the largest norm, per gain (n,).

        Parameters
        ----------
        Ks : array_like (n, 3, 6)
            Gains; their norms are computed (and counted) by :meth:`per_model`.

        Returns
        -------
        ndarray of int (n,)
            argmax over models of the norm (0 for a single model).
        """
        return np.argmax(self.per_model(Ks), axis=-1)
