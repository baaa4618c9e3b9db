"""Where a full-stack batched run-step goes: the batch with its on-board parts switched on one by one.

The same B runs (bench/torquer_batch.py's: full environment, each on its own orbit and epoch, from POINTING with
up to 2 deg and 2e-4 rad/s of error, the default sensor suite, shipped gains) for N steps, in one process, each
configuration after a warm-up of the same one (numba's compiled code loaded, the environment's first rows):

    truth         the modes on the true attitude (the truth-fed deployment's loop)
    + filter      the MEKF in the loop (BatchEstimator: propagation, magnetometer and sun updates)
    + validity    its validity gate (onboard.validity), which the modes fly with the estimator
    + sensor      the sensor watch and its recovery (onboard.sensor_watch), as the node runs them
    + record      the torquer watch's inputs recorded per step (BatchEstimator.torquer_watch)
    replay        sim.batch_torquer.replay of those inputs (after the run: the watch has no feedback)

Prints the process CPU per run-step of each and the difference to the previous line, and the machine load.
Figures: bench/README.md ("The full stack").

    python bench/stack_parts.py [--runs 100] [--orbits 1]      # from the repository root
"""
from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace

from torquer_batch import runs_of  # bench/

from magtune_core.onboard.modes import POINTING
from magtune_core.sim.batch import BatchEstimator, BatchModes, simulate_batch
from magtune_core.sim.batch_torquer import replay, watch_params


def configurations():
    """(label, estimator or None) in the order the parts are added."""
    base = BatchEstimator(validity_gate=False, sensor_watch=False, torquer_watch=False)
    return [("truth", None), ("+ filter", base), ("+ validity", replace(base, validity_gate=True)),
            ("+ sensor", replace(base, validity_gate=True, sensor_watch=True)),
            ("+ record", replace(base, validity_gate=True, sensor_watch=True, torquer_watch=True))]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--orbits", type=float, default=1.0)
    a = ap.parse_args()
    p, runs = runs_of(a.runs, 1)
    steps = int(round(a.orbits * p.orbit_period))
    n = a.runs * steps
    print(f"{a.runs} runs x {steps} steps, full environment, from POINTING; load before {os.getloadavg()[0]:.2f}")
    prev = None
    for label, est in configurations():
        kw = dict(ts=1.0, steps=steps, substeps=2, full_series=True, estimator=est, modes=BatchModes(initial_mode=POINTING))
        simulate_batch(runs, **{**kw, "steps": 60})  # warm-up: compiled code loaded
        c0 = time.process_time()
        res = simulate_batch(runs, **kw)
        us = 1e6 * (time.process_time() - c0) / n
        step = "" if prev is None else f"  (+{us - prev:.2f})"
        print(f"{label:12s} {us:7.2f} us per run-step{step}", flush=True)
        prev = us
    c0 = time.process_time()
    replay(res.torquer_inputs, watch_params(est, p, 1.0))
    print(f"{'replay':12s} {1e6 * (time.process_time() - c0) / n:7.2f} us per run-step (after the run); load after "
          f"{os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
