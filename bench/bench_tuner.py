"""Tuner benchmark: the methods against each other, and the cost of one J(K), in one run.

    python bench/bench_tuner.py [--sigmas 60,120,240] [--methods cma,paper] [--seeds 0] [--max-evals 30000]
                                [--max-seconds S] [--workers 2] [--skip-norm] [--skip-methods]

Prints, with the machine's load average (the machine is shared: read every time against it):

1. J(K) single-gain time at 1e-4 relative accuracy (bisection bracket) at half, once and twice
   the gain's resolved Magnus steps (``design.resolution``: 64 for the paper-method gain, the
   issue's reference point; 256 for the stiff optimum shipped since), the discretization error of
   each against 4x the resolved steps, and the per-gain time in a batch of 500 gains
   (HinfObjective, one process and ``--workers`` processes) at the resolved steps; next to it the
   hard requirements' cost for a population of 8 gains at Ts = 1 s: the held loop's spectral radius
   and the dipole budget's peak (``design.dipole``, the design spec's case; exact and with the
   screen's early exit);
2. per method, sigma and seed: evaluations and wall time until the best J is within 1 % and
   0.2 % of the best known J (the shipped gains' J; with ``--gain-margin 0``, the unconstrained
   problem, also the issue's values below), the
   final J, its gap to the best known and whether the method's stopping rule fired. Evaluations:
   full J evaluations for cma, candidates gamma-tested (one level each) for the paper's method.
   ``--max-seconds`` stops each cma run after that wall time (the issue's budget is 90 s per
   sigma) and keeps its best gain, as Ctrl-C does in ``magtune tune``.

Timings are wall-clock; nothing is asserted.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from magtune_core.design.cmaes import CmaSettings, tune_cma
from magtune_core.design.dipole import peak_dipole
from magtune_core.design.gains import load_gains
from magtune_core.design.lq import lq_gain
from magtune_core.design.model import AttitudeLTP
from magtune_core.design.objective import HinfObjective
from magtune_core.design.params import SpacecraftParams
from magtune_core.design.problem import performance_system
from magtune_core.design.requirements import load_requirements, spacecraft_dipole_limit
from magtune_core.design.sampled import HoldConstraint, SampledLoop, feasible_start
from magtune_core.design.tuner import TunerSettings, tune
from magtune_core.ltp import hinfnorm
from magtune_core.ltp.hinf import GROWTH, gamma_margins

ROOT = Path(__file__).resolve().parents[1]
#: Best J found before this benchmark existed (issue 9: CMA-ES from the then shipped gains, 64
#: steps); superseded by the certified gains shipped since (their provenance J is lower).
ISSUE_BEST = {60: 267.76, 120: 379.25, 240: 600.53}


def load() -> str:
    return "load average " + " ".join(open("/proc/loadavg").read().split()[:3])


def best_known(sigma: float, model, constrained: bool = True) -> float:
    """The shipped gain's J at 512 steps, like the runs' "J at 512 steps" it is compared with (the J in
    the file is at its analysis steps, 256, which differs by up to 4e-4 for these stiff gains; tuned
    under the default hold constraint); without the constraint also the issue's unconstrained values
    (whose gains need not meet it)."""
    vals = [] if constrained else [ISSUE_BEST.get(int(sigma), np.inf)]
    p = ROOT / "config" / "gains" / f"sigma_{sigma:g}.yaml"
    if p.exists():
        g = load_gains(p)
        vals.append(float(hinfnorm(performance_system(model, g.K, sigma), rtol=1e-7, steps=512, guess=g.provenance.get("J"))))
    return float(min(vals))


def bench_norm(model, sigma, workers, path):
    from magtune_core.design.resolution import resolved_steps

    K = load_gains(path).K
    r = resolved_steps(model, K, sigma)[0]
    sys_ = performance_system(model, K, sigma)
    ref = float(hinfnorm(sys_, rtol=1e-9, steps=4 * r))
    print(f"\n## J(K) cost, sigma = {sigma:g}, {path.relative_to(ROOT)}; resolved steps {r}; reference J = {ref:.6f} "
          f"({4 * r} Magnus steps); {load()}")
    print(f"| Magnus steps | rel. error vs {4 * r} | single J(K), rtol 1e-4 [ms] | batch of 500, 1 process [ms/gain] |")
    print("|---|---|---|---|")
    rng = np.random.default_rng(0)
    Ks = K * (1 + 0.02 * rng.standard_normal((500, 3, 6)))
    for steps in (r // 2, r, 2 * r):
        ts = []
        for _ in range(5):
            t = time.perf_counter()
            J = float(hinfnorm(sys_, rtol=1e-4, steps=steps))
            ts.append(time.perf_counter() - t)
        batch = ""
        if steps == r:
            obj = HinfObjective(model, sigma, steps=steps, rtol=1e-4)
            t = time.perf_counter()
            obj(Ks, guess=ref, spread=1.05)
            batch = f"{1e3 * (time.perf_counter() - t) / len(Ks):.1f}"
        print(f"| {steps} | {abs(J - ref) / ref:.1e} | {1e3 * np.median(ts):.1f} | {batch} |")
    print(f"\nInterval squarings (ltp.hinf.interval_scattering): one gamma-test at 1.01 J, plain exponential "
          f"(growth = inf, the arithmetic before) against squaring in scattering form beyond ||.||_1 = {GROWTH:g}:")
    print("| Magnus steps | plain: passes / ms | scattering form: passes / ms | time ratio |")
    print("|---|---|---|---|")
    for steps in (r // 2, r, 2 * r):
        row = []
        for growth in (np.inf, GROWTH):
            gamma_margins(sys_, 1.01 * ref, steps, growth=growth)  # compile / warm up
            t = time.perf_counter()
            for _ in range(5):
                p = bool(gamma_margins(sys_, 1.01 * ref, steps, growth=growth)[0])
            row.append((p, 1e3 * (time.perf_counter() - t) / 5))
        print(f"| {steps} | {row[0][0]} / {row[0][1]:.1f} | {row[1][0]} / {row[1][1]:.1f} | {row[1][1] / row[0][1]:.2f} |")
    # the hold constraint's cost next to J's (design/sampled.py): one build, one population of 8
    t = time.perf_counter()
    loop = SampledLoop.build(model, 1.0)
    t_build = time.perf_counter() - t
    loop.spectral_radius(Ks[:8])  # compile / load the cached kernel
    t = time.perf_counter()
    loop.spectral_radius(Ks[:8])
    t_pop = time.perf_counter() - t
    t = time.perf_counter()
    M = np.broadcast_to(np.eye(6), (8, 6, 6)).copy()
    for k in range(loop.intervals):  # the same product in numpy, batched over the 8 gains
        M = (loop.Ad + loop.Gamma[k] @ Ks[:8]) @ M
    t_np = time.perf_counter() - t
    print(f"\nHold constraint at Ts = 1 s ({loop.intervals} intervals): build {1e3 * t_build:.0f} ms once; "
          f"a population of 8 gains {1e3 * t_pop:.1f} ms compiled ({1e3 * t_pop / 8:.2f} ms/gain), the same product "
          f"in batched numpy {1e3 * t_np:.0f} ms: ratio {t_np / t_pop:.1f} ({load()})")
    bench_dipole(loop, Ks[:8])
    if workers > 1:
        with HinfObjective(model, sigma, steps=r, rtol=1e-4, workers=workers) as obj:
            obj(Ks[:2 * workers])  # start the workers
            t = time.perf_counter()
            obj(Ks, guess=ref, spread=1.05)
            print(f"batch of 500, {r} steps, {workers} processes: {1e3 * (time.perf_counter() - t) / len(Ks):.1f} ms/gain ({load()})")


def median_ms(f, reps: int = 5) -> float:
    """Median wall time of ``f()`` over ``reps`` calls after one untimed call (compile / load cached kernels) [ms]."""
    f()
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t)
    return 1e3 * float(np.median(ts))


def bench_dipole(loop, pop):
    """The dipole budget's cost (design/dipole.py, the feasibility screen's costliest check) for one population
    at the loop's Ts with the design spec's case (config/design.yaml, the spacecraft's limit), exact and with the
    screen's early exit at the budget, next to the held-loop spectral radius of the same population."""
    req = load_requirements(ROOT / "config/design.yaml", spacecraft_dipole_limit(ROOT / "config/spacecraft.yaml"))
    case = req.dipole_case()
    t_rho = median_ms(lambda: loop.spectral_radius(pop))
    t_exact = median_ms(lambda: peak_dipole(loop, pop, case))
    t_screen = median_ms(lambda: peak_dipole(loop, pop, case, stop_above=req.dipole_budget))
    over = int(np.sum(peak_dipole(loop, pop, case).max(axis=-1) > req.dipole_budget))
    steps = int(round(case.orbits * loop.intervals))
    print(f"Dipole peak at Ts = {loop.ts:.4g} s ({case.orbits:g} orbits, {steps} steps; the design spec's case): a population "
          f"of {len(pop)} gains {t_exact:.1f} ms exact, {t_screen:.1f} ms with the screen's early exit at {req.dipole_budget:g} A m^2 "
          f"({over} of {len(pop)} above); held-loop spectral radius {t_rho:.1f} ms (medians of 5; {load()})")


def run_method(model, sigma, method, seed, max_evals, workers, max_seconds=None, hold=None):
    """(rows of (evaluations, seconds, J_best), result) of one tuning run (cma: at most ``max_seconds``,
    under the hold constraint ``hold`` as ``magtune tune`` does by default; the paper's method: unconstrained)."""
    rows = []
    t0 = time.perf_counter()
    if method == "paper":
        s = TunerSettings(workers=workers)

        def prog(it, J, r, mu, nb):
            rows.append((it * s.samples, time.perf_counter() - t0, J))

        res = tune(model, sigma, seed=seed, settings=s, progress=prog)
    else:
        s = CmaSettings(max_evals=max_evals, workers=workers)

        def prog(ev, J, gen, step, restart):
            rows.append((ev, time.perf_counter() - t0, J))
            if max_seconds is not None and rows[-1][1] >= max_seconds:
                raise KeyboardInterrupt  # tune_cma's interrupt path: ends the search, keeps the best gain

        K0 = lq_gain(model, sigma) if hold is None else feasible_start(model, lq_gain(model, sigma), hold)[0]
        with HinfObjective(model, sigma, steps=s.steps, rtol=s.rtol, workers=workers, hold=hold) as obj:
            res = tune_cma(obj, K0, sigma, seed=seed, settings=s, progress=prog)
    return rows, res


def reach(rows, target):
    for ev, t, J in rows:
        if J <= target:
            return f"{ev} / {t:.0f} s"
    return "not reached"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sigmas", default="60,120,240")
    ap.add_argument("--methods", default="cma,paper")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--max-evals", type=int, default=30000)
    ap.add_argument("--max-seconds", type=float, default=None, help="wall-time budget of each cma run")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--gain-margin", type=float, default=2.0,
                    help="hold constraint of the cma runs at Ts = 1 s (default 2, as magtune tune; 0 = none)")
    ap.add_argument("--save", metavar="DIR", default=None,
                    help="write each run's final gain and J at 512 steps to DIR/<method>_sigma<s>_seed<n>.npz "
                         "(an existing file is an error: nothing is overwritten)")
    ap.add_argument("--skip-norm", action="store_true")
    ap.add_argument("--skip-methods", action="store_true")
    args = ap.parse_args()
    model = AttitudeLTP.from_params(SpacecraftParams())
    sigmas = [float(s) for s in args.sigmas.split(",")]
    save = Path(args.save) if args.save else None
    if save is not None:
        save.mkdir(parents=True, exist_ok=True)
        clash = [p.name for p in save.glob("*_sigma*_seed*.npz")]
        if clash:
            raise SystemExit(f"bench_tuner: --save {save}: holds results of an earlier run ({clash[0]}, ...); "
                             "choose an empty directory")
    print(f"# magtune tuner benchmark ({os.cpu_count()} cores; {load()})")
    if not args.skip_norm:
        for path in (ROOT / "config" / "gains" / "paper_method" / f"sigma_{sigmas[0]:g}.yaml",
                     ROOT / "config" / "gains" / f"sigma_{sigmas[0]:g}.yaml"):
            bench_norm(model, sigmas[0], args.workers, path)
    if args.skip_methods:
        return
    print(f"\n## Methods: evaluations / wall time to reach J within 1 % and 0.2 % of the best known ({args.workers} workers)")
    print("| sigma | method | seed | best known J | to 1 % | to 0.2 % | final J (tuned steps) | J at 512 steps "
          "| above best known | evaluations | time [s] | stop | load at end |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    bests = []
    for sigma in sigmas:
        bk = best_known(sigma, model, constrained=bool(args.gain_margin))
        finals = []
        for method in args.methods.split(","):
            for seed in (int(s) for s in args.seeds.split(",")):
                hold = HoldConstraint(1.0, args.gain_margin) if args.gain_margin else None
                rows, res = run_method(model, sigma, method, seed, args.max_evals, args.workers, args.max_seconds, hold)
                # the tuned grid's J may be below the resolved one by up to the resolution watch's 2e-3
                J512 = float(hinfnorm(performance_system(model, res.K, sigma), rtol=1e-7, steps=512, guess=res.J))
                finals.append((method, seed, J512))
                if save is not None:
                    np.savez(save / f"{method}_sigma{sigma:g}_seed{seed}.npz", K=res.K, J512=J512, J=res.J,
                             evaluations=res.evaluations, seconds=res.seconds, stop=str(res.stop))
                print(f"| {sigma:g} | {method} | {seed} | {bk:.2f} | {reach(rows, 1.01 * bk)} | {reach(rows, 1.002 * bk)} | "
                      f"{res.J:.3f} | {J512:.3f} | {100 * (J512 / bk - 1):+.2f} % | {res.evaluations} | {res.seconds:.0f} | "
                      f"{res.stop or res.converged} | "
                      f"{open('/proc/loadavg').read().split()[0]} |", flush=True)
        best = min(bk, min(J for _, _, J in finals))
        bests.append(f"sigma = {sigma:g}: best {best:.3f} (" + ", ".join(
            f"{m} seed {sd} {100 * (J / best - 1):+.2f} %" for m, sd, J in finals) + ")")
    print("\nAgainst the best of the shipped gain and this run's gains (J at 512 steps):\n" + "\n".join(bests))


if __name__ == "__main__":
    main()
