"""Benchmark of the core numerics: prints time per J(K) (exact and HTF), per tuner iteration,
per sigma, and the accuracy of each method against a high-order reference.

    python bench/bench_core.py [--workers 2] [--quick]

Timings are wall-clock medians on this machine; they are printed, never asserted in tests.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from magtune_core.design.lq import lq_gain
from magtune_core.design.model import AttitudeLTP
from magtune_core.design.params import SpacecraftParams
from magtune_core.design.problem import performance_system
from magtune_core.design.tuner import TunerSettings, tune
from magtune_core.ltp.hinf import gamma_test, hinfnorm
from magtune_core.ltp.htf import htf_hinfnorm


def timed(fn, repeat=5):
    ts, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts)), out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--sigma", type=float, default=60.0)
    ap.add_argument("--quick", action="store_true", help="skip the full tuning run")
    args = ap.parse_args()
    model = AttitudeLTP.from_params(SpacecraftParams())
    sigma = args.sigma
    K = lq_gain(model, sigma)
    sys_ = performance_system(model, K, sigma)

    ref = float(hinfnorm(sys_, rtol=1e-10, steps=1024))
    print(f"# magtune core benchmark, sigma = {sigma:g}, LQ gain; reference J = {ref:.8f} (exact, 1024 Magnus steps)")
    print("\n## Exact periodic H-inf (Riccati scattering/doubling gamma-test, bisection)")
    print("| Magnus steps | J(K) | rel. error | time per J(K) [ms] | time per gamma-test [ms] |")
    print("|---|---|---|---|---|")
    for steps in (32, 64, 128):
        t, J = timed(lambda: hinfnorm(sys_, rtol=1e-6, steps=steps, guess=ref * 1.01))
        tg, _ = timed(lambda: gamma_test(sys_, ref * 1.01, steps))
        print(f"| {steps} | {float(J):.6f} | {abs(J - ref) / ref:.1e} | {1e3 * t:.1f} | {1e3 * tg:.2f} |")

    print("\n## Truncated HTF (compressed, margin = harmonics), LTI Hamiltonian iteration")
    print("| harmonics | J(K) | rel. error | time [ms] |")
    print("|---|---|---|---|")
    reached = None
    for N in (2, 4, 6, 8, 10):
        t, J = timed(lambda: htf_hinfnorm(sys_, harmonics=N), repeat=1 if N > 6 else 3)
        err = abs(J - ref) / ref
        print(f"| {N} | {J:.6f} | {err:.1e} | {1e3 * t:.0f} |")
        if reached is None and err < 1e-4:
            reached = (N, t)
    if reached:
        print(f"\nHTF reaches 1e-4 at {reached[0]} harmonics: {1e3 * reached[1]:.0f} ms per J(K)")

    print("\n## Tuner (paper settings: N = 540, r_max = 0.995, mu = 1e-3)")
    rng = np.random.default_rng(0)
    Ks = K + 1e-3 * rng.normal(size=(540, 3, 6))
    t, _ = timed(lambda: gamma_test(performance_system(model, Ks, sigma), ref, 64), repeat=3)
    print(f"batched gamma-test of 540 candidates, 1 process: {t:.2f} s ({1e3 * t / 540:.2f} ms each)")
    if args.quick:
        return
    stamps = []
    res = tune(model, sigma, seed=0, settings=TunerSettings(workers=args.workers),
               progress=lambda *a: stamps.append(time.perf_counter()))
    per_it = np.diff(stamps)
    print(f"tune sigma={sigma:g}, seed 0, {args.workers} workers: {res.iterations} iterations, "
          f"{res.seconds:.1f} s total, {np.median(per_it) if per_it.size else res.seconds:.2f} s per iteration "
          f"(median), J {res.J0:.3f} -> {res.J:.3f}")


if __name__ == "__main__":
    main()
