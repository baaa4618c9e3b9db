"""Cost of the exact gradient of J(K) (magtune_core/ltp/hinf_gradient.py) against
the alternative it replaces: central differences of J over the 18 gain entries (36 gains, one batched
``hinfnorm`` call, same rtol), on the shipped gains at 128 and 256 Magnus steps and the LQ starts at 128, and their agreement.

Timings alternate A (exact: ``cost_gradient``, J included) and B (J + 36 differences) per repeat; the
median of each is printed with the ratio B / A. At a tuned optimum J has a kink (several active peaks),
so central differences average the peaks' gradients: the agreement column is informative only where
the kink column (|forward - backward| / |central|) is small. Printed, never asserted.

    PYTHONPATH=. python bench/bench_gradient.py
"""
from __future__ import annotations

import os
import time

import numpy as np

from magtune_core.design.gains import load_gains
from magtune_core.design.lq import lq_gain
from magtune_core.design.model import AttitudeLTP
from magtune_core.design.params import SpacecraftParams
from magtune_core.design.problem import cost_gradient, performance_system
from magtune_core.ltp import hinfnorm

RTOL = 1e-10  # the gradient needs the level within ~1e-9 of the norm (module docstring)
REPEATS = 3


def fd_gradient(model, K, sigma, steps, rel=1e-5):
    """J and central differences of J over the 18 entries, one batched hinfnorm call (37 gains)."""
    s = np.maximum(np.abs(K), 0.1 * np.abs(K).max()) * rel
    E = np.eye(18).reshape(18, 3, 6) * s
    Ks = np.concatenate([K[None], K + E, K - E])
    J = hinfnorm(performance_system(model, Ks, sigma), rtol=RTOL, steps=steps)
    fwd, bwd = J[1:19] - J[0], J[0] - J[19:]
    return J[0], ((fwd + bwd) / 2 / s.ravel()).reshape(3, 6), np.abs(fwd - bwd).max() / np.abs(fwd + bwd).max() * 2


def main():
    model = AttitudeLTP.from_params(SpacecraftParams())
    print(f"load (1/5/15 min): {' '.join(f'{x:.2f}' for x in os.getloadavg())}, {os.cpu_count()} cores; "
          f"hinfnorm rtol {RTOL:g}, median of {REPEATS}")
    print(f"{'gain':>7s} {'sigma':>5s} {'steps':>5s} {'exact [s]':>9s} {'FD [s]':>8s} {'FD/exact':>8s} {'max |diff| / max |g|':>20s} {'kink':>7s}")
    cases = [(s, "shipped", np.asarray(load_gains(f"config/gains/sigma_{s}.yaml").K).reshape(3, 6), n)
             for s in (60, 120, 240) for n in (128, 256)]
    cases += [(s, "LQ", lq_gain(model, float(s)), 128) for s in (60, 120, 240)]  # smooth points: agreement
    for sigma, name, K, steps in cases:
        ta, tb = [], []
        for _ in range(REPEATS):
            t = time.perf_counter()
            _, g, _ = cost_gradient(model, K, float(sigma), steps=steps, rtol=RTOL)
            ta.append(time.perf_counter() - t)
            t = time.perf_counter()
            _, gfd, kink = fd_gradient(model, K, float(sigma), steps)
            tb.append(time.perf_counter() - t)
        a, b = np.median(ta), np.median(tb)
        diff = np.abs(g - gfd).max() / np.abs(g).max()
        print(f"{name:>7s} {sigma:5d} {steps:5d} {a:9.3f} {b:8.3f} {b / a:8.1f} {diff:20.1e} {kink:7.1e}", flush=True)


if __name__ == "__main__":
    main()
