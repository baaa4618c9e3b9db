"""The certified tune under the design spec: where an evaluation's time goes, and the tune per sigma.

    python bench/bench_tune_spec.py [--sigmas 60,120,240] [--workers 2] [--skip-costs] [--skip-tunes]

Prints, with the machine's load average (run it alone: 2 cores):

1. the cost of one candidate gain under the default design spec (config/design.yaml), by part, in
   one process: the continuous-time monodromy test, the held-loop spectral radii (both ends of the
   margin at each checked period), the dipole proxy, and the objective without and with the screen;
2. a population of 8 through :class:`HinfObjective` on ``--workers`` processes, the objective's
   constants (models and screens) sent once per worker (the pool's initializer, the default) against
   sent with every part (a plain process pool as the executor: what the objective did before);
3. ``magtune tune --sigma S --seed 0 --workers W --verify-runs 0`` per sigma from the LQ start, as
   the command runs it (``design.pipeline.tune_gains``): certified J, evaluations, search seconds
   and seconds per evaluation (issue 46's "certified tune in a minute"), and the wall time of the whole
   ``tune_gains`` (search, dense scans, the figures and requirements of the gains file).

Timings are wall-clock; nothing is asserted.
"""
from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from bench_tuner import load, median_ms  # this directory's: the same clock and load line

from magtune_core.cli import build_parser
from magtune_core.cli.common import load_model
from magtune_core.cli.tune import _cma_settings, requirements_of
from magtune_core.design.dipole import peak_dipole
from magtune_core.design.lq import lq_gain
from magtune_core.design.objective import HinfObjective, model_feasible, model_norms, one_thread_per_worker
from magtune_core.design.pipeline import tune_gains
from magtune_core.design.problem import attitude_system, performance_system
from magtune_core.design.requirements import hold_ends
from magtune_core.design.sampled import feasible_start
from magtune_core.ltp import hinfnorm, spectral_radius


def population(model, sigma: float, req, n: int = 8, spread: float = 0.02, seed: int = 0) -> np.ndarray:
    """n feasible gains around the feasible LQ start (relative perturbations ``spread``, those that
    fail the spec dropped): what every part of the spec costs, as a candidate that passes pays it."""
    K0 = feasible_start(model, lq_gain(model, sigma), req)[0]
    Ks = K0 * (1 + spread * np.random.default_rng(seed).standard_normal((16 * n, 3, 6)))
    return Ks[model_feasible(model, Ks, 64, req.screen(model))][:n]


def bench_costs(model, sigma: float, req, workers: int) -> None:
    screen = req.screen(model)
    Ks = population(model, sigma, req)
    J = hinfnorm(performance_system(model, Ks[0], sigma), rtol=1e-4, steps=64)
    print(f"\n## One candidate under the design spec, sigma = {sigma:g} ({req.describe()}); ms per gain, one process, "
          f"population of {len(Ks)} feasible gains around the LQ start; {load()}")
    print("| part | ms per gain |\n|---|---|")
    rows = [("continuous-time monodromy test, 64 steps", lambda: spectral_radius(attitude_system(model, Ks), 64))]
    for loop in screen.loops:
        scales = np.array([g for g, _ in hold_ends(screen.gain_margin, screen.max_multiplier)])
        rows.append((f"held loop, Ts = {loop.ts:.3g} s ({loop.intervals} intervals), both ends",
                     lambda loop=loop, scales=scales: loop.spectral_radius((scales[:, None, None, None] * Ks).reshape(-1, 3, 6))))
    for loop in screen.dipole_loops:
        rows.append((f"dipole proxy, Ts = {loop.ts:.3g} s, {screen.case.orbits:g} orbits",
                     lambda loop=loop: peak_dipole(loop, Ks, screen.case)))
    for steps in (64, 128):
        rows.append((f"monodromy test and J to 1e-5 batched (the objective without the screen), {steps} steps",
                     lambda steps=steps: model_norms(model, sigma, Ks, steps, 1e-5, guess=J, spread=1.05)))
    rows.append(("the objective in one process, screen included, 64 steps",
                 lambda: model_norms(model, sigma, Ks, 64, 1e-5, guess=J, spread=1.05, hold=screen)))
    for name, f in rows:
        print(f"| {name} | {median_ms(f, 3) / len(Ks):.2f} |")
    with HinfObjective(model, sigma, steps=64, rtol=1e-5, workers=workers, hold=req) as once, \
            ProcessPoolExecutor(workers, initializer=one_thread_per_worker) as pool:
        per_part = HinfObjective(model, sigma, steps=64, rtol=1e-5, hold=req, executor=_Plain(pool, workers))
        a = median_ms(lambda: once(Ks, guess=J, spread=1.05))
        b = median_ms(lambda: per_part(Ks, guess=J, spread=1.05))
    print(f"\nA population of {len(Ks)} on {workers} processes: constants sent once per worker {a:.1f} ms, with every "
          f"part {b:.1f} ms: ratio {b / a:.2f} ({load()})")


class _Plain:
    """A process pool as an objective's executor without ``share``: the constants go with every part."""

    def __init__(self, pool, workers: int):
        self.pool, self.workers = pool, workers

    def submit(self, fn, *args):
        return self.pool.submit(fn, *args)


def bench_tunes(sigmas, workers: int) -> None:
    print(f"\n## magtune tune --sigma S --seed 0 --workers {workers} --verify-runs 0 (LQ start, default design spec)")
    print("| sigma | certified J | stop | evaluations | search [s] | ms per evaluation | tuned steps | tune_gains wall [s] "
          "| load at end |")
    print("|---|---|---|---|---|---|---|---|---|")
    for sigma in sigmas:
        args = build_parser().parse_args(["tune", "--sigma", f"{sigma:g}", "--workers", str(workers), "--verify-runs", "0"])
        t = time.perf_counter()
        res = tune_gains(load_model(args), sigma, seed=0, workers=workers, cma=_cma_settings(args),
                         requirements=requirements_of(args)).result
        wall = time.perf_counter() - t
        print(f"| {sigma:g} | {res.J:.3f} | {res.stop} | {res.evaluations} | {res.seconds:.1f} | "
              f"{1e3 * res.seconds / res.evaluations:.2f} | {res.tuned_steps} | {wall:.1f} | {load()} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sigmas", default="60,120,240")
    ap.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    ap.add_argument("--skip-costs", action="store_true")
    ap.add_argument("--skip-tunes", action="store_true")
    args = ap.parse_args()
    sigmas = [float(s) for s in args.sigmas.split(",")]
    print(f"# magtune tune under the design spec ({os.cpu_count()} cores; {load()})")
    if not args.skip_costs:
        targs = build_parser().parse_args(["tune", "--sigma", f"{sigmas[0]:g}"])
        bench_costs(load_model(targs), sigmas[0], requirements_of(targs), args.workers)
    if not args.skip_tunes:
        bench_tunes(sigmas, args.workers)


if __name__ == "__main__":
    main()
