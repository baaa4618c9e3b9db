"""Report of a Monte Carlo campaign directory (``magtune campaign-report DIR``).

Reads ``runs.parquet`` and ``histories/`` written by :mod:`magtune_core.studies.campaign` and
writes ``envelopes.png`` (5/50/95 % envelopes over time of the pointing error [deg] and of |m|
[A m^2], ok runs), ``histograms.png`` (the figures of merit of the ok runs) and ``summary.md``
(set-up, counts by status, pass rate, percentiles of every figure, every failed or diverged
run with its message, the worst runs with their parameters). Percentiles are numpy's linear
interpolation between order statistics; with N runs the 5 % / 95 % envelopes rest on about
0.05 N runs each, so they are rough below N ~ 100 (said in the summary).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..base.atomic import atomic_savefig, atomic_write
from ..design import faults as fl
from ..onboard.torquer_watch import AXES
from .campaign import ESTIMATION_FIGURES, FIGURES, MODE_FIGURES, STATUSES, read_histories, read_runs

PERCENTILES = (5.0, 50.0, 95.0)
#: Worst runs listed in summary.md (ranked by max pointing error after settling; not settled first).
WORST = 10
#: Parameters shown for the worst runs.
PARAMS = ("inertia_x", "inertia_y", "inertia_z", "residual_dipole_x", "residual_dipole_y", "residual_dipole_z",
          "attitude_angle_deg", "dw0_x", "dw0_y", "dw0_z", "epoch", "raan_deg", "dipole_limit")


def envelopes(h: dict, key: str, ok: np.ndarray) -> np.ndarray:
    """(3, n_t) 5/50/95 % percentiles over the ok runs of history ``key`` (nan where none)."""
    x = np.asarray(h[key], dtype=float)[ok]
    if x.shape[0] == 0:
        return np.full((3, len(h["t"])), np.nan)
    return np.nanpercentile(x, PERCENTILES, axis=0)


def figures_of(cols: dict) -> tuple:
    """(name, unit) of the figures the campaign's rows carry: FIGURES, MODE_FIGURES for a deployment campaign,
    ESTIMATION_FIGURES with the estimator in the loop."""
    return FIGURES + tuple(f for f in MODE_FIGURES + ESTIMATION_FIGURES if f[0] in cols)


def deployment_failures(cols: dict) -> np.ndarray:
    """Indices of the ok runs of a deployment campaign that never reached POINTING or did not end settled in it."""
    if "settled_time" not in cols:
        return np.zeros(0, dtype=int)
    ok = cols["status"].astype(str) == "ok"
    return np.nonzero(ok & ~np.isfinite(cols["settled_time"].astype(float)))[0]


def _deployment_lines(cols: dict) -> list:
    """summary.md section of a deployment campaign: how many runs reached and settled in POINTING, the failures."""
    if "settled_time" not in cols:
        return []
    ok = cols["status"].astype(str) == "ok"
    reached = cols["reached_pointing"].astype(bool) & ok
    fails = deployment_failures(cols)
    out = ["## Deployment", "", f"Reached POINTING: {int(reached.sum())} / {int(ok.sum())} ok runs; settled in POINTING at "
           f"the end: {int(ok.sum()) - fails.size}. Times in the table above: detumble_time (DETUMBLE left), "
           "pointing_time (POINTING entered), settled_time (from then on in POINTING with the error below the settle "
           "threshold); transitions: mode changes per run.", ""]
    if fails.size:
        out += ["| run | gains | final mode | detumble [s] | POINTING [s] | reason |", "|---|---|---|---|---|---|"]
        for i in fails:
            out.append(f"| {cols['run'][i]} | {cols['gains'][i]} | {cols['final_mode'][i]} | "
                       f"{_fmt(cols['detumble_time'][i])} | {_fmt(cols['pointing_time'][i])} | "
                       f"{cols['fail_reasons'][i] or '-'} |")
    else:
        out.append("No deployment failure: every ok run ended settled in POINTING.")
    return out + [""]


def torquer_outcomes(cols: dict, meta: dict) -> list:
    """The torquer watch's verdicts (rows ``torquer_*``) against the spec's torquer faults, over the ok runs.

    Per torquer fault of ``meta["faults"]`` a dict: ``fault`` (its spec string), ``runs`` (ok runs), ``detected``
    (its axis declared at or after the onset, first or not), ``delays`` (then minus the onset [s]), ``wrong_first``
    (another axis declared first, after the onset), ``early`` (a torquer declared before the onset) and ``kinds``
    ({kind: runs}: what the detections name its axis at the end). Without a torquer fault one dict with ``fault`` None
    and ``named``: the indices of the ok runs that declared a torquer (false detections). Empty when the campaign did
    not run the watch.
    """
    if "torquer_unit" not in cols:
        return []
    ok = cols["status"].astype(str) == "ok"
    unit, t = cols["torquer_unit"].astype(str)[ok], cols["torquer_time"].astype(float)[ok]
    faults = [f for f in fl.from_list(list(meta.get("faults") or [])) if f.kind in fl.TORQUER_KINDS]
    if not faults:
        return [dict(fault=None, runs=int(ok.sum()), named=np.nonzero(ok)[0][unit != ""])]
    out = []
    for f in faults:
        a = AXES[f.axis]
        ta, kind = cols[f"torquer_time_{a}"].astype(float)[ok], cols[f"torquer_kind_{a}"].astype(str)[ok]
        hit = ta >= f.t  # nan: never
        out.append(dict(fault=f.spec, runs=int(ok.sum()), detected=int(hit.sum()), delays=ta[hit] - f.t,
                        wrong_first=int(np.sum((unit != "") & (unit != f"torquer {a}") & (t >= f.t))),
                        early=int(np.sum(t < f.t)), kinds={k: int(np.sum(hit & (kind == k))) for k in dict.fromkeys(kind[hit])}))
    return out


def _torquer_lines(cols: dict, meta: dict) -> list:
    """summary.md section of a campaign with the torquer watch (``estimator.torquer_watch``)."""
    outcomes = torquer_outcomes(cols, meta)
    if not outcomes:
        return []
    lines = ["## Torquer watch", "", "The attitude estimator's torquer watch (onboard/torquer_watch.py), replayed over "
             "every run (sim/batch_torquer.py): the first torquer a run declares, when, and each axis' first "
             "declaration and kind at the end of the run.", ""]
    if outcomes[0]["fault"] is None:
        named = outcomes[0]["named"]
        lines.append(f"No torquer fault injected: **{named.size} / {outcomes[0]['runs']}** ok runs named a torquer "
                     "(false detections).")
        if named.size:
            lines += ["", "| run | gains | first unit | time [s] | kind |", "|---|---|---|---|---|"]
            lines += [f"| {cols['run'][i]} | {cols['gains'][i]} | {cols['torquer_unit'][i]} | "
                      f"{_fmt(cols['torquer_time'][i])} | {cols['torquer_kind'][i]} |" for i in named[:WORST]]
        return lines + [""]
    lines += ["| fault | detected (its axis declared at or after the onset) | time to detect p50 / p95 [s] | "
              "another axis declared first | a torquer declared before the onset | its kind at the end |",
              "|---|---|---|---|---|---|"]
    for o in outcomes:
        n, d = o["runs"], o["detected"]
        ttd = " / ".join(f"{v:.4g}" for v in np.percentile(o["delays"], (50.0, 95.0))) if d else "n/a"
        kinds = ", ".join(f"{k} {v}" for k, v in o["kinds"].items()) or "-"
        lines.append(f"| {o['fault']} | {d} / {n} ({100.0 * d / max(n, 1):.1f} %) | {ttd} | {o['wrong_first']} | "
                     f"{o['early']} | {kinds} |")
    return lines + [""]


def _fmt(v, unit="") -> str:
    if isinstance(v, (float, np.floating)):
        if not np.isfinite(v):
            return "n/a"
        return f"{v:.4g}"
    return str(v)


def worst_runs(cols: dict, n: int = WORST) -> np.ndarray:
    """Indices of the worst ok runs: not settled first (by final error), then by max pointing error."""
    ok = np.nonzero(cols["status"] == "ok")[0]
    mp = cols["max_pointing_deg"][ok].astype(float)
    fin = cols["final_pointing_deg"][ok].astype(float)
    key = np.where(np.isfinite(mp), mp, 1e6 + np.nan_to_num(fin, nan=1e6))
    return ok[np.argsort(-key, kind="stable")[:n]]


def _torquer_line(meta: dict) -> list:
    """The torquers of every run (campaign section ``torquers``: coupling, duty cycle), if the spec set them."""
    tq = meta.get("torquers")
    if not tq:
        return []
    C = np.asarray(tq.get("torquer_coupling", [0.0] * 9), dtype=float)
    off = float(tq.get("torquer_off_time", 0.0))
    duty = (f"off the last {off:g} s of every period ({'compensated' if tq.get('duty_compensation', True) else 'not compensated'}, "
            f"field decay {float(tq.get('torquer_decay_time', 0.0)):g} s)") if off > 0 else "always on"
    return [f"Torquers: coupling into the magnetometer max |C_ij| = {np.abs(C).max():.3g} T/(A m^2), {duty} "
            "(docs/torquers.md)."]


def _substeps(levels) -> str:
    """The RK4 sub-steps of campaign.json (a list of levels; an int in campaigns written before the ladder)."""
    lv = levels if isinstance(levels, list) else [levels]
    return f"{lv[0]} RK4 steps" if len(lv) == 1 else f"{lv[0]}-{lv[-1]} RK4 steps re-chosen from the rate"


def write_report(out) -> str:
    """Plots and summary.md in the campaign directory ``out``; returns the markdown."""
    out = Path(out)
    meta = json.loads((out / "campaign.json").read_text())
    for key in ("wall", "runs_per_second", "cpu_s_per_run"):  # strict JSON writes a non-finite figure as null
        meta[key] = math.nan if meta.get(key) is None else meta[key]
    cols = read_runs(out)
    h = read_histories(out)
    status = cols["status"].astype(str)
    ok = status == "ok"
    n = len(status)
    lines = [f"# Monte Carlo campaign: {meta['name']}", "",
             f"Spec `{meta['spec']}`, seed {meta['seed']}, {meta['runs']} dispersed runs x {len(meta['gains'])} gains "
             f"file(s) = {n} runs; environment **{meta['environment']}**, {meta['orbits']:g} orbits, Ts = "
             f"{meta['ts']:g} s ({_substeps(meta['substeps'])} per Ts), {meta['steps']} controller steps per run.",
             f"Executed on {meta.get('scheduler')} with {meta.get('workers')} worker(s), {meta['batches']} batches of "
             f"<= {meta['batch_size']} runs, {meta['wall']:.1f} s wall ({meta['runs_per_second']:.2f} runs/s; task CPU "
             f"{meta.get('cpu_s_per_run', float('nan')):.3f} s per run).", *_torquer_line(meta), "",
             "## Outcome", "", "| status | runs |", "|---|---|"]
    for s in STATUSES:
        lines.append(f"| {s} | {int(np.sum(status == s))} |")
    passed = cols["passed"].astype(bool)
    lines += [f"| **passed** (ok and every criterion met) | **{int(passed.sum())} / {n} ({100.0 * passed.mean():.1f} %)** |",
              "", "Criteria: " + ", ".join(f"{k} = {v}" for k, v in meta["criteria"].items() if v is not None) + ".", ""]
    if n < 100:
        lines += [f"With {n} runs the 5 % and 95 % percentiles rest on very few runs: read them as indications.", ""]
    lines += ["## Figures of merit (ok runs)", "", "| figure | unit | 5 % | 50 % | 95 % | max | runs with a value |",
              "|---|---|---|---|---|---|---|"]
    for key, unit in figures_of(cols):
        v = cols[key][ok].astype(float)
        f = v[np.isfinite(v)]
        if f.size:
            p5, p50, p95 = np.percentile(f, PERCENTILES)
            lines.append(f"| {key} | {unit} | {p5:.4g} | {p50:.4g} | {p95:.4g} | {f.max():.4g} | {f.size} / {v.size} |")
        else:
            lines.append(f"| {key} | {unit} | n/a | n/a | n/a | n/a | 0 / {v.size} |")
    lines += ["", "Settling time: first instant after which the pointing error stays below "
              f"{meta['criteria']['settle_threshold_deg']:g} deg (n/a: never). Max and RMS pointing error: over the "
              f"steady-state window t >= {meta['criteria']['max_settling_orbits']:g} orbits (the settling limit), the "
              "same for every run. Pointing error: rotation angle between body and orbital axes (true attitude).", ""]
    lines += _deployment_lines(cols)
    lines += _torquer_lines(cols, meta)
    bad = np.nonzero(~ok)[0]
    lines += ["## Failed and diverged runs", ""]
    if bad.size:
        lines += ["| run | gains | status | error |", "|---|---|---|---|"]
        for i in bad:
            lines.append(f"| {cols['run'][i]} | {cols['gains'][i]} | {status[i]} | {str(cols['error'][i]) or '-'} |")
    else:
        lines.append("None.")
    lines += ["", "## Worst runs", "", "Ranked by max pointing error in steady state (runs that never settled first). "
              "Re-run one with the same spec and seed: its parameters depend on (seed, run) only.", "",
              "| run | gains | max pointing [deg] | settling [s] | peak abs(m) | passed | reasons | "
              + " | ".join(PARAMS) + " |", "|" + "---|" * (7 + len(PARAMS))]
    for i in worst_runs(cols):
        lines.append(f"| {cols['run'][i]} | {cols['gains'][i]} | {_fmt(cols['max_pointing_deg'][i])} | "
                     f"{_fmt(cols['settling_time'][i])} | {_fmt(cols['peak_dipole'][i])} | {bool(cols['passed'][i])} | "
                     f"{cols['fail_reasons'][i] or '-'} | " + " | ".join(_fmt(cols[p][i]) for p in PARAMS) + " |")
    lines += ["", "![envelopes](envelopes.png)", "", "![histograms](histograms.png)", ""]
    if h:
        _plot_envelopes(h, cols, out / "envelopes.png", meta)
    _plot_histograms(cols, out / "histograms.png")
    md = "\n".join(lines)
    atomic_write(out / "summary.md", md)
    return md


def _plot_envelopes(h: dict, cols: dict, path: Path, meta: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # histories are stored for runs that produced one (failed runs have none): match by (gains, run)
    key_rows = {(int(g), int(r)): s for g, r, s in zip(cols["gains_index"], cols["run"], cols["status"].astype(str))}
    ok = np.array([key_rows.get((int(g), int(r))) == "ok" for g, r in zip(h["gains_index"], h["run"])], dtype=bool)
    T = float(np.nanmedian(cols["orbit_period"].astype(float)))
    t = h["t"] / T
    fig, ax = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    for a, key, label in ((ax[0], "pointing_deg", "pointing error [deg]"), (ax[1], "dipole", "|m| [A m^2]")):
        e = envelopes(h, key, ok)
        a.fill_between(t, e[0], e[2], color="tab:blue", alpha=0.25, lw=0, label="5-95 %")
        a.plot(t, e[1], color="tab:blue", lw=1.2, label="median")
        a.plot(t, e[2], color="tab:blue", lw=0.6, ls=":")
        a.set_ylabel(label)
        a.grid(True, alpha=0.3)
    ax[0].set_yscale("log")
    ax[0].axhline(meta["criteria"]["settle_threshold_deg"], color="gray", ls="--", lw=0.8, label="settle threshold")
    ax[0].legend(loc="upper right")
    ax[1].set_xlabel("time [orbits]")
    ax[0].set_title(f"{meta['name']}: {int(ok.sum())} ok runs, every {meta['record_every'] * meta['ts']:g} s")
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)


def _plot_histograms(cols: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = cols["status"].astype(str) == "ok"
    figs = figures_of(cols)
    nf = len(figs)
    ncol = 4
    fig, axes = plt.subplots(math.ceil(nf / ncol), ncol, figsize=(14, 2 * math.ceil(nf / ncol)))
    for a, (key, unit) in zip(axes.ravel(), figs):
        v = cols[key][ok].astype(float)
        f = v[np.isfinite(v)]
        if f.size:
            a.hist(f, bins=min(40, max(5, int(np.sqrt(f.size)) * 2)), color="tab:blue", alpha=0.8)
        a.set_title(f"{key} [{unit}]" + (f"  ({v.size - f.size} n/a)" if f.size < v.size else ""), fontsize=9)
        a.grid(True, alpha=0.3)
    for a in axes.ravel()[nf:]:
        a.set_visible(False)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=100)
    plt.close(fig)


def summary_lines(meta: dict, cols: dict) -> list:
    """A few lines for the terminal after a campaign."""
    status = cols["status"].astype(str)
    ok = status == "ok"
    n = len(status)
    out = [f"{n} runs in {meta['wall']:.1f} s ({meta['runs_per_second']:.2f} runs/s, {meta.get('workers')} worker(s), "
           f"{meta['batches']} batches, task CPU {meta.get('cpu_s_per_run', float('nan')):.3f} s per run): "
           + ", ".join(f"{s} {int(np.sum(status == s))}" for s in STATUSES)
           + f"; passed {int(cols['passed'].astype(bool).sum())} ({100.0 * cols['passed'].astype(bool).mean():.1f} %)"]
    keys = (("settling_time", "s"), ("max_pointing_deg", "deg"), ("peak_dipole", "A m^2"))
    if "settled_time" in cols:
        keys += (("detumble_time", "s"), ("settled_time", "s"))
    for key, unit in keys:
        v = cols[key][ok].astype(float)
        f = v[np.isfinite(v)]
        if f.size:
            p = np.percentile(f, PERCENTILES)
            out.append(f"  {key:18s} 5/50/95 %: {p[0]:.4g} / {p[1]:.4g} / {p[2]:.4g} {unit}"
                       + (f"  ({v.size - f.size} n/a)" if f.size < v.size else ""))
    for o in torquer_outcomes(cols, meta):
        if o["fault"] is None:
            out.append(f"  torquer watch: {o['named'].size} of {o['runs']} ok runs named a torquer (no torquer fault: false)")
        else:
            ttd = np.percentile(o["delays"], (50.0, 95.0)) if o["detected"] else (math.nan, math.nan)
            out.append(f"  torquer watch, {o['fault']}: detected {o['detected']} / {o['runs']}, time to detect p50/p95 "
                       f"{ttd[0]:.4g} / {ttd[1]:.4g} s; another axis first {o['wrong_first']}, before the onset "
                       f"{o['early']}")
    fails = deployment_failures(cols)
    if "settled_time" in cols:
        out.append(f"  deployment failures (never settled in POINTING): {fails.size}"
                   + (": runs " + ", ".join(str(cols["run"][i]) for i in fails[:10]) if fails.size else ""))
    bad = np.nonzero(~ok)[0]
    for i in bad[:10]:
        out.append(f"  run {cols['run'][i]} ({cols['gains'][i]}): {status[i]} {cols['error'][i]}")
    if bad.size > 10:
        out.append(f"  ... {bad.size - 10} more failed/diverged runs in runs.parquet")
    return out
