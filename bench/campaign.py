"""Monte Carlo throughput: per-run loop vs the batched engine on 1 and on 2 Dask workers.

    . scripts/env.sh; nice python bench/campaign.py [--runs 200] [--loop-runs 3] [--orbits 5] [--batch-size 100]
    . scripts/env.sh; nice python bench/campaign.py --deployment [--runs 200] [--orbits 10] [--batch-size 100]

The issue's measurement (bench/README.md, docs/campaigns.md): ``--runs 1000 --orbits 5 --batch-size 500 --loop-runs 2``.

One spec (config/campaigns/example.yaml with the sensor noise switched off, so the per-run
``simulate`` computes exactly the same runs: the bench checks that the batched figures equal the
loop's), the full environment (J2 orbit, IGRF-14 degree 10, gravity gradient, drag, SRP; epoch and
RAAN dispersed, so every run has its own orbit and environment table), 5 orbits at Ts = 1 s.
Prints runs/s of each engine, the ratios, the machine load before and after each measurement,
the time 1,000 runs would take on 2 workers at the measured rate (the issue's target: 2 min), and
the CPU time per run of each engine (process CPU of the loop, task CPU of the Dask workers): on a
shared machine the wall-clock rates follow the load, the CPU times much less.

``--deployment``: config/campaigns/deployment.yaml instead (the flight modes from tumbling at up to 5 deg/s
per axis, uniformly random attitudes, noise on), on a LocalCluster of 2 workers only; prints runs, orbits,
RK4 sub-steps, wall time, task CPU per run, the load before and after, and the 1,000-run time extrapolated
from the measured rate and from the CPU per run (the issue's target: 1,000 ten-orbit deployments in 2 min).
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from magtune_core.sim.simulate import simulate
from magtune_core.studies import campaign

ROOT = Path(__file__).resolve().parents[1]


def load() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spec", default=str(ROOT / "config" / "campaigns" / "example.yaml"))
    ap.add_argument("--runs", type=int, default=200, help="runs of each batched measurement (default 200)")
    ap.add_argument("--loop-runs", type=int, default=3, help="runs of the per-run loop (default 3)")
    ap.add_argument("--orbits", type=float, default=5.0)
    ap.add_argument("--batch-size", type=int, default=100)
    ap.add_argument("--json", help="also write the figures here")
    ap.add_argument("--deployment", action="store_true", help="bench config/campaigns/deployment.yaml on 2 workers")
    a = ap.parse_args()
    if a.deployment:
        return deployment(a)
    spec = campaign.load_spec(a.spec)
    spec.campaign.update(orbits=a.orbits, batch_size=a.batch_size)
    spec.dispersions.update(mag_noise_std=0.0, mag_bias_std=0.0, gyro_noise_std=0.0, gyro_bias_std=0.0,
                            attitude_noise_std=0.0)
    steps = spec.steps()
    print(f"campaign bench: {spec.campaign['environment']} environment, {a.orbits:g} orbits = {steps} steps of "
          f"{spec.campaign['ts']:g} s, {spec.substeps.levels} RK4 steps per Ts; cores {os.cpu_count()}")
    out = {}

    # 1. per-run loop: simulate() on the same dispersed runs, one after the other, in this process
    l0 = load()
    t0, c0 = time.perf_counter(), time.process_time()
    loop_rows = []
    for i in range(a.loop_runs):
        r = campaign.draw_run(spec, i)
        p = replace(spec.p, inertia=r["inertia"])
        res = simulate(spec.K[0], p, ts=spec.campaign["ts"], steps=steps, substeps=spec.substeps.most, dw0=r["dw0"], q0=r["q0"],
                       dipole_limit=r["dipole_limit"], residual_dipole=r["residual_dipole"], environment="full",
                       env_options=spec.env_options(r["epoch"], r["raan_deg"]))
        loop_rows.append(float(np.linalg.norm(res.m, axis=1).max()))
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    out["loop"] = dict(runs=a.loop_runs, wall=dt, runs_per_s=a.loop_runs / dt, cpu_s_per_run=cpu / a.loop_runs,
                       load_before=l0, load_after=load())
    print(f"per-run loop      : {a.loop_runs:5d} runs {dt:8.1f} s  {a.loop_runs / dt:8.3f} runs/s  CPU {cpu / a.loop_runs:7.3f} "
          f"s/run   load {l0} -> {load()}")

    # 2./3. batched engine as Dask tasks on a LocalCluster of 1 and 2 workers
    for workers in (1, 2):
        with tempfile.TemporaryDirectory() as tmp:
            l0 = load()
            meta = campaign.run_campaign(spec, a.runs, Path(tmp) / "o", workers=workers, progress=False)
            cols = campaign.read_runs(Path(tmp) / "o")
        key = f"batched_{workers}w"
        out[key] = dict(runs=a.runs, wall=meta["wall"], runs_per_s=a.runs / meta["wall"], load_before=l0,
                        load_after=load(), ok=meta["counts"]["ok"], cpu_s_per_run=meta["cpu_s_per_run"])
        print(f"batched, {workers} worker{'s' if workers > 1 else ' '}: {a.runs:5d} runs {meta['wall']:8.1f} s  "
              f"{a.runs / meta['wall']:8.3f} runs/s  CPU {meta['cpu_s_per_run']:7.3f} s/run   load {l0} -> {load()}  "
              f"(ok {meta['counts']['ok']})")
        # same runs, same numbers: the batched engine equals the loop (peak |m| of the first runs)
        dev = max(abs(cols["peak_dipole"][i] - loop_rows[i]) for i in range(min(a.loop_runs, a.runs)))
        out[key]["max_peak_dipole_deviation_vs_loop"] = dev
        assert dev < 1e-9, dev
    r1, r2, rl = out["batched_1w"]["runs_per_s"], out["batched_2w"]["runs_per_s"], out["loop"]["runs_per_s"]
    print(f"ratios: batched 1 worker / loop = {r1 / rl:.1f}x, 2 workers / 1 worker = {r2 / r1:.2f}x, "
          f"2 workers / loop = {r2 / rl:.1f}x")
    print(f"1000 runs on 2 workers at the measured rate: {1000 / r2:.0f} s (target 120 s)")
    cl, cb = out["loop"]["cpu_s_per_run"], out["batched_2w"]["cpu_s_per_run"]
    print(f"CPU per run: loop {cl:.3f} s, batched {cb:.3f} s ({cl / cb:.1f}x less); 1000 runs on 2 idle cores: "
          f"{1000 * cb / 2:.0f} s (CPU-time extrapolation; needs the cores to be free)")
    out.update(ratios=dict(batched1_over_loop=r1 / rl, two_over_one=r2 / r1), extrapolated_1000_runs_2w_s=1000 / r2,
               steps=steps, batch_size=a.batch_size)
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))


def deployment(a) -> None:
    """The deployment campaign (``--deployment``) on a LocalCluster of 2 workers: wall, CPU, load, extrapolation."""
    spec = campaign.load_spec(ROOT / "config" / "campaigns" / "deployment.yaml" if a.spec.endswith("example.yaml")
                              else a.spec)
    spec.campaign.update(orbits=a.orbits, batch_size=a.batch_size)
    print(f"deployment bench: {spec.campaign['environment']} environment, {a.runs} runs x {a.orbits:g} orbits = "
          f"{spec.steps()} steps of {spec.campaign['ts']:g} s, {spec.substeps.levels} RK4 steps per Ts (by rate), batch {a.batch_size}; "
          f"cores {os.cpu_count()}")
    with tempfile.TemporaryDirectory() as tmp:
        l0 = load()
        meta = campaign.run_campaign(spec, a.runs, Path(tmp) / "o", workers=2, progress=False)
        l1 = load()
        cols = campaign.read_runs(Path(tmp) / "o")
    settled = np.isfinite(cols["settled_time"].astype(float))
    wall, cpu = meta["wall"], meta["cpu_s_per_run"]
    print(f"2 workers: {a.runs} runs {wall:.1f} s wall, {a.runs / wall:.2f} runs/s, task CPU {cpu:.3f} s/run, "
          f"load {l0} -> {l1}; ok {meta['counts']['ok']}, settled in POINTING {int(settled.sum())}, passed {meta['passed']}")
    for k in ("detumble_time", "settled_time"):
        v = cols[k].astype(float)
        v = v[np.isfinite(v)]
        if v.size:
            print(f"  {k} 5/50/95 %: " + " / ".join(f"{x:.0f}" for x in np.percentile(v, (5, 50, 95))) + " s")
    print(f"1000 runs at the measured rate (under this load): {1000 * wall / a.runs:.0f} s; from the CPU per run on "
          f"2 idle cores: {1000 * cpu / 2:.0f} s (target 120 s; extrapolations, not a measurement)")
    if a.json:
        Path(a.json).write_text(json.dumps(dict(runs=a.runs, orbits=a.orbits, substeps=list(spec.substeps.levels), wall=wall,
                                                cpu_s_per_run=cpu, load_before=l0, load_after=l1,
                                                batch_size=a.batch_size), indent=1))


if __name__ == "__main__":
    main()
