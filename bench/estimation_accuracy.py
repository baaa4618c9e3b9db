"""Estimation error of the MEKF for the paper's satellite (docs/estimation.md#measured-figures).

Closed loop of the shipped gains (`config/gains/sigma_120.yaml`) for ``--orbits`` orbits at Ts = 1 s
(truth), the default sensors of ``magtune_core.sim.estimation.default_suite`` on it, one seed per
case. Prints RMS error per body axis [deg], the fraction inside 3 sigma, mean NEES, gate counts.

    python bench/estimation_accuracy.py --orbits 2
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from magtune_core.design.gains import load_gains
from magtune_core.design.params import load_spacecraft
from magtune_core.sim import estimation as E
from magtune_core.sim.simulate import simulate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--orbits", type=float, default=2.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--skip", type=float, default=600.0, help="start-up excluded from the statistics [s]")
    a = ap.parse_args()
    g, p = load_gains("config/gains/sigma_120.yaml"), load_spacecraft("config/spacecraft.yaml")
    out = {}
    for env, cases in (("full", (True, False)), ("paper", (False,))):
        res = simulate(g.K, p, ts=1.0, orbits=a.orbits, environment=env)
        truth = E.truth_along(res.t, res.q, p, env)
        for use_sun in cases:
            t0 = time.perf_counter()
            run = E.run_mekf(truth, seed=a.seed, use_sun=use_sun)
            s = E.error_summary(run, int(a.skip))
            key = f"{env}, {'magnetometer + sun' if use_sun else 'magnetometer only'}"
            out[key] = dict(rms_deg=np.round(np.degrees(s["rms"]), 3).tolist(),
                            inside_3sigma=np.round(s["inside_3sigma"], 4).tolist(), nees_mean=round(s["nees_mean"], 2),
                            bias_rms_deg_h=np.round(np.degrees(s["bias_rms"]) * 3600, 2).tolist(),
                            lit=round(float(np.mean(truth.lit)), 3) if truth.lit is not None else 0.0,
                            mag_rejected=s["mag_rejected"], sun_rejected=s["sun_rejected"], k0=run.k0,
                            seconds=round(time.perf_counter() - t0, 1))
            print(key, json.dumps(out[key]), flush=True)


if __name__ == "__main__":
    main()
