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

``tune_gains``: ``method`` "cma" (CMA-ES to a certified optimum under hard requirements) or
"paper" (the randomized algorithm of paper 4.2, no constraint). The hard requirements are
``requirements`` (a design spec, :mod:`.requirements`: hold margin over a sample-period range,
dipole budget; the gains' Ts is its ts_min) or, without one, the hold constraint of ``ts`` /
``gain_margin`` (``gain_margin`` 0: none, the paper's unconstrained problem). ``start_K``: start
from this gain instead of the LQ gain of the averaged model; ``progress``: the optimizer's
callback (raise KeyboardInterrupt in it to stop with the best gain so far). ``executor``: where
the CMA-ES candidates are evaluated instead of ``workers`` local processes (e.g. a Dask
cluster's, :class:`.objective.HinfObjective`); the same gain as ``workers`` = its number of parts.

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

from ..onboard.params import TS_DEFAULT
from .cmaes import CmaSettings
from .gains import Gains
from .problem import Figures, cost_gradient, figures
from .requirements import Requirements, scan_hold
from .resolution import resolved_steps, start_gain
from .sampled import HoldConstraint, SampledLoop, feasible_start, hold_gain_margin, hold_provenance
from .tuner import TunerSettings

#: Rounds after the first search: a period failing the quick scan, or the (period, scale) points a failing hold
#: certificate found, are added to the checked set and the search resumed.
SCAN_ROUNDS = 4
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
        """How the search ended, in words (certified, interrupted, budget, unresolved).

        Returns
        -------
        str
            "converged" for a certified stop, else "NOT certified (...)" with the reason.
        """
        return {"certified": "converged", "interrupted": "NOT certified (interrupted: the best gain so far)",
                "unresolved": "NOT certified (no improvement found, but max_steps Magnus steps do not resolve J to "
                              "the certificate's tolerance)"}.get(
            getattr(self.result, "stop", None), "NOT certified (budget reached)")

    @property
    def interrupted(self) -> bool:
        """True when a stop request ended the search early (the best gain so far).

        Returns
        -------
        bool
            True if the optimizer's ``stop`` is "interrupted".
        """
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


def _run_cma(model, sigma, K0, steps, *, seed, workers, cma: CmaSettings, hold, progress, notes, executor=None):
    from .cmaes import tune_cma
    from .objective import HinfObjective

    settings = replace(cma or CmaSettings(), workers=workers, steps=steps)
    with HinfObjective(model, sigma, steps=settings.steps, rtol=settings.rtol, workers=workers, hold=hold,
                       executor=executor) as obj:
        res = tune_cma(obj, K0, sigma, seed=seed, settings=settings, progress=progress)
    if obj.steps != steps:
        notes.append(f"the gains stiffened beyond {steps} Magnus steps; tuned on {obj.steps} (resolution watch)")
    return res


def tune_gains(model, sigma: float, *, method: str = "cma", seed: int = 0, start_K=None, start_name: str | None = None,
               workers: int = 1, ts: float = TS_DEFAULT, gain_margin: float = 2.0, cma: CmaSettings | None = None,
               paper: TunerSettings | None = None, progress=None, requirements: Requirements | None = None,
               executor=None) -> TuneOutcome:
    """H-infinity tuning of K for one sigma on ``model`` (an ``AttitudeLTP``).

    The hard requirements are ``requirements`` or, without one, the hold constraint of ``ts`` /
    ``gain_margin`` (module docstring).

    Parameters
    ----------
    model : AttitudeLTP
        Design model.
    sigma : float
        Weight of the torque in z (paper eq. 20).
    method : str
        "cma" (CMA-ES to a certified optimum under hard requirements) or "paper" (paper 4.2, no constraint).
    seed : int
        Seed of the optimizer.
    start_K : array_like (3, 6) or None
        Start gain instead of the LQ gain of the averaged model.
    start_name : str or None
        Name of ``start_K`` in the start's label ("start <name>").
    workers : int
        Local processes evaluating the candidates.
    ts : float
        Gains' sample period [s] and Ts of the hold constraint (without ``requirements``).
    gain_margin : float
        Hold gain margin without ``requirements`` (0: none, the paper's unconstrained problem).
    cma : CmaSettings or None
        CMA-ES settings (method "cma"); None: defaults.
    paper : TunerSettings or None
        Settings of the paper's tuner (method "paper"); None: defaults.
    progress : callable or None
        Optimizer callback; raise KeyboardInterrupt in it to stop with the best gain so far.
    requirements : Requirements or None
        Design spec (hold margin over a Ts range, dipole budget); its ts_min is the gains' Ts.
    executor : object or None
        Where the CMA-ES candidates are evaluated instead of ``workers`` (:class:`.objective.HinfObjective`).

    Returns
    -------
    TuneOutcome
        ``gains`` (K, sigma, Ts, provenance: J, c1, c2, rho of eqs. 20-22 at ``analysis_steps``
        Magnus steps, the optimizer's record, the start, the requirements and their values).

    Raises
    ------
    ValueError
        If ``method`` is unknown, an executor is given with method "paper", or no start gain stabilizes the model.
    InfeasibleStart
        If the start cannot meet the requirements (the message names the binding requirement).
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    cert = None
    if executor is not None and method != "cma":
        raise ValueError("an executor evaluates CMA-ES candidates only (method 'cma')")
    if requirements is not None:
        ts, gain_margin = requirements.ts, requirements.gain_margin
    K0, label, steps = _start(model, sigma, start_K, start_name)
    notes: list = []
    loops: dict = {}  # the dense scans' held loops, built once (cutting planes, then the provenance)
    if method == "paper":
        res = _run_paper(model, sigma, K0, steps, seed=seed, workers=workers, paper=paper, progress=progress)
    else:
        hold = requirements if requirements is not None and requirements.constrained else (
            HoldConstraint(ts, gain_margin) if gain_margin and requirements is None else None)
        res, steps, cert = _constrained_search(model, sigma, K0, label, steps, hold, seed=seed, workers=workers,
                                               cma=cma, progress=progress, notes=notes, executor=executor, cache=loops)
        label = notes.pop(0)
    analysis_steps, prov = _tuned_provenance(model, sigma, res, label, method, requirements, cert, ts, gain_margin)
    return TuneOutcome(Gains(res.K, sigma, ts, prov), res, label, steps, analysis_steps, notes)


def _tuned_provenance(model, sigma, res, label, method, requirements, cert, ts, gain_margin):
    """(analysis steps, provenance) of a tuned gain: its figures at resolved steps, the optimizer's record, and
    the requirement figures with the hold certificate (under a design spec) or the margin at ``ts``."""
    analysis_steps, _ = resolved_steps(model, res.K, sigma, ANALYSIS_STEPS)
    fig = figures(model, res.K, sigma, steps=analysis_steps)
    prov = {**fig.as_dict(), **res.provenance(), "start": label, "design_field": model.field.name,
            "analysis_steps": analysis_steps, "tune_seconds": round(res.seconds, 1)}
    prov.pop("stable", None)
    if requirements is not None and method == "cma":  # the certificate says what holds over the range
        prov.update(requirement_provenance(model, res.K, requirements, certificate=cert,
                                           certify=getattr(res, "stop", None) != "interrupted"))
    else:
        prov.update(hold_provenance(model, res.K, ts, gain_margin if method == "cma" else 0.0))
    return analysis_steps, prov


def _constrained_search(model, sigma, K0, label, steps, hold, *, seed, workers, cma, progress, notes, executor=None,
                        cache=None):
    """CMA-ES under ``hold``; with a design spec, the final gain's dense sample-period scan adds
    any failing period to the checked set and resumes from the gain (at most SCAN_ROUNDS times).
    The start's label goes first in ``notes``."""
    seconds = evaluations = 0
    J0 = cert = None
    for round_ in range(SCAN_ROUNDS + 1):
        if hold is not None:
            try:
                K0, note = feasible_start(model, K0, hold)
            except ValueError as exc:  # no scaling is feasible: phase 1, else the binding requirement
                K0, note = _restored_start(model, K0, hold, seed, str(exc))
            if note and round_ == 0:
                label += f", {note}"
                notes.append(f"start gain {note} to meet " + (hold.describe() if hasattr(hold, "describe") else
                             f"--gain-margin {hold.gain_margin:g} at --ts {hold.ts:g}"))
        res = _run_cma(model, sigma, K0, steps, seed=seed + round_, workers=workers, cma=cma, hold=hold,
                       progress=progress, notes=notes, executor=executor)
        seconds, evaluations = seconds + res.seconds, evaluations + res.evaluations
        J0 = res.J0 if J0 is None else J0
        if not isinstance(hold, Requirements) or not hold.gain_margin or res.stop == "interrupted":
            break
        K0 = res.K
        periods, ok = scan_hold(model, res.K, hold, cache=cache)  # quick: ~100 periods, the margin's two ends
        if not ok.all():
            hold = hold.with_periods(periods[~ok])
            notes.append(f"dense scan: the gain fails the hold margin at Ts = "
                         f"{', '.join(f'{t:.4g}' for t in periods[~ok])} s; added to the checked periods, search resumed")
            continue
        try:
            cert = hold.certify(model, res.K, workers=max(1, workers))
        except KeyboardInterrupt:  # a stop request during the certificate: the gain, uncertified
            res.stop = "interrupted"
            break
        if cert.met or round_ == SCAN_ROUNDS:
            break
        hold = hold.with_points(cert.unstable)
        notes.append(f"hold certificate: unstable at {len(cert.unstable)} (period, scale) points, the first at "
                     f"Ts = {cert.unstable[0][0]:.4g} s, {cert.unstable[0][1]:.4g} x K; added to the checked points, "
                     "search resumed")
    res.seconds, res.evaluations, res.J0 = seconds, evaluations, J0
    notes.insert(0, label)
    return res, steps, cert


def _restored_start(model, K0, hold, seed: int, reason: str):
    """A feasible start by phase 1 (:func:`.feasibility.restore`) when no scaling of ``K0`` meets a
    design spec; InfeasibleStart naming the binding requirement when phase 1 fails too."""
    if isinstance(hold, Requirements):
        from .feasibility import restore

        K, evals = restore([hold.screen(model)], K0, seed=seed)
        if K is not None:
            return K, f"moved to feasibility by phase 1 ({evals} evaluations of the requirements' violation)"
    raise InfeasibleStart(binding_message(model, K0, hold, reason))


def binding_message(model, K0, req, reason: str) -> str:
    """Which hard requirement keeps the start gain's scalings infeasible, and by how much: the best
    value each requirement reaches over the scalings 10^(0..-2) of ``K0`` (a Requirements; other
    constraints: ``reason`` as is).

    Parameters
    ----------
    model : AttitudeLTP
        Design model.
    K0 : array_like (3, 6)
        Start gain.
    req : Requirements or HoldConstraint
        The hard requirements the start failed.
    reason : str
        Why no scaling was feasible (the message of :func:`.sampled.feasible_start`).

    Returns
    -------
    str
        ``reason``, followed for a Requirements by the (at most two) most violated requirements at their best scaling.
    """
    if not isinstance(req, Requirements):
        return reason
    screen = req.screen(model)
    best: dict = {}
    for f in np.geomspace(1.0, 0.01, 13):
        for c in screen.checks(f * np.asarray(K0).reshape(3, 6)):
            key = c.name.split(" at ")[0] if c.kind == "<=" else c.name
            if key not in best or c.slack > best[key][0].slack:
                best[key] = (c, f)
    bind = sorted(((c, f) for c, f in best.values() if not c.ok), key=lambda cf: cf[0].slack)
    if not bind:
        return reason

    def words(c, f):
        if c.kind == ">=" and c.value == 0:
            return f"{c.name}: the held loop is unstable at every scaling (needs a margin >= {c.limit:g})"
        return f"{c.name}: at best {c.value:.4g} (needs {c.kind} {c.limit:.4g}, {-c.slack:.0%} short, at {f:.3g} x the start gain)"

    more = f"; {len(bind) - 2} more" if len(bind) > 2 else ""
    return f"{reason}; binding: " + "; ".join(words(c, f) for c, f in bind[:2]) + more


def requirement_provenance(model, K, req: Requirements, certificate=None, certify: bool = True) -> dict:
    """What a gains file records about its requirements: the spec in one line, the hold certificate's
    figures (:mod:`.hold_certificate`: the certified margin and its period, where ``verify`` also flies,
    the largest multiplier over the certified grid, rho(K)), the peak-dipole proxy, and whether every
    requirement holds.

    Parameters
    ----------
    model : AttitudeLTP
        Design model.
    K : array_like (3, 6)
        Gain.
    req : Requirements
        The design spec.
    certificate : HoldCertificate or None
        The gain's certificate when already computed; None: computed here (every admissible period).
    certify : bool
        False: no certificate (an interrupted tune), so the hold requirement is not claimed met.

    Returns
    -------
    dict
        ``requirements`` (one line), ``requirements_met`` (bool: the certificate holds and the dipole
        proxy is within the budget), the certificate's keys (:meth:`.hold_certificate.HoldCertificate.provenance`)
        when a hold margin is required, ``hold_gain_margin_required``, ``dipole_peak_proxy`` [A m^2] and
        ``dipole_budget``; also ``requirements_source`` and ``hold_ts_range`` [s].
    """
    screen = req.screen(model)
    checks = [c for c in screen.checks(K, hold=False) if c.name.startswith("peak |m_")]
    peak = max((c.value for c in checks), default=float("nan"))
    out = {"requirements": req.describe(), "requirements_source": req.source,
           "hold_gain_margin_required": float(req.gain_margin)}
    held_ok = True
    if req.gain_margin and (certify or certificate is not None):
        cert = certificate if certificate is not None else req.certify(model, K)
        out.update(cert.provenance())
        held_ok = cert.met
    elif req.gain_margin:
        held_ok = False
    met = bool(held_ok and (not req.dipole_budget or peak <= req.dipole_budget))
    out.update({"requirements_met": met, "hold_ts_range": [float(req.sampling["ts_min"]), float(req.sampling["ts_max"])],
                "dipole_peak_proxy": round(float(peak), 3), "dipole_budget": round(req.dipole_budget, 3)})
    return out


def requirement_lines(prov: dict, gain_margin: float) -> list:
    """Each hard requirement of a gain in one line, with how far it is from failing (what ``tune`` and
    ``analyze --requirements`` print).

    Parameters
    ----------
    prov : dict
        :func:`requirement_provenance` of the gain (or a gains file's provenance holding its keys).
    gain_margin : float
        The requirement's gain margin (factor; 0: no hold requirement).

    Returns
    -------
    list of str
        The hold certificate's lines (when a margin is required) and the dipole budget's.
    """
    out = []
    cert = prov.get("hold_certificate")
    if gain_margin and cert:
        margin, top = float(prov["hold_margin_min"]), float(cert["scale_top"])
        span = (f"{cert['periods']} admissible periods {cert['ts_first']:.4g}-{cert['ts_last']:.4g} s, "
                f"k step {cert['scale_step']:g}")
        if margin >= top:
            out.append(f"hold margin: held loop stable for every k in [1, {top:g}] x K ({gain_margin:g} + "
                       f"{cert['guard']:.1%} guard) at all {span}; largest multiplier on that grid "
                       f"{prov['hold_rho_max']:.3g} (1 fails), at Ts = {prov['hold_tightest_ts']:g} s")
        else:
            out.append(f"hold margin: FAILS: stable up to {margin:g} x K only (needs [1, {top:g}]), first unstable at "
                       f"Ts = {prov['hold_tightest_ts']:g} s; checked {span}")
        out.append(f"held loop with K: largest multiplier {prov['hold_multiplier_max']:.3g} per orbit at "
                   f"Ts = {prov['hold_multiplier_ts']:g} s; certificate computed in {cert['seconds']:g} s")
    budget = prov.get("dipole_budget")
    if budget:
        peak = float(prov["dipole_peak_proxy"])
        out.append(f"dipole: peak proxy {peak:.4g} of {float(budget):.4g} A m^2 "
                   + (f"({1 - peak / float(budget):.0%} to spare)" if peak <= float(budget) else "(FAILS)"))
    return out


def tune_robust_gains(model, models, sigma: float, *, seed: int = 0, start_K=None, start_name: str | None = None,
                      workers: int = 1, ts: float = TS_DEFAULT, gain_margin: float = 2.0, cma: CmaSettings | None = None,
                      spec_name: str = "", requirements: Requirements | None = None, executor=None) -> TuneOutcome:
    """Robust tuning: minimize the worst J over ``models`` (``design.robust.model_set`` of a
    robust spec; ``model``: the nominal one) with the CMA-ES tuner (:func:`magtune_core.design.robust.tune_robust`);
    ``executor`` as in :func:`tune_gains`.

    Parameters
    ----------
    model : AttitudeLTP
        Nominal design model (design field, hold margin and requirement provenance).
    models : sequence of NamedModel
        The model set.
    sigma : float
        Weight of the torque in z (paper eq. 20).
    seed : int
        Seed of the tuner.
    start_K : array_like (3, 6) or None
        Start gain; None: the LQ start resolved on the set.
    start_name : str or None
        Label of ``start_K`` in the provenance.
    workers : int
        Local processes evaluating the candidates.
    ts : float
        Gains' sample period [s] and Ts of the hold constraint (without ``requirements``).
    gain_margin : float
        Hold gain margin without ``requirements`` (0: none).
    cma : CmaSettings or None
        CMA-ES settings; None: defaults.
    spec_name : str
        Name of the robust spec recorded in the provenance.
    requirements : Requirements or None
        Design spec every model must meet.
    executor : object or None
        Where the candidates are evaluated instead of ``workers``.

    Returns
    -------
    TuneOutcome
        ``gains`` with the nominal figures, the worst model's (``worst_*``) and the spec's name
        in the provenance; ``result.J0`` is the start's worst J.

    Raises
    ------
    ValueError
        From :func:`~magtune_core.design.robust.tune_robust` when no start stabilizes every model or meets the hold.
    """
    from .robust import robust_figures, tune_robust

    settings = replace(cma or CmaSettings(), workers=workers)
    K0 = None if start_K is None else np.asarray(start_K, dtype=float).reshape(3, 6)
    hold = HoldConstraint(ts, gain_margin) if gain_margin else None
    if requirements is not None:  # every model of the set meets the spec's checked periods and budget
        ts, gain_margin = requirements.ts, requirements.gain_margin
        hold = requirements if requirements.constrained else None
    res, sigma0, steps = tune_robust(models, sigma, seed=seed, settings=settings, K0=K0, hold=hold, executor=executor)
    analysis_steps, _ = resolved_steps([m.model for m in models], res.K, sigma, ANALYSIS_STEPS)
    rf = robust_figures(models, res.K, sigma, steps=analysis_steps)
    nom, worst = rf.nominal(), rf.worst()
    prov = {**(nom.as_dict() if nom else {}), **res.provenance(), "design_field": model.field.name,
            "analysis_steps": analysis_steps, "tune_seconds": round(res.seconds, 1),
            "robust_spec": str(spec_name), "robust_models": len(models), "robust_worst_model": rf.worst_name,
            **{f"worst_{k}": v for k, v in worst.items()}}
    prov.pop("stable", None)
    if requirements is not None:
        prov.update(requirement_provenance(model, res.K, requirements))
    else:
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

    Parameters
    ----------
    model : AttitudeLTP
        Design model.
    gains : Gains
        K, sigma and Ts to analyze.
    steps : int or None
        Magnus intervals per period; None: resolved from ANALYSIS_STEPS.
    sensitivity : bool
        Also compute :func:`gain_sensitivity` (when the loop is stable).

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

    Parameters
    ----------
    model : AttitudeLTP
        Design model.
    gains : Gains
        K and sigma.
    steps : int
        Magnus intervals per period.

    Returns
    -------
    dict
        ``dJ_dK`` (3 x 6), ``elasticity`` K_ij dJ/dK_ij / J, ``worst_multiplier_angle`` [rad],
        ``worst_frequency_mod_orbit`` [rad/s] and ``orbit_rate`` [rad/s].

    Raises
    ------
    ArithmeticError, ValueError or LinAlgError
        When the gradient cannot be computed (e.g. a flow not finite at the norm).
    """
    J, dK, grad = cost_gradient(model, gains.K, gains.sigma, steps=steps)
    angle = float(abs(np.angle(grad.multipliers).mean()))
    return {"dJ_dK": dK.tolist(), "elasticity": (np.asarray(gains.K).reshape(3, 6) * dK / J).tolist(),
            "worst_multiplier_angle": angle, "worst_frequency_mod_orbit": angle / model.period,
            "orbit_rate": 2.0 * math.pi / model.period}
