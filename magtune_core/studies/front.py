"""The trade-off front: the J-optimal gain for each control-effort weight sigma (paper eq. 20).

``magtune front --sigmas 30,45,60,...`` (the command: :mod:`magtune_core.cli.front`) tunes one gain
per sigma with the converging tuner (:func:`magtune_core.design.cmaes.tune_cma`) and reports J
(eq. 21), c1 = ||T_d -> dq_R||_inf (eq. 28), c2 = ||T_d -> m||_2 (eq. 29) and rho (eq. 30).

Continuation in sigma: the sigmas are tuned in increasing order and each run starts from the
best (lowest J at the new sigma) of the LQ gain (paper 4.2), the previous sigma's optimum and any
gains given as ``starts`` (e.g. the shipped, certified sigma = 60/120/240 gains); the front is
smooth in sigma, so the warm start saves most of the search. The population of
every generation is split over ``workers`` processes (all cores by default), since the sigmas
depend on each other through the warm start.

The plot shows c1 against c2 (the attitude-versus-dipole trade-off the paper's Table 1 samples at
sigma = 60, 120, 240, whose three points are marked as published) and J, c1, c2, rho against sigma.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..base.atomic import atomic_savefig
from ..design.cmaes import CmaSettings, tune_cma
from ..design.lq import lq_gain
from ..design.model import AttitudeLTP
from ..design.objective import HinfObjective
from ..design.problem import figures
from ..design.resolution import resolved_steps
from ..design.sampled import HoldConstraint, feasible_start

#: Paper Table 1 (c1, c2, rho) at sigma = 60, 120, 240, as published.
PAPER_TABLE1 = {60: (239.19, 12072.45, 0.00283), 120: (283.96, 11039.75, 0.00345), 240: (399.32, 9348.98, 0.00598)}
DEFAULT_SIGMAS = (30, 45, 60, 80, 100, 120, 150, 180, 210, 240, 300, 360, 420, 480)


@dataclass
class FrontPoint:
    """One sigma of the front: the tuned gain and its figures of merit."""

    sigma: float
    K: np.ndarray
    J: float
    c1: float
    c2: float
    rho: float
    evaluations: int
    seconds: float
    converged: bool
    start: str
    stop: str = ""  # the tuner's stop reason ("certified", "budget", "unresolved", ...)

    def as_dict(self) -> dict:
        return {"sigma": self.sigma, "J": self.J, "c1": self.c1, "c2": self.c2, "rho": self.rho,
                "evaluations": self.evaluations, "seconds": round(self.seconds, 1), "converged": self.converged,
                "start": self.start, "stop": self.stop, "gain": [float(v) for v in self.K.ravel()]}


def run_front(model: AttitudeLTP, sigmas, settings: CmaSettings, seed: int = 0, analysis_steps: int = 128,
              progress=None, starts=(), hold: HoldConstraint | None = None, executor=None) -> list[FrontPoint]:
    """Tune each sigma (increasing, warm-started) and compute its figures of merit.

    ``starts`` is a sequence of (label, K) candidate start gains tried at every sigma besides the
    LQ gain and the previous sigma's optimum. Figures are computed at ``analysis_steps`` doubled
    until resolved (:func:`~magtune_core.design.resolution.resolved_steps`).
    ``progress(i, n, point)`` is called after each sigma. ``hold``: the digital-implementation
    constraint of every tuning (design/sampled.py); candidate starts that fail it are scaled down.
    ``executor``: where each population is evaluated instead of ``settings.workers`` local
    processes (e.g. :class:`.cluster.ClusterExecutor`; :class:`~magtune_core.design.objective.HinfObjective`).

    Returns
    -------
    list of FrontPoint
        One per sigma, in increasing sigma.
    """
    out: list[FrontPoint] = []
    prev = None
    sig = sorted(float(s) for s in sigmas)
    for i, sigma in enumerate(sig):
        t0 = time.perf_counter()
        cands = [("lq", lq_gain(model, sigma))] + ([(f"sigma={out[-1].sigma:g}", prev)] if prev is not None else [])
        cands += [(label, np.asarray(K, dtype=float).reshape(3, 6)) for label, K in starts]
        if hold is not None:
            cands = [(label, feasible_start(model, K, hold)[0]) for label, K in cands]
        # each candidate's J on its own resolved grid (a stiff start may need more steps than 64)
        Js = [resolved_steps(model, K, sigma, settings.steps) for _, K in cands]
        best = int(np.argmin([J for _, J in Js]))
        (start, K0), steps = cands[best], max(Js[best][0], settings.steps)
        with HinfObjective(model, sigma, steps=steps, rtol=settings.rtol, workers=settings.workers, hold=hold,
                           executor=executor) as obj:
            res = tune_cma(obj, K0, sigma, seed=seed, settings=settings)
        f = figures(model, res.K, sigma, steps=resolved_steps(model, res.K, sigma, analysis_steps)[0])
        pt = FrontPoint(sigma, res.K, f.J, f.c1, f.c2, f.rho, res.evaluations, time.perf_counter() - t0,
                        res.converged, start, res.stop or "")
        out.append(pt)
        prev = res.K
        if progress is not None:
            progress(i + 1, len(sig), pt)
    return out


def front_table(points: list[FrontPoint]) -> str:
    """Markdown table of the front (one row per sigma)."""
    lines = ["| sigma | J | c1 | c2 | rho | evaluations | time [s] | certified | start |", "|---|---|---|---|---|---|---|---|---|"]
    for p in points:
        cert = "yes" if p.converged else f"no ({p.stop or 'budget'})"
        lines.append(f"| {p.sigma:g} | {p.J:.2f} | {p.c1:.2f} | {p.c2:.1f} | {p.rho:.2e} | {p.evaluations} | "
                     f"{p.seconds:.0f} | {cert} | {p.start} |")
    return "\n".join(lines)


def plot_front(points: list[FrontPoint], path) -> None:
    """c1 against c2 with the paper's Table 1 points, and J, c1, c2, rho against sigma (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401  (matplotlib.ticker below)

    s = np.array([p.sigma for p in points])
    c1, c2 = np.array([p.c1 for p in points]), np.array([p.c2 for p in points])
    fig = plt.figure(figsize=(12, 6.5), constrained_layout=True)
    gs = fig.add_gridspec(2, 3)
    ax = fig.add_subplot(gs[:, 0:2])
    ax.plot(c2, c1, "o-", color="C0", label="ours: J-optimal gain per sigma (converging tuner)")
    for p in points:
        ax.annotate(f"{p.sigma:g}", (p.c2, p.c1), textcoords="offset points", xytext=(4, 4), fontsize=8, color="C0")
    pc1 = [v[0] for v in PAPER_TABLE1.values()]
    pc2 = [v[1] for v in PAPER_TABLE1.values()]
    ax.plot(pc2, pc1, "s", color="C3", ms=9, label="paper Table 1 (sigma = 60, 120, 240), as published")
    for sg, (a, b, _) in PAPER_TABLE1.items():
        ax.annotate(f"paper {sg}", (b, a), textcoords="offset points", xytext=(6, -10), fontsize=8, color="C3")
    ax.set_xlabel("c2 = ||T_d -> m||_2  (H2, eq. 29)")
    ax.set_ylabel("c1 = ||T_d -> dq_R||_inf  (eq. 28)")
    ax.set_title("Trade-off front: attitude (c1) against dipole effort (c2); labels: sigma")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    for k, (key, label) in enumerate((("J", "J (eq. 21)"), ("rho", "rho = max |multiplier|"))):
        a = fig.add_subplot(gs[k, 2])
        a.plot(s, [getattr(p, key) for p in points], "o-")
        if key == "J":
            a.plot(s, c1, "^-", label="c1")
            a.legend(["J", "c1"], fontsize=8)
        a.set_xscale("log")
        nice = [v for v in (10, 15, 30, 60, 120, 240, 480, 960, 1920) if s.min() <= v <= s.max()] or list(s[[0, -1]])
        a.set_xticks(nice, [f"{v:g}" for v in nice])  # plain sigmas: log-axis minor labels (3 x 10^1 ...) overlap
        a.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        if key == "rho":
            a.set_yscale("log")
        a.set_xlabel("sigma")
        a.set_ylabel(label)
        a.grid(True, which="both", alpha=0.3)
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)
