"""Tuning and analysis as library calls: start gain, Magnus resolution, optimizer, figures, provenance -> ``Gains``.

``tune_gains(model, sigma)`` is what ``magtune tune`` runs: the start gain and Magnus steps
resolved for the model (:mod:`.resolution`; the paper's LQ start, section 4.2), the CMA-ES tuner
under the sample-and-hold gain-margin constraint (:mod:`.cmaes`, :mod:`.sampled`) or the
paper's randomized algorithm (:mod:`.tuner`, eqs. 23-25), the figures of merit J, c1, c2, rho
(eqs. 20-22, 28-30) at a resolution that resolves them, and the provenance a gains file
carries. ``tune_robust_gains`` does the same for the worst J over a model set
(:mod:`.robust`). Both return a :class:`TuneOutcome`; writing the file is the caller's
(``save_gains``). ``analyze_gains`` recomputes a gain's figures, its sample-and-hold margin and,
if asked, the exact gradient of J (what ``magtune analyze`` prints).

Example (the paper's satellite at sigma = 60, a short paper-method run)::

    from magtune_core.design.model import AttitudeLTP
    from magtune_core.design.params import SpacecraftParams
    from magtune_core.design.pipeline import tune_gains
    from magtune_core.design.tuner import TunerSettings
    out = tune_gains(AttitudeLTP.from_params(SpacecraftParams()), 60.0, method="paper",
                     paper=TunerSettings(samples=20, max_iter=2))
    out.gains.K, out.gains.provenance["J"]
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .cmaes import CmaSettings
from .gains import Gains
from .problem import Figures, cost_gradient, figures
from .resolution import resolved_steps, start_gain
from .sampled import HoldConstraint, SampledLoop, feasible_start, hold_gain_margin, hold_provenance
from .tuner import TunerSettings

#: Magnus steps of the final figures (at least; doubled while J moves, :func:`.resolution.resolved_steps`):
#: ~1e-5 relative for the paper's satellite (bench/README.md).
ANALYSIS_STEPS = 128
METHODS = ("cma", "paper")


class InfeasibleStart(ValueError):
    """The start gain cannot be brought within the hold constraint (a smaller margin or a longer Ts may)."""


@dataclass
class TuneOutcome:
    """A tuned gain with its provenance, and how the run went."""

    gains: Gains           # K, sigma, Ts and the provenance a gains file carries
    result: object         # the optimizer's result (J0, evaluations, seconds, stop, method)
    start: str             # where the search started ("LQ start", "start FILE", ...)
    steps: int             # Magnus steps the search started with
    analysis_steps: int    # Magnus steps of the final figures
    notes: list = field(default_factory=list)  # what the pipeline adjusted on the way (one line each)
    robust: object = None  # robust tuning: the figures of every model (design.robust.RobustFigures)

    @property
    def state(self) -> str:
        """How the search ended, in words (certified, interrupted, budget, unresolved)."""
        return {"certified": "converged", "interrupted": "NOT certified (interrupted: the best gain so far)",
                "unresolved": "NOT certified (no improvement found, but max_steps Magnus steps do not resolve J to "
                              "the certificate's tolerance)"}.get(
            getattr(self.result, "stop", None), "NOT certified (budget reached)")

    @property
    def interrupted(self) -> bool:
        """True when a stop request ended the search early (the best gain so far)."""
        return getattr(self.result, "stop", None) == "interrupted"


def _start(model, sigma: float, start_K, start_name: str | None):
    """Start gain, its label and the Magnus steps that resolve it (:mod:`.resolution`)."""
    try:
        K0, sigma0, steps, _ = start_gain(model, sigma)
    except ValueError as exc:
        raise ValueError(f"{exc}; try a larger --sigma") from None
    label = "LQ start" if sigma0 == sigma else f"LQ start of sigma {sigma0:g}"
    if start_K is not None:
        K0, label = np.asarray(start_K, dtype=float).reshape(3, 6), f"start {start_name or 'gain'}"
        steps, _ = resolved_steps(model, K0, sigma)
    return K0, label, steps


def _run_paper(model, sigma, K0, steps, *, seed, workers, paper: TunerSettings, progress):
    from .tuner import tune

    settings = replace(paper or TunerSettings(), workers=workers, steps=steps)
    return tune(model, sigma, seed=seed, settings=settings, K0=K0, progress=progress)


def _run_cma(model, sigma, K0, steps, *, seed, workers, cma: CmaSettings, hold, progress, notes):
    from .cmaes import tune_cma
    from .objective import HinfObjective

    settings = replace(cma or CmaSettings(), workers=workers, steps=steps)
    with HinfObjective(model, sigma, steps=settings.steps, rtol=settings.rtol, workers=workers, hold=hold) as obj:
        res = tune_cma(obj, K0, sigma, seed=seed, settings=settings, progress=progress)
    if obj.steps != steps:
        notes.append(f"the gains stiffened beyond {steps} Magnus steps; tuned on {obj.steps} (resolution watch)")
    return res


def tune_gains(model, sigma: float, *, method: str = "cma", seed: int = 0, start_K=None, start_name: str | None = None,
               workers: int = 1, ts: float = 1.0, gain_margin: float = 2.0, cma: CmaSettings | None = None,
               paper: TunerSettings | None = None, progress=None) -> TuneOutcome:
    """H-infinity tuning of K for one sigma on ``model`` (an ``AttitudeLTP``).

    ``method`` "cma" (CMA-ES to a certified optimum, under the hold constraint of ``ts`` /
    ``gain_margin`` when ``gain_margin`` >= 1; 0: none) or "paper" (the randomized algorithm of
    paper 4.2, no constraint); ``start_K``: start from this gain instead of the LQ gain of the
    averaged model; ``progress``: the optimizer's callback (raise KeyboardInterrupt in it to stop
    with the best gain so far).

    Returns
    -------
    TuneOutcome
        ``gains`` (K, sigma, ``ts``, provenance: J, c1, c2, rho of eqs. 20-22 at
        ``analysis_steps`` Magnus steps, the optimizer's record, the start, the hold margin).
        Raises ValueError when no start gain stabilizes the model, :class:`InfeasibleStart`
        when the start cannot meet the constraint.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    K0, label, steps = _start(model, sigma, start_K, start_name)
    notes: list = []
    if method == "paper":
        res = _run_paper(model, sigma, K0, steps, seed=seed, workers=workers, paper=paper, progress=progress)
    else:
        hold = HoldConstraint(ts, gain_margin) if gain_margin else None
        if hold is not None:
            try:
                K0, note = feasible_start(model, K0, hold)
            except ValueError as exc:  # a start far beyond the margin
                raise InfeasibleStart(str(exc)) from None
            if note:
                label += f", {note}"
                notes.append(f"start gain {note} to meet --gain-margin {hold.gain_margin:g} at --ts {hold.ts:g}")
        res = _run_cma(model, sigma, K0, steps, seed=seed, workers=workers, cma=cma, hold=hold, progress=progress,
                       notes=notes)
    analysis_steps, _ = resolved_steps(model, res.K, sigma, ANALYSIS_STEPS)
    fig = figures(model, res.K, sigma, steps=analysis_steps)
    prov = {**fig.as_dict(), **res.provenance(), "start": label, "design_field": model.field.name,
            "analysis_steps": analysis_steps, "tune_seconds": round(res.seconds, 1)}
    prov.pop("stable", None)
    prov.update(hold_provenance(model, res.K, ts, gain_margin if method == "cma" else 0.0))
    return TuneOutcome(Gains(res.K, sigma, ts, prov), res, label, steps, analysis_steps, notes)


def tune_robust_gains(model, models, sigma: float, *, seed: int = 0, start_K=None, start_name: str | None = None,
                      workers: int = 1, ts: float = 1.0, gain_margin: float = 2.0, cma: CmaSettings | None = None,
                      spec_name: str = "") -> TuneOutcome:
    """Robust tuning: minimize the worst J over ``models`` (``design.robust.model_set`` of a
    robust spec; ``model``: the nominal one) with the CMA-ES tuner (:func:`magtune_core.design.robust.tune_robust`).

    Returns
    -------
    TuneOutcome
        ``gains`` with the nominal figures, the worst model's (``worst_*``) and the spec's name
        in the provenance; ``result.J0`` is the start's worst J.
    """
    from .robust import robust_figures, tune_robust

    settings = replace(cma or CmaSettings(), workers=workers)
    K0 = None if start_K is None else np.asarray(start_K, dtype=float).reshape(3, 6)
    hold = HoldConstraint(ts, gain_margin) if gain_margin else None
    res, sigma0, steps = tune_robust(models, sigma, seed=seed, settings=settings, K0=K0, hold=hold)
    analysis_steps, _ = resolved_steps([m.model for m in models], res.K, sigma, ANALYSIS_STEPS)
    rf = robust_figures(models, res.K, sigma, steps=analysis_steps)
    nom, worst = rf.nominal(), rf.worst()
    prov = {**(nom.as_dict() if nom else {}), **res.provenance(), "design_field": model.field.name,
            "analysis_steps": analysis_steps, "tune_seconds": round(res.seconds, 1),
            "robust_spec": str(spec_name), "robust_models": len(models), "robust_worst_model": rf.worst_name,
            **{f"worst_{k}": v for k, v in worst.items()}}
    prov.pop("stable", None)
    prov.update(hold_provenance(model, res.K, ts, gain_margin))
    label = "LQ start"
    if start_K is not None:
        label = prov["start"] = str(start_name or "gain")
    elif sigma0 != sigma:
        label = prov["start"] = f"LQ of sigma {sigma0:g} (the LQ gain of sigma {sigma:g} does not stabilize every model)"
    return TuneOutcome(Gains(res.K, sigma, ts, prov), res, label, steps, analysis_steps, robust=rf)


@dataclass
class Analysis:
    """A gain's figures recomputed (:func:`analyze_gains`)."""

    figures: Figures               # J, c1, c2, rho (paper eqs. 21, 28-30), stable
    steps: int                     # Magnus steps they were computed with
    hold_gain_margin: float        # sample-and-hold gain margin at the gains' Ts (0: unstable when held)
    sensitivity: dict | None = None  # :func:`sensitivity`, when asked for and the loop is stable


def analyze_gains(model, gains: Gains, *, steps: int | None = None, sensitivity: bool = False) -> Analysis:
    """J, c1, c2, rho of ``gains`` on ``model`` at ``steps`` Magnus steps (default: ANALYSIS_STEPS,
    doubled until J is resolved, :func:`.resolution.resolved_steps`), the hold gain margin at the
    gains' Ts (:func:`.sampled.hold_gain_margin`, paper section 5) and optionally the gradient.

    Returns
    -------
    Analysis
        the figures, the steps used, the margin and the sensitivity (None unless asked for and stable).
    """
    steps = steps or resolved_steps(model, gains.K, gains.sigma, ANALYSIS_STEPS)[0]
    fig = figures(model, gains.K, gains.sigma, steps=steps)
    margin = hold_gain_margin(SampledLoop.build(model, gains.ts), gains.K)
    sens = gain_sensitivity(model, gains, steps) if sensitivity and fig.stable else None
    return Analysis(fig, steps, margin, sens)


def gain_sensitivity(model, gains: Gains, steps: int) -> dict:
    """Exact dJ/dK (:func:`.problem.cost_gradient`) and the worst-case disturbance frequency.

    Returns
    -------
    dict
        ``dJ_dK`` (3 x 6), ``elasticity`` K_ij dJ/dK_ij / J, ``worst_multiplier_angle`` [rad],
        ``worst_frequency_mod_orbit`` [rad/s] and ``orbit_rate`` [rad/s]. Raises ArithmeticError,
        ValueError or LinAlgError when the gradient cannot be computed (e.g. a flow not finite at the norm).
    """
    J, dK, grad = cost_gradient(model, gains.K, gains.sigma, steps=steps)
    angle = float(abs(np.angle(grad.multipliers).mean()))
    return {"dJ_dK": dK.tolist(), "elasticity": (np.asarray(gains.K).reshape(3, 6) * dK / J).tolist(),
            "worst_multiplier_angle": angle, "worst_frequency_mod_orbit": angle / model.period,
            "orbit_rate": 2.0 * math.pi / model.period}
