"""The requirement front: what a longer sample period or a smaller torquer costs in J.

``magtune front --over ts_max|dipole_limit --levels ...`` (:mod:`magtune_core.cli.front`) tunes
one gain per (sigma, level) under the design spec with one requirement moved to that level (the
longest sample period the hold gain margin must cover, or the torquers' per-axis dipole limit,
of which the budget is the spec's ``budget_fraction``), and reports J (eq. 21), c1 (eq. 28),
c2 (eq. 29), the smallest hold margin of the dense scan and the peak-dipole proxy. A level whose
requirements no start gain can meet is recorded with the binding requirement, not skipped.

Continuation in the level: the levels of a sigma are tuned from the hardest (longest Ts_max,
smallest dipole limit) to the loosest, each started from the better (lower J once scaled into
the level's requirements) of the harder level's optimum (feasible for the looser level by
construction) and the ``starts`` of that sigma (e.g. the shipped gains); the LQ gain where
neither can be scaled into them. The reference gains (the paper-method gains) are evaluated at every level:
their J, c1, c2 do not depend on it; whether they meet the level's requirements does.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..base.atomic import atomic_savefig
from ..design.cmaes import CmaSettings
from ..design.pipeline import InfeasibleStart, requirement_provenance, tune_gains
from ..design.problem import figures
from ..design.requirements import Requirements
from ..design.resolution import resolved_steps
from ..design.sampled import feasible_start
from .front import PAPER_TABLE1

#: The requirement axes a front can be drawn over, and their unit.
AXES = {"ts_max": "s", "dipole_limit": "A m^2"}
#: Default levels (issue 29: the nutation limit of the paper's satellite is 38 s).
DEFAULT_LEVELS = {"ts_max": (1, 2, 5, 10, 20, 30, 35), "dipole_limit": (10, 20, 30, 40, 50)}
DEFAULT_SIGMAS = (60, 120, 240)


def at_level(req: Requirements, axis: str, level: float) -> Requirements:
    """``req`` with one requirement moved: ``ts_max`` [s] (not below ts_min) or ``dipole_limit`` [A m^2].

    Returns
    -------
    Requirements
        A copy; the spec's other values unchanged.
    """
    if axis == "ts_max":
        return replace(req, sampling={**req.sampling, "ts_max": max(float(level), req.ts)}, extra_periods=())
    if axis == "dipole_limit":
        return replace(req, dipole_limit=float(level), extra_periods=())
    raise ValueError(f"axis must be one of {', '.join(AXES)}, got {axis!r}")


def hardest_first(axis: str, levels) -> list[float]:
    """The levels in continuation order: longest Ts_max first, smallest dipole limit first."""
    return sorted((float(v) for v in levels), reverse=axis == "ts_max")


@dataclass
class LevelPoint:
    """One (sigma, level) of the front: the tuned (or reference) gain and its figures."""

    sigma: float
    level: float
    label: str               # "tuned" or the reference's name
    K: np.ndarray | None     # None: infeasible
    J: float = float("nan")
    c1: float = float("nan")
    c2: float = float("nan")
    hold_margin_min: float = float("nan")
    dipole_peak: float = float("nan")
    met: bool = False        # every hard requirement of the level holds (dense scan, dipole proxy)
    certified: bool = False
    evaluations: int = 0
    seconds: float = 0.0
    note: str = ""           # the tuner's stop reason, or the binding requirement when infeasible

    def as_dict(self) -> dict:
        d = {k: getattr(self, k) for k in ("sigma", "level", "label", "J", "c1", "c2", "hold_margin_min",
                                           "dipole_peak", "met", "certified", "evaluations", "note")}
        d["seconds"] = round(self.seconds, 1)
        d["gain"] = None if self.K is None else [float(v) for v in self.K.ravel()]
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in d.items()}


    @classmethod
    def from_dict(cls, d: dict) -> "LevelPoint":
        """The point of :meth:`as_dict` (a partial front's record, for ``--resume``)."""
        nan = float("nan")
        K = None if d.get("gain") is None else np.asarray(d["gain"], dtype=float).reshape(3, 6)
        return cls(float(d["sigma"]), float(d["level"]), d["label"], K,
                   *(nan if d.get(k) is None else float(d[k]) for k in ("J", "c1", "c2", "hold_margin_min",
                                                                        "dipole_peak")),
                   bool(d["met"]), bool(d["certified"]), int(d["evaluations"]), float(d["seconds"]), d["note"])


def evaluate(model, K, sigma: float, req: Requirements, label: str, level: float) -> LevelPoint:
    """A gain's figures at ``sigma`` and its requirement values under ``req`` (no tuning).

    Returns
    -------
    LevelPoint
        J, c1, c2 at a resolved Magnus grid; the dense-scan hold margin and dipole proxy.
    """
    K = np.asarray(K, dtype=float).reshape(3, 6)
    f = figures(model, K, sigma, steps=resolved_steps(model, K, sigma, 128)[0])
    r = requirement_provenance(model, K, req)
    return LevelPoint(sigma, level, label, K, f.J, f.c1, f.c2, r["hold_margin_min"], r["dipole_peak_proxy"],
                      bool(r["requirements_met"]))


def best_start(model, sigma: float, req: Requirements, candidates) -> tuple:
    """The candidate start (name, K) of lowest J once scaled into ``req`` (``feasible_start``);
    (None, None) when none can be (the tuner then starts from the LQ gain).

    Returns
    -------
    (str or None, ndarray (3, 6) or None)
    """
    best = (None, None, np.inf)
    for name, K in candidates:
        try:
            Kf, _ = feasible_start(model, K, req)
        except ValueError:
            continue
        J = resolved_steps(model, Kf, sigma)[1]
        if J < best[2]:
            best = (name, Kf, J)
    return best[0], best[1]


def run_level_front(model, req: Requirements, axis: str, levels, sigmas=DEFAULT_SIGMAS, *,
                    settings: CmaSettings | None = None, seed: int = 0, workers: int = 1, starts=None,
                    references=None, progress=None, executor=None, done=()) -> list[LevelPoint]:
    """Tune every (sigma, level) under ``req`` moved along ``axis`` (module docstring).

    ``starts``: {sigma: K} first start of each sigma (e.g. the shipped gains; else the LQ gain);
    ``references``: {sigma: (label, K)} gains evaluated at every level (the paper-method gains);
    ``progress(point)`` after each point; ``executor``: the tuner's evaluations on a cluster
    (:class:`magtune_core.design.objective.HinfObjective`), None for local ``workers``; ``done``:
    points of an interrupted run of the same front (``--resume``), kept as they are.

    Returns
    -------
    list of LevelPoint
        Tuned points (label "tuned") and reference points, by sigma then level (continuation order).
    """
    if axis not in AXES:
        raise ValueError(f"axis must be one of {', '.join(AXES)}, got {axis!r}")
    settings = settings or CmaSettings()
    starts, references = starts or {}, references or {}
    out: list[LevelPoint] = []
    for sigma in sorted(float(s) for s in sigmas):
        prev = None
        for level in hardest_first(axis, levels):
            kept = [p for p in done if p.sigma == sigma and p.level == level]
            tuned = [p for p in kept if p.label == "tuned"]
            if tuned and (sigma not in references or len(kept) > 1):  # this level is complete
                out.extend(kept)
                prev = tuned[0].K if tuned[0].K is not None else prev
                continue
            r = at_level(req, axis, level)
            t0 = time.perf_counter()
            cands = [(name, K) for name, K in (("start", starts.get(sigma)), ("previous level", prev)) if K is not None]
            name, K0 = best_start(model, sigma, r, cands)
            try:
                res = tune_gains(model, sigma, seed=seed, start_K=K0, start_name=name, workers=workers, cma=settings,
                                 requirements=r, executor=executor)
            except InfeasibleStart as exc:
                pt = LevelPoint(sigma, level, "tuned", None, seconds=time.perf_counter() - t0, note=str(exc))
            else:
                g = res.gains.provenance
                pt = LevelPoint(sigma, level, "tuned", res.gains.K, g["J"], g["c1"], g["c2"], g["hold_margin_min"],
                                g["dipole_peak_proxy"], bool(g["requirements_met"]), bool(res.result.converged),
                                res.result.evaluations, time.perf_counter() - t0, res.result.stop or "")
                prev = res.gains.K
            out.append(pt)
            if progress is not None:
                progress(pt)
            if sigma in references:
                label, K = references[sigma]
                ref = evaluate(model, K, sigma, r, label, level)
                out.append(ref)
                if progress is not None:
                    progress(ref)
    return out


def level_table(points: list[LevelPoint], axis: str) -> str:
    """Markdown table: one row per (sigma, level), the tuned gain then the references."""
    unit = AXES[axis]
    head = (f"| sigma | {axis} [{unit}] | gain | J | c1 | c2 | hold margin (min) | peak dipole [A m^2] | "
            "requirements | certified | evaluations | time [s] |")
    lines = [head, "|" + "---|" * 12]
    for p in sorted(points, key=lambda p: (p.sigma, p.level, p.label != "tuned")):
        if p.K is None:
            lines.append(f"| {p.sigma:g} | {p.level:g} | {p.label} | infeasible: {p.note} | | | | | | | | "
                         f"{p.seconds:.0f} |")
            continue
        cert = "" if p.label != "tuned" else ("yes" if p.certified else f"no ({p.note or 'budget'})")
        ev = "" if p.label != "tuned" else str(p.evaluations)
        tm = "" if p.label != "tuned" else f"{p.seconds:.0f}"
        lines.append(f"| {p.sigma:g} | {p.level:g} | {p.label} | {p.J:.2f} | {p.c1:.2f} | {p.c2:.0f} | "
                     f"{p.hold_margin_min:.2f} | {p.dipole_peak:.1f} | {'met' if p.met else 'not met'} | {cert} | "
                     f"{ev} | {tm} |")
    return "\n".join(lines)


def cost_of(points: list[LevelPoint], level: float, base: float) -> dict:
    """Relative J cost of ``level`` against ``base`` per sigma (tuned gains): {sigma: J(level)/J(base) - 1}.

    Returns
    -------
    dict
        sigma -> relative cost (nan where either point is infeasible).
    """
    J = {(p.sigma, p.level): p.J for p in points if p.label == "tuned" and p.K is not None}
    return {s: J.get((s, level), np.nan) / J.get((s, base), np.nan) - 1.0 for s in sorted({p.sigma for p in points})}


def plot_level_front(points: list[LevelPoint], axis: str, path) -> None:
    """J, c1 and c2 against the level for each sigma, the reference gains (dashed; filled where they
    meet the level's requirements) and the paper's Table 1 c1, c2 (dotted) (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.6), constrained_layout=True)
    sigmas = sorted({p.sigma for p in points})
    for i, sigma in enumerate(sigmas):
        color = f"C{i}"
        tuned = sorted((p for p in points if p.sigma == sigma and p.label == "tuned" and p.K is not None),
                       key=lambda p: p.level)
        refs = sorted((p for p in points if p.sigma == sigma and p.label != "tuned"), key=lambda p: p.level)
        for ax, key in zip(axes, ("J", "c1", "c2")):
            x = [p.level for p in tuned]
            ax.plot(x, [getattr(p, key) for p in tuned], "o-", color=color, label=f"tuned, sigma = {sigma:g}")
            if refs:
                ax.plot([p.level for p in refs], [getattr(p, key) for p in refs], "--", color=color, alpha=0.6,
                        label=f"{refs[0].label}, sigma = {sigma:g} (filled: meets the level)")
                met = [p for p in refs if p.met]
                ax.plot([p.level for p in met], [getattr(p, key) for p in met], "s", color=color, alpha=0.6)
            if key != "J" and int(sigma) in PAPER_TABLE1:
                ax.axhline(PAPER_TABLE1[int(sigma)][0 if key == "c1" else 1], color=color, ls=":", lw=1)
            bad = [p.level for p in points if p.sigma == sigma and p.label == "tuned" and p.K is None]
            for b in bad:
                ax.axvline(b, color=color, ls="-.", lw=0.8)
    titles = {"J": "J (eq. 21)", "c1": "c1 = ||T_d -> dq_R||_inf (eq. 28)", "c2": "c2 = ||T_d -> m||_2 (eq. 29)"}
    xlabel = "longest sample period of the hold requirement Ts_max [s]" if axis == "ts_max" else \
        "torquer dipole limit per axis [A m^2] (budget = fraction of it)"
    for ax, key in zip(axes, ("J", "c1", "c2")):
        ax.set_xlabel(xlabel)
        ax.set_title(titles[key] + ("; dotted: paper Table 1" if key != "J" else ""), fontsize=9)
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=7)
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)
