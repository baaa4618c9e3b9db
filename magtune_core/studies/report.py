"""Paper Figs. 2-5 from recorded bags (``magtune report bags/A [bags/B ...] --out reports/NAME/``).

Everything comes from the bags (CDR decoded with rosbags; no rclpy, no simulator output):

* ``fig2_first_orbit.png``   |dq_R| and |m| over the first orbit, every bag overlaid;
* ``fig3_orbits_2_5.png``    the same over orbits 2-5;
* ``fig4_quaternion.png``    attitude quaternion (body w.r.t. orbital) of one run;
* ``fig5_rates_dipoles.png`` rate deviation dw and commanded dipole m of one run;
* ``summary.md`` (+ ``summary.json``): figures of merit per bag (same definitions as
  ``magtune_core.sim.metrics.figures_of_merit``: |dq_R| final and peak, RMS |dq_R| over orbits
  2-5, peak |m|) plus the bag's integrity (complete / recovered).

Signals: truth attitude and rate from ``/sim/truth`` (nav_msgs/Odometry: pose.orientation,
twist.angular = inertial body rate), ``x = linear_state(q, w, W0)``, |dq_R| = |x[0:3]|;
dipole from ``/controller/dipole_command`` (geometry_msgs/Vector3Stamped). Time axis = the
header stamps (sim time). Legends use the bag's ``custom_data`` ``sigma`` (recorder
``--custom-data sigma=60``) or else the bag name. Topic names can be overridden.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from .. import bags as baglib
from ..bags.decode import Decoder, stamp_ns
from ..base.topics import DIPOLE, TRUTH
from ..design.law import linear_state
from ..design.params import SpacecraftParams
from ..sim.metrics import figures_of_merit


@dataclass
class Run:
    """Time series of one bag (sim time in s)."""

    name: str
    label: str
    t: np.ndarray        # truth times
    q: np.ndarray        # (n, 4) scalar-first
    x: np.ndarray        # (n, 6) [dq; dw]
    tm: np.ndarray       # dipole times
    m: np.ndarray        # (k, 3)
    integrity: dict

    @property
    def dq_norm(self):
        return np.linalg.norm(self.x[:, :3], axis=1)

    @property
    def m_norm(self):
        return np.linalg.norm(self.m, axis=1) if len(self.m) else np.zeros(0)


def load_run(path, *, truth=TRUTH, dipole=DIPOLE, orbit_rate: float | None = None) -> Run:
    """Decode the truth and dipole topics of a bag (damaged bags: what is readable)."""
    path = Path(path)
    w0 = orbit_rate if orbit_rate is not None else SpacecraftParams().orbit_rate
    d = Decoder()
    report: dict = {}
    t, q, w, tm, m = [], [], [], [], []
    for msg in baglib.iter_messages(path, topics=[truth, dipole], report=report):
        o = d.decode(msg.data, msg.type)
        s = stamp_ns(o)
        s = msg.log_time if s is None else s
        if msg.topic == truth:
            p, a = o.pose.pose.orientation, o.twist.twist.angular
            t.append(s * 1e-9)
            q.append((p.w, p.x, p.y, p.z))
            w.append((a.x, a.y, a.z))
        else:
            v = o.vector
            tm.append(s * 1e-9)
            m.append((v.x, v.y, v.z))
    if not t:
        raise ValueError(f"{path}: no messages on {truth} (topics: {sorted(baglib.topics_of(path))})")
    q_arr = np.array(q)
    x = np.array([linear_state(qi, wi, w0) for qi, wi in zip(q_arr, w)])
    label = path.name
    try:
        sigma = (baglib.read_metadata(path).get("custom_data") or {}).get("sigma")
        if sigma:
            label = f"sigma = {sigma}"
    except (OSError, KeyError, TypeError, AttributeError, yaml.YAMLError):
        pass  # a malformed metadata.yaml only costs the label
    integ = {"complete": bool(report.get("complete", True))}
    if not integ["complete"]:
        integ.update({k: report.get(k) for k in ("messages_recovered", "messages_expected",
                                                "messages_in_damaged_chunks", "chunks_bad", "problem")})
    return Run(path.name, label, np.array(t), q_arr, x, np.array(tm), np.array(m).reshape(-1, 3), integ)


def run_figures(run: Run, orbit_period: float) -> dict:
    """:func:`magtune_core.sim.metrics.figures_of_merit` of a recorded run, with sample counts."""
    return {**figures_of_merit(run.t, run.x, run.m, orbit_period, tm=run.tm),
            "truth_samples": int(len(run.t)), "dipole_samples": int(len(run.tm))}


def _window(t, lo, hi):
    return (t >= lo) & (t <= hi)


def plot_norms(runs: list[Run], T: float, lo_orbit: float, hi_orbit: float, title: str, out: Path):
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for r in runs:
        s = _window(r.t, lo_orbit * T, hi_orbit * T)
        ax[0].plot(r.t[s] / T, r.dq_norm[s], label=r.label, lw=1)
        if len(r.tm):
            sm = _window(r.tm, lo_orbit * T, hi_orbit * T)
            ax[1].plot(r.tm[sm] / T, r.m_norm[sm], label=r.label, lw=1)
    ax[0].set_ylabel("|dq_R|")
    ax[1].set_ylabel("|m| [A m^2]")
    ax[1].set_xlabel("time [orbits]")
    ax[0].set_title(title)
    for a in ax:
        a.grid(True, alpha=0.3)
        a.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def plot_quaternion(run: Run, T: float, out: Path):
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(4, 1, figsize=(8, 7), sharex=True)
    q = run.q * np.where(run.q[:, :1] < 0, -1.0, 1.0)
    for i, name in enumerate(("q1 (scalar)", "q2 (yaw)", "q3 (roll)", "q4 (pitch)")):
        ax[i].plot(run.t / T, q[:, i], lw=1)
        ax[i].set_ylabel(name)
        ax[i].grid(True, alpha=0.3)
    ax[0].set_title(f"Attitude quaternion, {run.label} ({run.name})")
    ax[-1].set_xlabel("time [orbits]")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def plot_rates_dipoles(run: Run, T: float, out: Path):
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for i, c in enumerate("xyz"):
        ax[0].plot(run.t / T, run.x[:, 3 + i], lw=1, label=f"dw_{c}")
        if len(run.tm):
            ax[1].plot(run.tm / T, run.m[:, i], lw=1, label=f"m_{c}")
    ax[0].set_ylabel("dw [rad/s]")
    ax[1].set_ylabel("m [A m^2]")
    ax[1].set_xlabel("time [orbits]")
    ax[0].set_title(f"Body rate deviation and dipole, {run.label} ({run.name})")
    for a in ax:
        a.grid(True, alpha=0.3)
        a.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def _sigma_key(run: Run):
    digits = "".join(ch for ch in run.label.split("=")[-1] if ch.isdigit() or ch == ".")
    try:
        return float(digits)
    except ValueError:
        return -1.0


def make_report(bags, out, *, run: str | None = None, truth=TRUTH, dipole=DIPOLE,
                orbit_period: float | None = None, labels: list[str] | None = None) -> dict:
    """Write the figures and summary for ``bags`` into ``out``; returns the summary dict."""
    import matplotlib
    matplotlib.use("Agg")
    T = orbit_period or SpacecraftParams().orbit_period
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    runs = [load_run(b, truth=truth, dipole=dipole, orbit_rate=2 * np.pi / T) for b in bags]
    if labels:
        if len(labels) != len(runs):
            raise ValueError(f"{len(labels)} labels for {len(runs)} bags")
        for r, lab in zip(runs, labels):
            r.label = lab
    one = next((r for r in runs if r.name == run), None) if run else max(runs, key=_sigma_key)
    if one is None:
        raise ValueError(f"--run {run!r} is not one of {[r.name for r in runs]}")
    plot_norms(runs, T, 0.0, 1.0, "First orbit", out / "fig2_first_orbit.png")
    plot_norms(runs, T, 1.0, 5.0, "Orbits 2-5", out / "fig3_orbits_2_5.png")
    plot_quaternion(one, T, out / "fig4_quaternion.png")
    plot_rates_dipoles(one, T, out / "fig5_rates_dipoles.png")
    summary = {r.name: {"label": r.label, **run_figures(r, T), "integrity": r.integrity}
               for r in runs}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    (out / "summary.md").write_text(_markdown(summary, one.name, T))
    return summary


def _markdown(summary: dict, one: str, T: float) -> str:
    lines = ["# magtune run report", "",
             f"Orbit period T = {T} s. |dq_R| = norm of the quaternion vector part (truth, "
             "body w.r.t. orbital axes); |m| = commanded dipole. RMS over orbits 2-5 "
             "(or the whole run if it is shorter than 2 orbits).", "",
             "| bag | label | orbits | final abs(dq_R) | peak abs(dq_R) | RMS abs(dq_R) | peak abs(m) [A m^2] "
             "| RMS abs(m), orbits 2-5 | samples truth/dipole | bag integrity |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for name, s in summary.items():
        integ = "complete" if s["integrity"]["complete"] else \
            f"damaged: {s['integrity'].get('messages_recovered')} msgs recovered"
        lines.append(f"| {name} | {s['label']} | {s['orbits']:.3f} | {s['final_dq']:.4e} | "
                     f"{s['peak_dq']:.4e} | {s['rms_dq']:.4e} | {s['peak_m']:.4g} | "
                     f"{s['rms_m_orbits_2_5']:.4g} | {s['truth_samples']}/{s['dipole_samples']} | {integ} |")
    lines += ["", "Figures: `fig2_first_orbit.png` (Fig. 2), `fig3_orbits_2_5.png` (Fig. 3), "
              f"`fig4_quaternion.png` and `fig5_rates_dipoles.png` (Figs. 4-5, run `{one}`).", ""]
    return "\n".join(lines)
