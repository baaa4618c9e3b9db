"""Estimation figures of a bag recorded with ``magtune sil --attitude estimator`` (part of ``magtune report``).

From the bag only: the estimate ``estimate/attitude`` (sensor_msgs/Imu: orientation = body w.r.t. orbital
axes, orientation_covariance = the attitude block of the MEKF's P, body axes) against the truth
``sim/truth`` (nav_msgs/Odometry), matched by header stamp. Error dtheta in body axes with
q_true = q_est (x) exp(dtheta/2) (:func:`magtune_core.onboard.mekf.attitude_error`, the filter's own error
definition, so its covariance bounds it), NEES dtheta^T P^-1 dtheta (3 dof; Bar-Shalom, Li & Kirubarajan
2001, sec. 5.4.2; Markley & Crassidis 2014, sec. 6.2 for the filter).

* ``fig6_estimation.png`` (``fig6_estimation_<ns>.png`` per satellite of a fleet bag): the error per body
  axis with its +-3 sigma bounds, and the windowed NEES: means of ``N`` samples taken ``LAG`` s apart
  (consecutive 1 Hz NEES samples are correlated over ~60-550 s, docs/estimation.md#consistency; at 100 s the
  normalized error's autocorrelation is <~0.3) with the 95 % band of chi2(3N)/N;
* the fraction of samples inside 3 sigma per axis, the RMS error per axis and the mean NEES, over every
  estimated sample and from ``SETTLE`` s on (``estimation.json``, and a section of ``summary.md``).

Samples whose covariance is marked unknown (orientation_covariance[0] = -1, before the coarse fix) are not
estimates and are left out.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import bags as baglib
from ..bags.decode import Decoder, stamp_ns
from ..base import jsonout
from ..base.atomic import atomic_savefig, atomic_write
from ..base.topics import ESTIMATE, TOPIC_ESTIMATE, TOPIC_TRUTH, TRUTH
from ..onboard.mekf import attitude_error
from ..sim.estimation import nees_windows

#: NEES window: N samples LAG seconds apart (the chi-square band of their mean assumes independent samples).
N_WINDOW, LAG = 10, 100.0
#: Samples from this time on [s] are the filter's steady state (the bias transient after the fix at t = 0 is
#: a few minutes: the check window of tests/ros/test_estimator_sil.py).
SETTLE = 300.0
FIGURE = "fig6_estimation.png"


@dataclass
class EstimationSeries:
    """Estimate against truth of one satellite, at the stamps that have both (sim time [s])."""

    name: str
    t: np.ndarray  #: (n,)
    error: np.ndarray  #: (n, 3) dtheta [rad], body axes
    sigma: np.ndarray  #: (n, 3) sqrt of the covariance's diagonal [rad]
    nees: np.ndarray  #: (n,)
    unknown: int = 0  #: estimate messages with an unknown covariance (before the fix)


def _q(o):
    return np.array([o.w, o.x, o.y, o.z])


def load_estimation(path, ns: str = "", name: str | None = None) -> EstimationSeries | None:
    """The :class:`EstimationSeries` of satellite ``ns`` of the bag (None: no ``estimate/attitude`` in it)."""
    path = Path(path)
    est_topic, truth_topic = (f"{ns}/{TOPIC_ESTIMATE}", f"{ns}/{TOPIC_TRUTH}") if ns else (ESTIMATE, TRUTH)
    if est_topic not in baglib.topics_of(path):
        return None
    try:
        origin = int((baglib.read_metadata(path).get("custom_data") or {}).get("time_origin_ns", 0))
    except (OSError, KeyError, TypeError, ValueError):
        origin = 0
    d = Decoder()
    est, truth = {}, {}
    for msg in baglib.iter_messages(path, topics=[est_topic, truth_topic], report={}):
        o = d.decode(msg.data, msg.type)
        s = stamp_ns(o)
        s = msg.log_time if s is None else s
        if msg.topic == est_topic:
            est[s] = o
        else:
            truth[s] = o.pose.pose.orientation
    stamps = sorted(set(est) & set(truth))
    unknown = sum(1 for s in stamps if est[s].orientation_covariance[0] < 0)
    stamps = [s for s in stamps if est[s].orientation_covariance[0] >= 0]
    n = len(stamps)
    e, sig, nees = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n)
    for i, s in enumerate(stamps):
        P = np.reshape(np.asarray(est[s].orientation_covariance, dtype=float), (3, 3))
        e[i] = attitude_error(_q(truth[s]), _q(est[s].orientation))
        sig[i] = np.sqrt(np.diag(P))
        nees[i] = e[i] @ np.linalg.solve(P, e[i])
    t = (np.array(stamps, dtype=np.int64) - origin) * 1e-9
    return EstimationSeries(name or path.name + ns, t, e, sig, nees, unknown)


def estimation_summary(s: EstimationSeries, settle: float = SETTLE) -> dict:
    """Consistency figures of one satellite: over every estimated sample and from ``settle`` s on.

    Returns
    -------
    dict
        ``samples``, ``inside_3sigma`` (3,) fraction of samples with |dtheta_i| <= 3 sigma_i per body axis,
        ``rms_deg`` (3,), ``nees_mean`` for ``all`` and ``settled`` (t >= settle); the NEES windows
        (``window_n``, ``window_lag_s``, ``window_band`` (low, high) of chi2(3N)/N at 95 %, ``windows_inside``
        the fraction of window means inside it); ``unknown`` estimates before the fix.
    """
    out = {"samples": int(s.t.size), "unknown": int(s.unknown), "settle_s": float(settle)}
    for key, sel in (("all", np.ones(s.t.size, dtype=bool)), ("settled", s.t >= settle)):
        e, sig = s.error[sel], s.sigma[sel]
        out[key] = dict(samples=int(sel.sum()),
                        inside_3sigma=np.mean(np.abs(e) <= 3 * sig, axis=0).tolist() if sel.any() else [np.nan] * 3,
                        rms_deg=np.degrees(np.sqrt(np.mean(e**2, axis=0))).tolist() if sel.any() else [np.nan] * 3,
                        nees_mean=float(np.mean(s.nees[sel])) if sel.any() else np.nan)
    tw, means, lo, hi = _windows(s)
    out.update(window_n=N_WINDOW, window_lag_s=LAG, window_band=[lo, hi], windows=int(means.size),
               windows_inside=float(np.mean((means >= lo) & (means <= hi))) if means.size else np.nan)
    return out


def _windows(s: EstimationSeries):
    """Window means of the NEES sampled every LAG s from t = 0 on, their centre times and the 95 % band."""
    if s.t.size == 0:
        return np.zeros(0), np.zeros(0), np.nan, np.nan
    grid = np.arange(s.t[0], s.t[-1] + 0.5, LAG)
    idx = np.unique(np.clip(np.searchsorted(s.t, grid), 0, s.t.size - 1))
    means, lo, hi = nees_windows(s.nees[idx], N_WINDOW)
    tw = s.t[idx][: means.size * N_WINDOW].reshape(-1, N_WINDOW).mean(axis=1) if means.size else np.zeros(0)
    return tw, means, lo, hi


def plot_estimation(s: EstimationSeries, orbit_period: float, out: Path) -> None:
    """Error per body axis with +-3 sigma and the windowed NEES with its chi-square band (module docstring)."""
    import matplotlib.pyplot as plt

    T = orbit_period
    fig, axes = plt.subplots(4, 1, figsize=(10, 9), sharex=True)
    x = s.t / T
    for i, a in enumerate("xyz"):
        ax = axes[i]
        three = 3 * np.degrees(s.sigma[:, i])
        ax.fill_between(x, -three, three, color="tab:blue", alpha=0.2, lw=0, label="+-3 sigma")
        ax.plot(x, np.degrees(s.error[:, i]), color="k", lw=0.6, label="error")
        inside = np.mean(np.abs(s.error[:, i]) <= 3 * s.sigma[:, i]) if s.t.size else np.nan
        ax.set_ylabel(f"dtheta_{a} [deg]")
        ax.set_title(f"body {a}: {100 * inside:.1f} % of the samples inside 3 sigma", fontsize=9, loc="left")
        if i == 0:
            ax.legend(loc="upper right", fontsize=8)
    tw, means, lo, hi = _windows(s)
    ax = axes[3]
    ax.axhspan(lo, hi, color="tab:green", alpha=0.2, label=f"95 % band of chi2({3 * N_WINDOW})/{N_WINDOW}")
    ax.axhline(3.0, color="tab:green", lw=0.8)
    ax.plot(tw / T, means, "o-", color="k", ms=3, lw=0.8, label=f"mean of {N_WINDOW} samples {LAG:g} s apart")
    ax.set_ylabel("NEES")
    ax.set_xlabel("t [orbits]")
    ax.legend(loc="upper right", fontsize=8)
    fig.suptitle(f"Attitude estimation error vs truth: {s.name}")
    fig.tight_layout()
    atomic_savefig(fig, out)
    plt.close(fig)


def write(bags, out, orbit_period: float, namespaces) -> dict:
    """Figures and ``estimation.json`` of every satellite with an estimate; ``namespaces`` maps a bag to its
    satellites' namespaces ([""] for a single one). Stale figures of an earlier report are removed.

    Returns
    -------
    dict
        satellite name -> {"figure": file name, **estimation_summary}; empty when no bag has an estimate.
    """
    out = Path(out)
    result = {}
    for path in bags:
        path = Path(path)
        for ns in namespaces(path) or [""]:
            s = load_estimation(path, ns)
            if s is None or s.t.size == 0:
                continue
            tag = ns.strip("/").replace("/", "_")
            fig = FIGURE if not tag else FIGURE.replace(".png", f"_{tag}.png")
            plot_estimation(s, orbit_period, out / fig)
            result[s.name] = {"figure": fig, **estimation_summary(s)}
    if result:
        atomic_write(out / "estimation.json", jsonout.dumps(result, indent=1))
    else:
        for f in list(out.glob("fig6_estimation*.png")) + [out / "estimation.json"]:
            f.unlink(missing_ok=True)
    return result


def markdown(result: dict) -> str:
    """The summary.md section of :func:`write`'s result ("" without estimates)."""
    if not result:
        return ""
    lines = ["## Attitude estimation", "",
             f"Estimate (`{TOPIC_ESTIMATE}`) against truth (`{TOPIC_TRUTH}`), error per body axis, 3 sigma from the "
             f"estimate's covariance; NEES windows: means of {N_WINDOW} samples {LAG:g} s apart against the 95 % band "
             f"of chi2({3 * N_WINDOW})/{N_WINDOW}.", "",
             "| satellite | window | samples | inside 3 sigma x, y, z | RMS x, y, z [deg] | mean NEES | NEES windows inside |",
             "|---|---|---|---|---|---|---|"]
    for name, r in result.items():
        for key, label in (("all", "every estimate"), ("settled", f"t >= {r['settle_s']:g} s")):
            a = r[key]
            ins = ", ".join(f"{100 * v:.1f} %" for v in a["inside_3sigma"])
            rms = ", ".join(f"{v:.3f}" for v in a["rms_deg"])
            win = f"{100 * r['windows_inside']:.0f} % of {r['windows']}" if key == "all" else ""
            lines.append(f"| {name} | {label} | {a['samples']} | {ins} | {rms} | {a['nees_mean']:.2f} | {win} |")
    figs = ", ".join(f"`{r['figure']}`" for r in result.values())
    return "\n".join(lines + ["", f"Figures: {figs}.", ""])
