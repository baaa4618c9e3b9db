"""The torquer watch over batched runs: :class:`~magtune_core.onboard.torquer_watch.TorquerWatch` replayed after the run.

The attitude_estimator node steps the torquer watch on every sample its filter has a state for (``watch_torquers``)
with the gyro minus the estimated bias, the measured field, the dipole commanded one period before, the estimate
w.r.t. the orbital axes and ``active`` (a valid estimate in POINTING or an ACQUISITION after it, a command). The watch only
reports: nothing in the loop reads it. So a batched run records those inputs at every step
(``BatchEstimator(torquer_watch=True)``, :class:`~magtune_core.sim.batch.TorquerInputs`) and :func:`replay` runs the
flight's watch over them afterwards, all runs at once (``TorquerWatch(shape=(B,))``: the flight's arithmetic with a
batch axis), equal to one watch per run (tests/sim/test_batch_torquer.py: the same verdicts at the same samples).

The clock. The watch's sub-windows are counted in the samples it is stepped on, and the node does not step it
before the coarse fix nor between a filter restart and the next fix (a start in eclipse fixes at ~50 s). With
``clock="node"`` (the default) each run's watch steps on its own such samples, as the node: step j of the batch is
the j-th sample with a state of every run (the runs' times differ; a run out of samples steps inactive). With
``clock="run"`` every instant from t = 0 is a step: sub-windows on a common grid, shifted from the node's by the
fix's step modulo ``sub_window`` where the fix is late.

The series are read in chunks of ``chunk`` steps, gathered and made contiguous per step (B, 3): the replay holds
one chunk beyond the recording, plus the per-run index of the samples stepped (4 B per run-step).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..onboard.estimator import FilterModel
from ..onboard.torquer_watch import KINDS, TorquerWatch, TorquerWatchParams, unit_name
from .batch import TorquerInputs

#: Steps replayed per chunk (10 sub-windows of 60 samples).
CHUNK = 600
CLOCKS = ("node", "run")


def watch_params(estimator, p, ts: float, **kw) -> TorquerWatchParams:
    """The node's watch parameters: ``TorquerWatchParams.of_filter`` on the estimator's model and the nominal spacecraft.

    Parameters
    ----------
    estimator : BatchEstimator
        The filter's model of the sensors (``mag_noise_std``, ``gyro_arw``, ``gyro_rrw``, ``sun_noise_std``).
    p : SpacecraftParams
        The run's spacecraft file (what the flight software knows): ``inertia``, ``wheel_momentum``, ``orbit_rate``.
    ts : float
        Control sample period [s].
    **kw
        Other fields of :class:`~magtune_core.onboard.torquer_watch.TorquerWatchParams`.

    Returns
    -------
    TorquerWatchParams
        As the attitude_estimator node builds them.
    """
    model = FilterModel(float(ts), float(estimator.mag_noise_std) ** 2, float(estimator.gyro_arw),
                        float(estimator.gyro_rrw), float(estimator.sun_noise_std))
    return TorquerWatchParams.of_filter(model, p.inertia, p.wheel_momentum, p.orbit_rate, **kw)


@dataclass
class TorquerDetections:
    """The torquer watch's verdicts over B runs (:func:`replay`).

    ``axis`` (B,) the first axis declared (-1: none; two at once: the larger statistic, as ``TorquerWatch.step``),
    ``time`` (B,) its sample's time [s] (nan: none), ``kind`` (B,) the kind the watch names that axis with at the end
    (a first verdict ``fault`` is named later; "" none), ``verdicts`` (B,) every verdict (declarations and kind
    changes, all axes), ``declared`` (B, 3) the declared kind codes at the end (-1: none), ``axis_time`` (B, 3) each
    axis' first declaration [s] (nan: never; a wrong first axis does not hide the right one declared later),
    ``events`` every verdict as (run, instant k, axis, kind code) in the replay's step order, the first of a step the
    larger statistic's.
    """

    axis: np.ndarray
    time: np.ndarray
    kind: np.ndarray
    verdicts: np.ndarray
    declared: np.ndarray
    axis_time: np.ndarray
    events: list = field(default_factory=list)

    def axis_kind(self, run: int, axis: int) -> str:
        """The kind ``axis`` of run ``run`` is declared with at the end.

        Parameters
        ----------
        run : int
            Index in the batch.
        axis : int
            0, 1, 2.

        Returns
        -------
        str
            A name of :data:`~magtune_core.onboard.torquer_watch.KINDS`, or "" when the axis was not declared.
        """
        code = int(self.declared[run, axis])
        return KINDS[code] if code >= 0 else ""

    def unit(self, run: int) -> str:
        """The unit named first in run ``run``.

        Parameters
        ----------
        run : int
            Index in the batch.

        Returns
        -------
        str
            ``torquer x|y|z``, or "" when none was named.
        """
        a = int(self.axis[run])
        return unit_name(a) if a >= 0 else ""


def replay(inputs: TorquerInputs, params: TorquerWatchParams, *, chunk: int = CHUNK,
           clock: str = "node") -> TorquerDetections:
    """Step ``TorquerWatch(params, shape=(B,))`` over the recorded inputs.

    Parameters
    ----------
    inputs : TorquerInputs
        The per-step inputs of B runs (:attr:`magtune_core.sim.batch.BatchResult.torquer_inputs`).
    params : TorquerWatchParams
        The watch's parameters (:func:`watch_params`); its ``ts`` must be the recording's.
    chunk : int
        Steps gathered at once.
    clock : str
        "node": each run's watch steps on its samples with a state, as the node (module docstring); "run": on every
        instant from t = 0.

    Returns
    -------
    TorquerDetections
        First axis, time and kind per run; every verdict.

    Raises
    ------
    ValueError
        A sample period other than the recording's, a chunk below 1 or an unknown clock.
    """
    if abs(params.ts - inputs.ts) > 1e-12 * inputs.ts or chunk < 1 or clock not in CLOCKS:
        raise ValueError(f"replay: params.ts {params.ts:g} s must be the recording's {inputs.ts:g} s, chunk >= 1 (got "
                         f"{chunk}) and clock one of {', '.join(CLOCKS)} (got {clock!r})")
    B, N = inputs.shape
    order = [np.flatnonzero(s).astype(np.int32) for s in inputs.stepped] if clock == "node" else None
    steps = max((o.size for o in order), default=0) if order is not None else N
    watch = TorquerWatch(params, shape=(B,))
    out = TorquerDetections(np.full(B, -1), np.full(B, np.nan), np.full(B, "", dtype=object), np.zeros(B, int),
                            watch.declared, np.full((B, 3), np.nan))
    for j0 in range(0, steps, chunk):
        j1 = min(j0 + chunk, steps)
        if order is None:
            k = np.broadcast_to(np.arange(j0, j1), (B, j1 - j0))
        else:
            k = np.full((B, j1 - j0), -1, dtype=np.int64)
            for r, o in enumerate(order):
                part = o[j0:j1]
                k[r, :part.size] = part
        w, b, m, q, act = _gather(inputs, k)
        for j in range(j1 - j0):
            new = watch.advance(w[j], b[j], m[j], q[j], act[j])
            if new.any():
                _note(out, watch, new, k[:, j], inputs.ts)
    out.declared = watch.declared.copy()
    for r in np.nonzero(out.axis >= 0)[0]:
        out.kind[r] = out.axis_kind(r, int(out.axis[r]))
    return out


def _gather(inputs: TorquerInputs, k: np.ndarray) -> tuple:
    """The inputs at instants ``k`` (B, c) (-1: none, inactive), step-major: (c, B, .) contiguous."""
    rows, kk = np.arange(k.shape[0])[:, None], np.maximum(k, 0)
    w, b, m, q = (np.ascontiguousarray(np.swapaxes(a[rows, kk], 0, 1)) for a in
                  (inputs.w, inputs.b, inputs.m_prev, inputs.q))
    return w, b, m, q, np.ascontiguousarray((inputs.active[rows, kk] & (k >= 0)).T)


def _note(out: TorquerDetections, watch: TorquerWatch, new: np.ndarray, k: np.ndarray, ts: float) -> None:
    """The verdicts of one step (run r at instant k[r]): events (the larger statistic first), first axis and time."""
    for r in np.nonzero(new.any(-1))[0]:
        first = int(np.argmax(np.where(new[r], watch.statistic[r], -np.inf)))
        for a in [first] + [a for a in np.nonzero(new[r])[0] if a != first]:
            out.events.append((int(r), int(k[r]), int(a), int(watch.declared[r, a])))
            if np.isnan(out.axis_time[r, a]):
                out.axis_time[r, a] = int(k[r]) * ts
        out.verdicts[r] += int(new[r].sum())
        if out.axis[r] < 0:
            out.axis[r], out.time[r] = first, int(k[r]) * ts
