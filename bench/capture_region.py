"""Region of attraction of the shipped pointing gains from arbitrary attitudes (docs/modes.md).

Usage: python bench/capture_region.py [--per-cell 24] [--orbits 3] [--seed 0] [--json docs/capture.json]
Flies magtune_core.studies.capture.capture_region for config/gains/sigma_120.yaml and sigma_60.yaml
(paper environment, Ts = 1 s, dipole limit 50 A m^2): attitude errors 10..180 deg about random axes,
rate deviations of 1, 2 and 4 W0 in random directions; prints the captured fractions, the capture
times and the failures, and writes them as JSON.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from magtune_core.design.gains import load_gains
from magtune_core.studies.capture import capture_region


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--per-cell", type=int, default=24, help="runs per (angle, rate) cell")
    ap.add_argument("--orbits", type=float, default=3.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default="", help="write the summary here")
    a = ap.parse_args(argv)
    out = {}
    for name in ("sigma_120", "sigma_60"):
        t0 = time.perf_counter()
        r = capture_region(load_gains(f"config/gains/{name}.yaml").K, per_cell=a.per_cell, orbits=a.orbits,
                           seed=a.seed)
        s = {k: r[k] for k in ("runs", "by_angle", "by_rate", "capture_time_p50", "capture_time_p95",
                               "capture_time_max", "failures", "final_error_max_captured", "settings")}
        s["captured_fraction"] = float(np.mean(r["captured"]))
        s["wall_s"] = round(time.perf_counter() - t0, 1)
        out[name] = s
        print(f"{name}: {s['runs']} runs, captured {s['captured_fraction']:.4f}, capture time p50 "
              f"{s['capture_time_p50']:.0f} s, p95 {s['capture_time_p95']:.0f} s, max {s['capture_time_max']:.0f} s, "
              f"final error of captured runs <= {s['final_error_max_captured']:.2f} deg ({s['wall_s']} s)")
        for f in s["failures"]:
            print(f"  not captured: angle {f[0]:g} deg, |dw0| {f[1]:g} W0, final error {f[2]:.1f} deg")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1, sort_keys=True)
            fh.write("\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
