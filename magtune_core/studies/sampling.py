"""Sampling-period study (paper section 5): the digital sample-and-hold controller at Ts.

``magtune sampling [--sigmas 60,120,240] [--ts 1,2,5,10,20,30] [--orbits 5] [--environment full]``
(the command: :mod:`magtune_core.cli.sampling`)

The paper implements the controllers "in digital form, using a conventional sample and hold
scheme" with Ts = 1 s and reports no significant degradation up to Ts = 20 s. This command runs
the offline equivalent of the full-environment SIL (``simulate(..., environment=...)``, which
the SIL reproduces bit for bit, tests/sim/test_fullenv.py) for every (sigma, Ts): the tuned gain
``config/gains/sigma_<sigma>.yaml`` (the same continuous-time design K at every Ts), dw(0) of
paper eq. (31), dipole saturation 50 A m^2 per axis and the 0.1 uT weak-field guard of
``simulate``. The plant is integrated with RK4 steps of at most 0.5 s
(``fullenv.substeps_for``), so only the controller's sample-and-hold changes with Ts.

Figures of merit per run (``t_k = k Ts`` controller instants, T the nominal orbit period):

* RMS |dq_R| over orbits 2-5: sqrt(mean |dq_R(t_k)|^2) for T <= t_k <= 5 T (paper Fig. 3);
* peak |m|: max_k |m(t_k)| of the (saturated) commanded dipole [A m^2] (paper Figs. 2-3);
* settling time t_s: the first t_k after which |dq_R| stays below 2 x the orbits-2-5 RMS of
  the *reference run* (smallest Ts of the grid, same sigma) until the end of the run. A fixed
  reference threshold per sigma keeps t_s comparable across Ts (a threshold relative to each
  run's own RMS would reward a degraded steady state).

Runs are distributed over ``--workers`` processes (``base.workers.worker_pool``: they die with
the command); each run is a deterministic fixed-step integration (no noise), so the table does not depend on the number
of workers. ``--backend sil`` runs every case through ``magtune sil`` instead (the three ROS 2
nodes over DDS, lockstep); the trajectories, hence the table, are identical. Outputs: ``docs/sampling.md`` (table + verdict on the paper's claim),
``docs/sampling.png`` (matplotlib, Agg) and ``docs/sampling.json`` (raw numbers).
"""
from __future__ import annotations

import contextlib
import time
from pathlib import Path

import numpy as np

from ..base.ament import ROOT
from ..base.atomic import atomic_savefig, atomic_write
from ..base.workers import worker_pool
from ..design.gains import load_gains
from ..design.params import load_spacecraft
from ..onboard.law import DEFAULT_DIPOLE_LIMIT
from ..sim.fullenv import FullEnvironmentOptions, substeps_for
from ..sim.metrics import settling_time
from ..sim.simulate import simulate

DEFAULT_SIGMAS = (60.0, 120.0, 240.0)
DEFAULT_TS = (1.0, 2.0, 5.0, 10.0, 20.0, 30.0)
#: a change of an RMS / peak / settling figure above this fraction of the Ts-reference value
#: counts as "significant degradation" in the verdict
SIGNIFICANT = 0.10
SETTLING_FACTOR = 2.0


def _run_one(job: dict) -> dict:
    """One (sigma, Ts) closed loop; returns the figures and the |dq_R|, |m| histories (decimated)."""
    p = load_spacecraft(job["spacecraft"], warn=False)  # the command warned
    K = load_gains(job["gains"]).K
    ts = float(job["ts"])
    opts = FullEnvironmentOptions(**job["env_options"]) if job["environment"] == "full" else None
    t0 = time.perf_counter()
    if job.get("backend", "offline") == "sil":  # the ROS 2 nodes over DDS (same trajectory, bit for bit)
        from ..ros.sil import run_sil  # the ROS layer only when asked for

        res = run_sil(job["gains"], orbits=job["orbits"], ts=ts, substeps=substeps_for(ts),
                      spacecraft=job["spacecraft"], environment=job["environment"], env_options=opts).result
        res.info["saturated_steps"] = int(np.count_nonzero(np.any(np.abs(res.m) >= DEFAULT_DIPOLE_LIMIT, axis=1)))
        res.info["substeps"] = substeps_for(ts)
    else:
        res = simulate(K, p, ts=ts, orbits=job["orbits"], substeps=substeps_for(ts), environment=job["environment"],
                       env_options=opts)
    wall = time.perf_counter() - t0
    f = res.figures_of_merit()
    dq = np.linalg.norm(res.x[:, :3], axis=1)
    mn = np.linalg.norm(res.m, axis=1)
    every = max(1, int(round(30.0 / ts)))  # ~30 s resolution for the plot
    return dict(sigma=job["sigma"], ts=ts, rms_dq=f["rms_dq"], peak_m=f["peak_m"], peak_dq=f["peak_dq"],
                final_dq=f["final_dq"], finite=bool(np.all(np.isfinite(res.x))), orbit_period=res.orbit_period,
                saturated_steps=int(res.info["saturated_steps"]), substeps=int(res.info["substeps"]), wall=wall,
                t=res.t.tolist(), dq=dq.tolist(), t_plot=res.t[::every].tolist(), dq_plot=dq[::every].tolist(),
                m_plot=mn[::every].tolist())


def run_study(sigmas=DEFAULT_SIGMAS, ts_list=DEFAULT_TS, orbits: float = 5.0, environment: str = "full",
              env_options: dict | None = None, workers: int = 2, gains_dir=None, spacecraft=None,
              backend: str = "offline", progress=None) -> list[dict]:
    """All (sigma, Ts) runs, with settling times; sorted by sigma then Ts. ``progress(i, n, row)``
    is called as each run finishes (in job order)."""
    gains_dir = Path(gains_dir or ROOT / "config" / "gains")
    spacecraft = str(spacecraft or ROOT / "config" / "spacecraft.yaml")
    jobs = [dict(sigma=float(s), ts=float(ts), orbits=float(orbits), environment=environment,
                 env_options=dict(env_options or {}), gains=str(gains_dir / f"sigma_{s:g}.yaml"),
                 spacecraft=spacecraft, backend=backend) for s in sigmas for ts in sorted(ts_list)]
    for j in jobs:
        if not Path(j["gains"]).is_file():
            raise FileNotFoundError(f"gains file not found: {j['gains']}")
    rows = []
    with worker_pool(workers) if workers > 1 else contextlib.nullcontext() as ex:
        for row in (ex.map(_run_one, jobs) if ex else map(_run_one, jobs)):
            rows.append(row)
            if progress:
                progress(len(rows), len(jobs), row)
    for s in sigmas:
        mine = [r for r in rows if r["sigma"] == float(s)]
        ref = min(mine, key=lambda r: r["ts"])
        thr = SETTLING_FACTOR * ref["rms_dq"]
        for r in mine:
            r["settling_threshold"] = thr
            r["settling_time"] = settling_time(r["t"], r["dq"], thr)
    for r in rows:
        del r["t"], r["dq"]
    return rows


def _verdict(rows, claim_ts: float = 20.0) -> tuple[str, dict]:
    """Worst relative change vs the reference Ts over Ts <= claim_ts, per sigma and figure."""
    worst = {}
    lines = []
    for s in sorted({r["sigma"] for r in rows}):
        mine = sorted([r for r in rows if r["sigma"] == s], key=lambda r: r["ts"])
        ref = mine[0]
        upto = [r for r in mine if r["ts"] <= claim_ts]
        d = {}
        for key in ("rms_dq", "peak_m", "settling_time"):
            vals = [(r[key] - ref[key]) / ref[key] if np.isfinite(r[key]) and ref[key] else float("inf")
                    for r in upto]
            d[key] = (min(vals), max(vals))
        worst[s] = d
        rng = {k: f"{100 * a:+.1f} % .. {100 * b:+.1f} %" for k, (a, b) in d.items()}
        ok = all(b <= SIGNIFICANT for _, b in d.values())
        lines.append(f"sigma = {s:g}, Ts = {ref['ts']:g} .. {upto[-1]['ts']:g} s, change vs Ts = {ref['ts']:g} s: "
                     f"RMS abs(dq_R) {rng['rms_dq']}, peak abs(m) {rng['peak_m']}, settling time "
                     f"{rng['settling_time']} -> " + ("no significant degradation" if ok else "significant degradation")
                     + f" (criterion: no figure worse by more than {100 * SIGNIFICANT:.0f} %)")
    return "\n".join(f"* {x}" for x in lines), worst


def write_markdown(rows, path, meta: dict) -> str:
    """The study as markdown: set-up, definitions, the table, the verdict."""
    lines = [
        "# Sampling-period study (paper section 5)",
        "",
        f"Generated by `{meta['command']}` ({meta['wall']:.0f} s on {meta['workers']} workers).",
        "",
        f"Set-up: environment **{meta['environment']}**"
        + (" (J2 orbit, IGRF-14 degree 10 along the actual orbit, gravity gradient with the actual radius, "
           "residual dipole [1, 1, 1] A m^2, Harris-Priester drag, SRP with eclipse; see docs/environment.md)"
           if meta["environment"] == "full" else " (eq. 26 field, circular orbit, gravity gradient, residual dipole)")
        + f", {meta['orbits']:g} orbits of T = {rows[0]['orbit_period']:.1f} s, dw(0) = [1e-3, 2e-3, 0] rad/s, "
        "tuned gains `config/gains/sigma_*.yaml` (the same K at every Ts), dipole saturation 50 A m^2 per axis, "
        "weak-field guard 0.1 uT, plant RK4 step <= 0.5 s (only the controller's sample-and-hold changes).",
        "",
        "Definitions: RMS |dq_R| over orbits 2-5 at the controller instants; peak |m| of the commanded "
        "(saturated) dipole; settling time t_s = first instant after which |dq_R| stays below "
        f"{SETTLING_FACTOR:g} x the orbits-2-5 RMS of the smallest-Ts run of the same sigma (threshold column) "
        "until the end of the run.",
        "",
        "| sigma | Ts [s] | RMS abs(dq_R), orbits 2-5 | peak abs(m) [A m^2] | settling time [s] | threshold | "
        "peak abs(dq_R) | saturated steps |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ts_ = "not settled" if not np.isfinite(r["settling_time"]) else f"{r['settling_time']:.0f}"
        lines.append(f"| {r['sigma']:g} | {r['ts']:g} | {r['rms_dq']:.4e} | {r['peak_m']:.3f} | {ts_} | "
                     f"{r['settling_threshold']:.3e} | {r['peak_dq']:.4e} | {r['saturated_steps']} |")
    text, _ = _verdict(rows)
    lines += ["", "![sampling study](sampling.png)", "", "## The paper's claim (no significant degradation up to Ts = 20 s)",
              "", text, ""]
    if meta.get("conclusion"):
        lines += [meta["conclusion"], ""]
    md = "\n".join(lines)
    atomic_write(path, md)
    return md


def plot(rows, path) -> None:
    """Figures of merit vs Ts per sigma, and |dq_R|(t) at the extreme Ts for each sigma."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sigmas = sorted({r["sigma"] for r in rows})
    colors = dict(zip(sigmas, ["tab:blue", "tab:green", "tab:red", "tab:purple", "tab:orange"]))
    fig, ax = plt.subplots(2, 2, figsize=(11, 7.5))
    for s in sigmas:
        mine = sorted([r for r in rows if r["sigma"] == s], key=lambda r: r["ts"])
        tsv = [r["ts"] for r in mine]
        ax[0, 0].plot(tsv, [r["rms_dq"] for r in mine], "o-", color=colors[s], label=f"sigma = {s:g}")
        ax[0, 1].plot(tsv, [r["peak_m"] for r in mine], "o-", color=colors[s])
        ax[1, 0].plot(tsv, [r["settling_time"] for r in mine], "o-", color=colors[s])
        for r, style in ((mine[0], "-"), (mine[-1], ":")):
            T = r["orbit_period"]
            ax[1, 1].semilogy(np.asarray(r["t_plot"]) / T, r["dq_plot"], style, color=colors[s], lw=0.8,
                              label=f"sigma {s:g}, Ts {r['ts']:g} s")
    for a, yl in ((ax[0, 0], "RMS |dq_R|, orbits 2-5"), (ax[0, 1], "peak |m| [A m^2]"),
                  (ax[1, 0], "settling time [s]")):
        a.set_xscale("log")
        a.set_xlabel("Ts [s]")
        a.set_ylabel(yl)
        a.axvline(20.0, color="gray", ls="--", lw=0.8)
        a.grid(True, which="both", alpha=0.3)
    ax[0, 0].set_yscale("log")
    ax[0, 0].legend()
    ax[1, 1].set_xlabel("t / T [orbits]")
    ax[1, 1].set_ylabel("|dq_R|")
    ax[1, 1].legend(fontsize=7)
    ax[1, 1].grid(True, which="both", alpha=0.3)
    fig.suptitle("Sample-and-hold period study (dashed line: the paper's Ts = 20 s)")
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)
