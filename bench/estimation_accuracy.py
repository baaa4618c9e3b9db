"""Estimation error of the MEKF for the paper's satellite (docs/estimation.md#measured-figures).

Closed loop of the shipped gains (`config/gains/sigma_120.yaml`) for ``--orbits`` orbits at Ts = 1 s
(truth), the default sensors of ``magtune_core.design.sensors.default_suite`` on it, one seed per
case. Prints RMS error per body axis [deg], the fraction inside 3 sigma, mean NEES, gate counts.
``--seeds N``: also the mean NEES over seeds seed .. seed+N-1 with its standard error, the spread of the
single-run means and the NEES's integrated autocorrelation time (docs/estimation.md#consistency).

    python bench/estimation_accuracy.py --orbits 3
    python bench/estimation_accuracy.py --orbits 3 --seeds 20 --seed 100
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
    ap.add_argument("--seeds", type=int, default=1, help="seeds of the NEES ensemble (from --seed on)")
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
            if truth.lit is not None:
                out[key].update(eclipse_split(run, truth.lit, int(a.skip)))
            print(key, json.dumps(out[key]), flush=True)
            if a.seeds > 1:
                print(key, json.dumps(ensemble(truth, use_sun, a)), flush=True)


def eclipse_split(run, lit, start: int) -> dict:
    """What eclipse costs: RMS error and mean 3-sigma bound per axis [deg] over the lit and the eclipsed
    samples (truth's illumination, from ``start``), and the peak 3-sigma in eclipse."""
    s = slice(max(start, run.k0), None)
    e, sig, on = run.error[s], run.sigma()[s], np.asarray(lit, dtype=bool)[s]
    out = {}
    for name, m in (("lit", on), ("eclipse", ~on)):
        if m.any():
            out[f"rms_{name}_deg"] = np.round(np.degrees(np.sqrt(np.mean(e[m] ** 2, axis=0))), 3).tolist()
            out[f"mean_3sigma_{name}_deg"] = np.round(np.degrees(3 * sig[m].mean(axis=0)), 3).tolist()
    if (~on).any():
        out["peak_3sigma_eclipse_deg"] = np.round(np.degrees(3 * sig[~on].max(axis=0)), 3).tolist()
    return out


def autocorrelation_time(x, max_lag: int = 3000) -> float:
    """Integrated autocorrelation time [samples] 1 + 2 sum rho(l), summed up to the first negative rho
    (Sokal's window; the number of independent samples of a mean is len(x) / tau)."""
    x = np.asarray(x, dtype=float) - np.mean(x)
    v = x @ x
    rho = np.array([x[: len(x) - k] @ x[k:] / v for k in range(1, min(max_lag, len(x) - 1))])
    cut = int(np.argmax(rho < 0)) if np.any(rho < 0) else rho.size
    return float(1.0 + 2.0 * rho[:cut].sum())


def ensemble(truth, use_sun: bool, a) -> dict:
    """Mean NEES over ``a.seeds`` seeds: mean, standard error, std of the single-run means, and that std
    predicted from the autocorrelation time (sqrt(6 tau / n): chi2(3) has variance 6)."""
    means, taus, n = [], [], 0
    for s in range(a.seed, a.seed + a.seeds):
        x = E.run_mekf(truth, seed=s, use_sun=use_sun).nees[int(a.skip):]
        means.append(float(x.mean()))
        taus.append(autocorrelation_time(x))
        n = x.size
    m = np.array(means)
    return dict(seeds=a.seeds, nees_mean=round(float(m.mean()), 3), sem=round(float(m.std(ddof=1) / np.sqrt(m.size)), 3),
                single_run_std=round(float(m.std(ddof=1)), 3), tau_s=round(float(np.mean(taus)), 0),
                predicted_std=round(float(np.sqrt(6 * np.mean(taus) / n)), 3), min=round(float(m.min()), 2),
                max=round(float(m.max()), 2))


if __name__ == "__main__":
    main()
