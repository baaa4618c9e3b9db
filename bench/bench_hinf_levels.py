"""How many gamma-tests one H-infinity norm costs: hinfnorm's placed levels against plain bisection.

    python bench/bench_hinf_levels.py [--quick]

Every J(K) is a sequence of Riccati gamma-tests (``ltp.hinf``), each costing the same, so the number
of tests per norm is the figure to compare (wall time follows it; printed too). For the shipped and
paper-method gains at their resolved Magnus steps, at rtol 1e-4 and 1e-6:

* single: ``hinfnorm(sys)`` with no guess (``magtune analyze``'s case), tests including the bracketing;
* batch: 8 gains perturbed by 1 % with guess = the centre's J and spread 1.05 (the tuner's case),
  tests per gain including the bracketing;
* bisection: plain geometric bisection of the bracket [J / 1.05, 1.05 J] to the same rtol, the
  bracketing given for free (the alternative the level model has to beat).

Prints the machine load; nothing is asserted.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import magtune_core.ltp.hinf as hinf
from magtune_core.design.gains import load_gains
from magtune_core.design.model import AttitudeLTP
from magtune_core.design.params import SpacecraftParams
from magtune_core.design.problem import performance_system

ROOT = Path(__file__).resolve().parents[1]
CASES = [("config/gains/paper_method/sigma_60.yaml", 64), ("config/gains/paper_method/sigma_240.yaml", 64),
         ("config/gains/sigma_60.yaml", 256), ("config/gains/sigma_120.yaml", 512), ("config/gains/sigma_240.yaml", 256)]


def load() -> str:
    return "load average " + " ".join(open("/proc/loadavg").read().split()[:3])


class Counter:
    """Counts the (system, level) pairs hinfnorm sends to the gamma-test."""

    def __init__(self):
        self.n = 0
        self._orig = hinf.gamma_margins

    def __enter__(self):
        def counted(sys_, gamma, steps, growth=hinf.GROWTH):
            self.n += int(np.size(gamma))
            return self._orig(sys_, gamma, steps, growth)
        hinf.gamma_margins = counted
        return self

    def __exit__(self, *exc):
        hinf.gamma_margins = self._orig


def bisection_tests(sys_, J, rtol, steps) -> int:
    """Gamma-tests plain geometric bisection needs from [J / 1.05, 1.05 J] to a relative bracket rtol."""
    lo, hi, n = J / 1.05, 1.05 * J, 0
    while hi - lo > rtol * hi:
        g = np.sqrt(lo * hi)
        n += 1
        if bool(hinf.gamma_test(sys_, g, steps)):
            hi = g
        else:
            lo = g
    return n


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="only the 64-step cases")
    args = ap.parse_args()
    model = AttitudeLTP.from_params(SpacecraftParams())
    rng = np.random.default_rng(0)
    print(f"# gamma-tests per H-inf norm ({load()})\n")
    print("| gains | steps | rtol | single: tests / ms | batch of 8: tests per gain / ms per gain | bisection of +-5 %: tests |")
    print("|---|---|---|---|---|---|")
    for rel, steps in CASES:
        if args.quick and steps > 64:
            continue
        g = load_gains(ROOT / rel)
        sigma = g.sigma
        sys_ = performance_system(model, g.K, sigma)
        J = float(hinf.hinfnorm(sys_, rtol=1e-9, steps=steps))
        Ks = g.K * (1 + 0.01 * rng.standard_normal((8, 3, 6)))
        sysb = performance_system(model, Ks, sigma)
        for rtol in (1e-4, 1e-6):
            with Counter() as c:
                t = time.perf_counter()
                hinf.hinfnorm(sys_, rtol=rtol, steps=steps)
                t1, n1 = time.perf_counter() - t, c.n
                c.n = 0
                t = time.perf_counter()
                hinf.hinfnorm(sysb, rtol=rtol, steps=steps, guess=np.full(8, J), spread=1.05, grid=1)
                tb, nb = time.perf_counter() - t, c.n
            nbis = bisection_tests(sys_, J, rtol, steps)
            print(f"| {rel.removeprefix('config/gains/')} | {steps} | {rtol:g} | {n1} / {1e3 * t1:.0f} | "
                  f"{nb / 8:.1f} / {1e3 * tb / 8:.0f} | {nbis} |", flush=True)
    print(f"\n({load()})")


if __name__ == "__main__":
    main()
