"""The torquer watch in batched full-stack flights (sim/batch_torquer.py): false detections and a stuck torquer.

B runs of the full stack from POINTING (``simulate_batch`` with the modes and the estimator, its validity gate on),
full environment, each on its own orbit (RAAN uniform over 360 deg, epoch over 2026) from up to 2 deg and 2e-4 rad/s
of error, residual dipole (1, 1, 1) + N(0, 0.3^2) A m^2, the default sensor suite (100 nT, sigma_v 1e-4, sigma_u
1e-6, gyro bias (40, -60, 30) deg/h, 0.5 deg sun), shipped gains ``config/gains/sigma_60.yaml``, 50 A m^2 per axis.
The watch (the attitude_estimator node's parameters) is replayed over the recorded inputs of every run. Prints the
fault-free runs' verdicts, then per onset of the fault (the same runs, the same fault from each onset): the first
torquer declared; the runs declaring the faulty axis within 600 s (first or after another), when, with what kind at
the end; how long POINTING lasted after
the onset (the node runs the watch in POINTING and an ACQUISITION after it, not in DETUMBLE or SAFE). A run that
starts in eclipse fixes its attitude from the
magnetometer alone, is not valid within attitude_loss_time and comes back to POINTING only after a detumble and an
acquisition (~2400-4000 s): at an early onset it is not in POINTING and counts for nothing.

    python bench/torquer_batch.py --runs 20 --orbits 2 --onsets 5500          # 40 s of CPU (2 shared cores, load 4-6)
    python bench/torquer_batch.py --runs 20 --orbits 0.25 --onsets 700 1500 2500 3500 4500 5500 --window 700   # 40 s

The figures: docs/campaigns.md#the-torquer-watch.
"""
from __future__ import annotations

import argparse
import time
from datetime import datetime, timedelta

import numpy as np

from magtune_core.design.gains import load_gains
from magtune_core.design.params import load_spacecraft
from magtune_core.design.sensors import default_suite
from magtune_core.onboard.modes import ACQUISITION, POINTING
from magtune_core.onboard.modes_kernel import MODE_CODE
from magtune_core.onboard.torquer_watch import AXES
from magtune_core.sim.batch import BatchEstimator, BatchModes, BatchRuns, SensorNoise, simulate_batch
from magtune_core.sim.batch_torquer import replay, watch_params
from magtune_core.sim.fullenv import FullEnvironmentOptions


def runs_of(n: int, seed: int):
    """The n dispersed runs (module docstring)."""
    g, p = load_gains("config/gains/sigma_60.yaml"), load_spacecraft("config/spacecraft.yaml")
    rng = np.random.default_rng(seed)
    su = default_suite()
    ax = rng.standard_normal((n, 3))
    ax /= np.linalg.norm(ax, axis=1, keepdims=True)
    ang = np.radians(2.0) * rng.uniform(size=n)
    q0 = np.c_[np.cos(ang / 2), np.sin(ang / 2)[:, None] * ax]
    dw0 = 2e-4 * rng.uniform(-1.0, 1.0, (n, 3))
    opts = [FullEnvironmentOptions(raan_deg=360.0 * rng.uniform(), epoch=datetime(2026, 1, 1) + timedelta(
        days=365.0 * rng.uniform())) for _ in range(n)]
    sens = SensorNoise(np.full(n, su.magnetometer.noise_std), np.zeros((n, 3)), np.zeros(n), np.tile(su.gyro.bias, (n, 1)),
                       np.zeros(n), [[seed, i, 1] for i in range(n)], gyro_arw=np.full(n, su.gyro.arw),
                       gyro_rrw=np.full(n, su.gyro.rrw))
    return p, BatchRuns(g.K, np.tile(np.asarray(p.inertia, float), (n, 1)), 1.0 + 0.3 * rng.standard_normal((n, 3)),
                        np.full(n, 50.0), q0, dw0, p, "full", opts, sens)


def fly(p, runs, steps: int, faults=()):
    """One batch: the detections, the mode series and the CPU of the run and of the replay."""
    est = BatchEstimator(validity_gate=True, torquer_watch=True)
    c0 = time.process_time()
    res = simulate_batch(runs, ts=1.0, steps=steps, substeps=2, full_series=True, estimator=est,
                         modes=BatchModes(initial_mode=POINTING), faults=faults)
    c1 = time.process_time()
    det = replay(res.torquer_inputs, watch_params(est, p, 1.0))
    return det, res, c1 - c0, time.process_time() - c1


def _p50(v) -> float:
    f = v[np.isfinite(v)]
    return float(np.median(f)) if f.size else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--orbits", type=float, default=2.0, help="run length of the fault-free batch and, without "
                    "--window, of every faulty one [nominal orbits]")
    ap.add_argument("--onsets", type=float, nargs="*", default=[5500.0], help="onsets of the stuck torquer [s]")
    ap.add_argument("--window", type=float, default=0.0, help="faulty runs end this long after their onset [s] (0: "
                    "--orbits)")
    ap.add_argument("--axis", default="y")
    ap.add_argument("--value", type=float, default=25.0)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    p, runs = runs_of(a.runs, a.seed)
    steps = int(round(a.orbits * p.orbit_period))
    det, res, cs, cr = fly(p, runs, steps)
    print(f"fault-free: {a.runs} runs x {steps} s: {int((det.axis >= 0).sum())} named a torquer "
          f"{[(det.unit(r), det.time[r], det.kind[r]) for r in np.nonzero(det.axis >= 0)[0]]}; active "
          f"{100 * res.torquer_inputs.active.mean():.1f} % of the steps; CPU run {cs:.1f} s, replay {cr:.1f} s")
    axis = AXES.index(a.axis)
    for t0 in a.onsets:
        n = int(t0 + a.window) if a.window > 0 else steps
        det, res, cs, cr = fly(p, runs, n, (f"torquer_stuck@{t0:g},axis={a.axis},value={a.value:g}",))
        pnt = res.mode[:, int(t0):] == MODE_CODE[POINTING]
        watched = pnt | (res.mode[:, int(t0):] == MODE_CODE[ACQUISITION])  # the modes the node runs the watch in
        lasted = np.where(pnt.all(1) | ~pnt[:, 0], np.nan, np.argmin(pnt, 1))
        dropped = int(np.sum(pnt[:, 0] & ~watched.all(1)))
        ta = det.axis_time[:, axis]  # the faulty axis declared, first or after another
        hit = (ta >= t0) & (ta <= t0 + 600.0)
        delay = ta[hit] - t0
        kinds = {str(k): int(c) for k, c in zip(*np.unique([det.axis_kind(r, axis) for r in np.flatnonzero(hit)],
                                                           return_counts=True))}
        on = res.torquer_inputs.active[:, int(t0)]  # the watch running at the onset (torquer_watch.watch_mode)
        print(f"onset {t0:g} s: watched at the onset {int(on.sum())} / {a.runs} (POINTING "
              f"{int(pnt[:, 0].sum())}; the others in DETUMBLE or a capture after a start without a valid estimate); torquer "
              f"{a.axis} declared within 600 s in {int(hit.sum())}"
              + (f", delay p50 / p95 / max {np.percentile(delay, 50):.0f} / {np.percentile(delay, 95):.0f} / "
                 f"{delay.max():.0f} s" if hit.any() else "")
              + f"; another axis first {int(np.sum((det.axis >= 0) & (det.axis != axis)))}, before the onset "
              f"{int(np.sum(det.time < t0))}, none {int(np.sum(on & (det.axis < 0)))}; kinds {kinds}; POINTING left after the "
              f"onset in {int(np.isfinite(lasted).sum())} runs (after {_p50(lasted):.0f} s, median), ACQUISITION too in "
              f"{dropped}; CPU run {cs:.1f} s, replay {cr:.1f} s")
        for r in np.nonzero((~hit | (det.axis != axis)) & on)[0]:
            print(f"   run {r}: first {det.unit(r) or 'none'} at {det.time[r]:g} s ({det.kind[r]}), torquer {a.axis} at "
                  f"{ta[r]:g} s ({det.axis_kind(r, axis)}), POINTING for {lasted[r]:g} s after the onset")


if __name__ == "__main__":
    main()
