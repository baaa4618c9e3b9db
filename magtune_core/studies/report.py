"""Paper Figs. 2-5 from recorded bags (``magtune report bags/A [bags/B ...] --out reports/NAME/``).

Everything comes from the bags (CDR decoded with rosbags; no rclpy, no simulator output):

* ``fig2_first_orbit.png``   pointing error [deg] and |m| over the first orbit (the whole run
  if shorter; the window is in the title), every run overlaid;
* ``fig3_orbits_2_5.png``    the same over orbits 2-5 (up to the end of the longest run); not
  drawn, and said so in the summary, when no run is longer than one orbit;
* ``fig4_quaternion.png``    attitude quaternion (body w.r.t. orbital) of every run, one panel
  per run (small multiples), components in ROS order and names x, y, z, w;
* ``fig5_rates_dipoles.png`` rate deviation dw and commanded dipole m of every run, one row per
  run, with the per-axis dipole limit drawn;
* ``summary.md`` (+ ``summary.json``): figures of merit per run (same definitions as
  ``magtune_core.sim.metrics.figures_of_merit``: pointing error and |dq_R| final, peak and RMS
  over the stated window, peak and RMS |m|) plus the bag's integrity (complete / recovered);
* ``report.html``: one self-contained file (figures embedded) with the summary table;
* flight modes (a bag with the ``mode`` topic, ``magtune sil --modes``): coloured bands per mode on
  the pointing-error plots and the transitions in the text (:mod:`.report_modes`).

Signals: truth attitude from ``/sim/truth`` (nav_msgs/Odometry: pose.orientation), inertial
body rate w from ``/sim/inertial_rate`` (else from the Odometry twist, see :func:`load_run`),
``x = linear_state(q, w, W0)``, |dq_R| = |x[0:3]|,
pointing error = 2 asin |dq_R|; dipole from ``/controller/dipole_command``
(geometry_msgs/Vector3Stamped), only the commands the simulator flies (:func:`screen_dipoles`: a
non-finite one, which the simulator rejects, or one beyond the per-axis limit, which no controller
sends, is counted, named in the summary and left out of the figures). Time axis = the header stamps (sim time). A bag of several
namespaced satellites (``magtune sil --gains sat1=... sat2=...``) gives one run per namespace.
Legends use the bag's ``custom_data`` ``sigma`` (recorder ``--custom-data sigma=60``) or else
the bag name. Topic names can be overridden.
"""
from __future__ import annotations

import base64
import html
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from .. import bags as baglib
from ..bags.decode import Decoder, stamp_ns
from ..base import jsonout
from ..base.atomic import atomic_savefig, atomic_write
from ..base.rotations import rotation_matrix
from ..base.topics import DIPOLE, TOPIC_DIPOLE, TOPIC_INERTIAL_RATE, TOPIC_TRUTH, TRUTH
from ..design.params import SpacecraftParams
from ..onboard.law import DEFAULT_DIPOLE_LIMIT, linear_state
from ..sim.metrics import figures_of_merit, pointing_error_deg
from . import report_estimation, report_modes

#: ROS order and names of the quaternion components (geometry_msgs/Quaternion).
QUAT_NAMES = ("x", "y", "z", "w")
FIGURES = ("fig2_first_orbit.png", "fig3_orbits_2_5.png", "fig4_quaternion.png", "fig5_rates_dipoles.png")


@dataclass
class Run:
    """Time series of one satellite of one bag (sim time in s)."""

    name: str
    label: str
    t: np.ndarray        # truth times
    q: np.ndarray        # (n, 4) scalar-first
    x: np.ndarray        # (n, 6) [dq; dw]
    tm: np.ndarray       # dipole times
    m: np.ndarray        # (k, 3)
    integrity: dict
    modes: list = field(default_factory=list)  # report_modes.ModeChange of the mode topic (none: no band)
    #: dipole commands left out (:func:`screen_dipoles`): "rejected" (non-finite), "beyond_limit"
    dipoles_left_out: dict = field(default_factory=lambda: {"rejected": 0, "beyond_limit": 0})

    @property
    def dq_norm(self):
        return np.linalg.norm(self.x[:, :3], axis=1)

    @property
    def pointing_deg(self):
        return pointing_error_deg(self.dq_norm)

    @property
    def m_norm(self):
        return np.linalg.norm(self.m, axis=1) if len(self.m) else np.zeros(0)


#: How the truth Odometry's twist is read: "relative" (this release: body w.r.t. orbital frame,
#: REP-105) or "inertial" (bags recorded before it carried the inertial rate there).
TWIST_MODES = ("relative", "inertial")


def load_run(path, *, truth=TRUTH, dipole=DIPOLE, orbit_rate: float | None = None, name: str | None = None,
             label: str | None = None, twist: str = "relative") -> Run:
    """Decode the truth, inertial-rate and dipole topics of a bag (damaged bags: what is readable).

    The inertial body rate w of the paper's state comes from ``<ns>/sim/inertial_rate`` when the
    bag has it (exact). Otherwise from the truth twist: with ``twist="relative"`` (the
    convention of this release) w = twist + R(q)^T [0, 0, -W0], exact on the paper's circular
    orbit and within the orbital frame's rate variation (J2, eccentricity) in the full
    environment; with ``twist="inertial"`` (bags recorded before this release) w = twist.
    """
    path = Path(path)
    if twist not in TWIST_MODES:
        raise ValueError(f"twist must be one of {TWIST_MODES}, got {twist!r}")
    w0 = orbit_rate if orbit_rate is not None else SpacecraftParams().orbit_rate
    rate_topic = truth[: -len(TOPIC_TRUTH)] + TOPIC_INERTIAL_RATE if truth.endswith(TOPIC_TRUTH) else None
    has_rate = rate_topic is not None and rate_topic in baglib.topics_of(path)
    d = Decoder()
    report: dict = {}
    t, t_ns, q, w, tm, m, rates = [], [], [], [], [], [], {}
    # a run recorded with `magtune sil --epoch-time` is stamped from the scenario epoch (ns since
    # 1970); times here are seconds from the start of the run, as the offline simulation's
    try:
        origin = int((baglib.read_metadata(path).get("custom_data") or {}).get("time_origin_ns", 0))
    except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError):
        origin = 0
    for msg in baglib.iter_messages(path, topics=[truth, dipole] + ([rate_topic] if has_rate else []), report=report):
        o = d.decode(msg.data, msg.type)
        s = stamp_ns(o)
        s = (msg.log_time if s is None else s) - origin
        if msg.topic == truth:
            p, a = o.pose.pose.orientation, o.twist.twist.angular
            t_ns.append(s)
            t.append(s * 1e-9)
            q.append((p.w, p.x, p.y, p.z))
            w.append((a.x, a.y, a.z))
        elif msg.topic == rate_topic:
            rates[s] = (o.vector.x, o.vector.y, o.vector.z)
        else:
            v = o.vector
            tm.append(s * 1e-9)
            m.append((v.x, v.y, v.z))
    if not t:
        raise ValueError(f"{path}: no messages on {truth} (topics: {sorted(baglib.topics_of(path))})")
    # time series in stamp order: bag order is log-time order, and in a multi-satellite bag the
    # log times of the other satellites come from the first one's clock (ties, reordering)
    o = np.argsort(np.array(t_ns), kind="stable")
    t_ns, t, q, w = [t_ns[i] for i in o], [t[i] for i in o], [q[i] for i in o], [w[i] for i in o]
    om = np.argsort(np.array(tm), kind="stable")
    tm, m = [tm[i] for i in om], [m[i] for i in om]
    q_arr = np.array(q)
    # the exact inertial rate at each truth stamp when recorded (a damaged bag may miss some)
    w = [rates.get(k) or _inertial(qi, wi, w0, twist) for k, qi, wi in zip(t_ns, q_arr, w)]
    x = np.array([linear_state(qi, wi, w0) for qi, wi in zip(q_arr, w)])
    if label is None:
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
                                                "messages_in_damaged_chunks", "chunks_bad", "problem",
                                                "missing_files", "metadata_disagreements", "metadata_message_count")})
    return Run(name or path.name, label, np.array(t), q_arr, x, np.array(tm), np.array(m).reshape(-1, 3), integ)


def _inertial(q, twist_angular, w0: float, mode: str):
    """Inertial body rate from the Odometry twist (see :func:`load_run`)."""
    if mode == "inertial":
        return twist_angular
    return np.asarray(twist_angular, dtype=float) + rotation_matrix(q).T @ np.array([0.0, 0.0, -w0])


def screen_dipoles(run: Run, dipole_limit) -> Run:
    """Keep the dipole commands the simulator flies; count the others (``run.dipoles_left_out``).

    A bag records every message on the dipole topic, also those the simulator refused: a peer on the
    domain can publish there. A non-finite command (nan, inf) is rejected by the simulator ("rejected");
    a finite one beyond the per-axis limit (a relative 1e-9 over it) is one no controller sends (it
    saturates to the same limit) and the simulator would clip ("beyond_limit"). Both are left out of
    peak and RMS abs(m) and of the figures; the summary says how many (:func:`dipole_note`).

    Parameters
    ----------
    run : Run
        A run as decoded (:func:`load_run`); changed in place.
    dipole_limit : float or array_like (3,)
        Per-axis dipole limit [A m^2] the run was flown with.

    Returns
    -------
    Run
        ``run``, its ``tm``/``m`` the commands kept.
    """
    m = np.asarray(run.m, dtype=float).reshape(-1, 3)
    finite = np.isfinite(m).all(axis=1)
    lim = np.broadcast_to(np.asarray(dipole_limit, dtype=float), (3,))
    within = np.zeros(len(m), bool)
    within[finite] = (np.abs(m[finite]) <= lim * (1.0 + 1e-9)).all(axis=1)
    run.dipoles_left_out = {"rejected": int(np.count_nonzero(~finite)),
                            "beyond_limit": int(np.count_nonzero(finite & ~within))}
    run.tm, run.m = np.asarray(run.tm)[within], m[within]
    return run


def dipole_note(left_out: dict, dipole_limit) -> str:
    """One sentence on the dipole commands :func:`screen_dipoles` left out ("" when none).

    Parameters
    ----------
    left_out : dict
        ``{"rejected": N, "beyond_limit": M}``.
    dipole_limit : float or array_like (3,)
        The per-axis limit [A m^2] they were screened with.

    Returns
    -------
    str
        E.g. "1 dipole command rejected by the simulator (non-finite); left out of abs(m) and the figures".
    """
    parts = []
    if left_out.get("rejected"):
        n = left_out["rejected"]
        parts.append(f"{n} dipole command{'s' if n != 1 else ''} rejected by the simulator (non-finite)")
    if left_out.get("beyond_limit"):
        n = left_out["beyond_limit"]
        lim = np.broadcast_to(np.asarray(dipole_limit, dtype=float), (3,))
        parts.append(f"{n} dipole command{'s' if n != 1 else ''} beyond the per-axis limit "
                     f"+-{', '.join(f'{v:g}' for v in np.unique(lim))} A m^2 (the simulator flies at most the limit)")
    return "; ".join(parts) + ("; left out of abs(m) and the figures" if parts else "")


def bag_namespaces(path, truth=TRUTH) -> list[str]:
    """Namespaces of the satellites recorded in a bag: ``[""]`` when ``truth`` itself is there,
    else every ``NS`` with a ``NS/sim/truth`` topic (a ``magtune sil --gains sat1=... sat2=...``
    bag), sorted; empty if none."""
    topics = baglib.topics_of(path)
    if truth in topics:
        return [""]
    suffix = "/" + TOPIC_TRUTH
    return sorted(n[: -len(suffix)] for n in topics if n.endswith(suffix) and n != suffix)


def load_runs(path, *, truth=TRUTH, dipole=DIPOLE, orbit_rate: float | None = None, twist: str = "relative") -> list[Run]:
    """Every satellite of a bag as a :class:`Run` (one for a single-satellite bag; one per
    namespace, named ``<bag>/<ns>`` and labelled with that satellite's sigma, otherwise)."""
    path = Path(path)
    nss = bag_namespaces(path, truth) if truth == TRUTH and dipole == DIPOLE else [""]
    if nss in ([""], []):
        return [load_run(path, truth=truth, dipole=dipole, orbit_rate=orbit_rate, twist=twist)]
    try:
        custom = baglib.read_metadata(path).get("custom_data") or {}
    except (OSError, KeyError, TypeError, AttributeError, yaml.YAMLError):
        custom = {}
    out = []
    for ns in nss:
        tag = ns.strip("/").replace("/", "_")
        sigma = custom.get(f"{tag}.sigma")
        out.append(load_run(path, truth=f"{ns}/{TOPIC_TRUTH}", dipole=f"{ns}/{TOPIC_DIPOLE}", orbit_rate=orbit_rate, twist=twist,
                            name=f"{path.name}{ns}", label=f"{ns} sigma = {sigma}" if sigma else f"{path.name}{ns}"))
    return out


def run_figures(run: Run, orbit_period: float) -> dict:
    """:func:`magtune_core.sim.metrics.figures_of_merit` of a recorded run, with sample counts."""
    return {**figures_of_merit(run.t, run.x, run.m, orbit_period, tm=run.tm),
            "truth_samples": int(len(run.t)), "dipole_samples": int(len(run.tm))}


def _window(t, lo, hi):
    return (t >= lo) & (t <= hi)


def _legend_outside(fig, axes) -> None:
    """One legend for the figure, right of the axes (never over the data)."""
    handles, labels = axes[0].get_legend_handles_labels()
    seen = dict(zip(labels, handles))
    if seen:
        fig.legend(list(seen.values()), list(seen.keys()), loc="outside right upper", fontsize=8)


def plot_norms(runs: list[Run], T: float, lo_orbit: float, hi_orbit: float, title: str, out: Path):
    """Pointing error [deg] and |m| of every run over [lo_orbit, hi_orbit] (paper Figs. 2-3)."""
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(2, 1, figsize=(9, 6), sharex=True, layout="constrained")
    for r in runs:
        s = _window(r.t, lo_orbit * T, hi_orbit * T)
        ax[0].plot(r.t[s] / T, r.pointing_deg[s], label=r.label, lw=1)
        if len(r.tm):
            sm = _window(r.tm, lo_orbit * T, hi_orbit * T)
            ax[1].plot(r.tm[sm] / T, r.m_norm[sm], label=r.label, lw=1)
        report_modes.draw_bands(ax[0], report_modes.spans(r.modes, float(r.t[-1])), T, lo_orbit * T, hi_orbit * T)
    ax[0].set_ylabel("pointing error [deg]")
    ax[1].set_ylabel("|m| [A m^2]")
    ax[1].set_xlabel("time [orbits]")
    ax[0].set_title(title)
    for a in ax:
        a.grid(True, alpha=0.3)
    _legend_outside(fig, ax)
    atomic_savefig(fig, out, dpi=110)
    plt.close(fig)


def plot_quaternion(runs: list[Run], T: float, out: Path):
    """Attitude quaternion of each run (small multiples, one row per run), components in ROS
    order and names: vector part x, y, z on the left, scalar w (close to 1) on the right."""
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(len(runs), 2, figsize=(11, 1.2 + 2.0 * len(runs)), sharex=True, squeeze=False,
                           layout="constrained", gridspec_kw={"width_ratios": (3, 1)})
    for row, r in zip(ax, runs):
        q = r.q * np.where(r.q[:, :1] < 0, -1.0, 1.0)  # hemisphere w >= 0, as dq_R
        for name, col in zip(QUAT_NAMES[:3], (1, 2, 3)):
            row[0].plot(r.t / T, q[:, col], lw=1, label=name)
        row[1].plot(r.t / T, q[:, 0], lw=1, color="C3", label="w")
        row[0].set_ylabel("q.x, q.y, q.z")
        row[1].set_ylabel("q.w")
        row[0].set_title(f"{r.label} ({r.name})", fontsize=9)
        for a in row:
            a.grid(True, alpha=0.3)
    fig.suptitle("Attitude quaternion, body w.r.t. orbital axes (ROS order x, y, z, w)")
    for a in ax[-1]:
        a.set_xlabel("time [orbits]")
    h0, l0 = ax[0, 0].get_legend_handles_labels()
    h1, l1 = ax[0, 1].get_legend_handles_labels()
    fig.legend(h0 + h1, l0 + l1, loc="outside right upper", fontsize=8)
    atomic_savefig(fig, out, dpi=110)
    plt.close(fig)


def plot_rates_dipoles(runs: list[Run], T: float, out: Path, dipole_limit: float = DEFAULT_DIPOLE_LIMIT):
    """Rate deviation dw and dipole m (per axis, with the +-limit) of each run, one row each."""
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(len(runs), 2, figsize=(12, 1.2 + 2.2 * len(runs)), sharex=True, squeeze=False,
                           layout="constrained")
    for row, r in zip(ax, runs):
        for i, c in enumerate("xyz"):
            row[0].plot(r.t / T, r.x[:, 3 + i], lw=1, label=c)
            if len(r.tm):
                row[1].plot(r.tm / T, r.m[:, i], lw=1, label=c)
        for sgn in (1.0, -1.0):
            row[1].axhline(sgn * dipole_limit, color="k", ls="--", lw=0.8,
                           label=f"limit +-{dipole_limit:g} A m^2 per axis")
        row[0].set_ylabel("dw [rad/s]")
        row[1].set_ylabel("m [A m^2]")
        row[0].set_title(f"{r.label} ({r.name}): rate deviation", fontsize=9)
        row[1].set_title(f"{r.label} ({r.name}): commanded dipole", fontsize=9)
        for a in row:
            a.grid(True, alpha=0.3)
    for a in ax[-1]:
        a.set_xlabel("time [orbits]")
    h0, l0 = ax[0, 0].get_legend_handles_labels()
    h1, l1 = ax[0, 1].get_legend_handles_labels()
    seen = dict(zip(l0 + l1, h0 + h1))
    fig.legend(list(seen.values()), list(seen.keys()), loc="outside right upper", fontsize=8)
    atomic_savefig(fig, out, dpi=110)
    plt.close(fig)


def _sigma_key(run: Run):
    digits = "".join(ch for ch in run.label.split("=")[-1] if ch.isdigit() or ch == ".")
    try:
        return float(digits)
    except ValueError:
        return -1.0


def windows(runs: list[Run], T: float) -> dict:
    """The time windows of Figs. 2 and 3 [orbits] and why, from the longest run.

    Fig. 2 is the first orbit, or the whole run if it is shorter; Fig. 3 is orbits 2-5 (to the
    end of the longest run if it ends before 5 orbits), or None when no run has two samples after
    the first orbit (nothing to draw).
    """
    end = max(float(r.t[-1]) for r in runs) / T
    fig2 = (0.0, min(1.0, end))
    later = max(int(np.count_nonzero(r.t > T)) for r in runs)
    fig3 = (1.0, min(5.0, end)) if later >= 2 else None
    return {"fig2": fig2, "fig3": fig3, "longest_orbits": end}


def make_report(bags, out, *, run: str | None = None, truth=TRUTH, dipole=DIPOLE,
                orbit_period: float | None = None, labels: list[str] | None = None,
                dipole_limit: float = DEFAULT_DIPOLE_LIMIT, twist: str = "relative") -> dict:
    """Write the figures, ``summary.md``/``.json`` and ``report.html`` for ``bags`` into ``out``.

    ``run``: only this run in Figs. 4-5 (default: every run, small multiples).

    Returns
    -------
    dict
        run name -> label, figures of merit (:func:`run_figures`) and integrity.
    """
    import matplotlib
    matplotlib.use("Agg")
    T = orbit_period or SpacecraftParams().orbit_period
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    runs = [screen_dipoles(r, dipole_limit) for b in bags
            for r in report_modes.attach(load_runs(b, truth=truth, dipole=dipole, orbit_rate=2 * np.pi / T, twist=twist), b)]
    if labels:
        if len(labels) != len(runs):
            raise ValueError(f"{len(labels)} labels for {len(runs)} runs")
        for r, lab in zip(runs, labels):
            r.label = lab
    detail = [r for r in runs if r.name == run] if run else runs
    if not detail:
        raise ValueError(f"--run {run!r} is not one of {[r.name for r in runs]}")
    win = windows(runs, T)
    a, b = win["fig2"]
    plot_norms(runs, T, a, b, "First orbit" if b >= 1.0 else
               f"Whole run: {b:.2f} orbits (shorter than one orbit)", out / FIGURES[0])
    if win["fig3"]:
        a, b = win["fig3"]
        plot_norms(runs, T, a, b, "Orbits 2-5" if b >= 5.0 else f"Orbits 2-5: orbit 1 to {b:.2f} (end of the run)",
                   out / FIGURES[1])
    else:
        (out / FIGURES[1]).unlink(missing_ok=True)  # no stale figure from an earlier report
    plot_quaternion(detail, T, out / FIGURES[2])
    plot_rates_dipoles(detail, T, out / FIGURES[3], dipole_limit)
    summary = {r.name: {"label": r.label, **run_figures(r, T), "integrity": _with_note(r, dipole_limit),
                        "dipole_commands_rejected": r.dipoles_left_out["rejected"],
                        "dipole_commands_beyond_limit": r.dipoles_left_out["beyond_limit"],
                        **({"modes": report_modes.summary_entry(r.modes, float(r.t[-1]))} if r.modes else {})}
               for r in runs}
    atomic_write(out / "summary.json", jsonout.dumps(summary, indent=1))
    # bags flown on the estimator (--attitude estimator): fig6 and estimation.json (studies/report_estimation.py)
    est = report_estimation.write(bags, out, T, lambda b: bag_namespaces(b, truth) if truth == TRUTH else [""])
    md = _markdown(summary, [r.name for r in detail], T, win, dipole_limit) + report_estimation.markdown(est)
    atomic_write(out / "summary.md", md)
    atomic_write(out / "report.html", _html(summary, out, T, win, [r.name for r in detail], dipole_limit,
                                            tuple(r["figure"] for r in est.values())))
    return summary


def _with_note(run: Run, dipole_limit) -> dict:
    """The run's integrity report, with ``note`` (:func:`dipole_note`) when dipole commands were left out."""
    note = dipole_note(run.dipoles_left_out, dipole_limit)
    return {**run.integrity, "note": note} if note else run.integrity


def _integrity_cell(integ: dict) -> str:
    """The report table's "bag integrity" cell: complete, or what was recovered and what is wrong; then
    the note on dipole commands left out, if any (a bag with forged commands is never just "complete")."""
    note = f"; {integ['note']}" if integ.get("note") else ""
    if integ["complete"]:
        return f"files complete{note}" if note else "complete"
    text = f"damaged: {integ.get('messages_recovered')} msgs recovered"
    if integ.get("missing_files"):
        text += f"; missing file(s) {', '.join(integ['missing_files'])}"
    if integ.get("metadata_disagreements"):
        text += f"; metadata.yaml says {integ.get('metadata_message_count')} msgs"
    return text + note


def _rows(summary: dict) -> tuple[list[str], list[list[str]]]:
    head = ["bag", "label", "orbits", "final pointing [deg]", "peak pointing [deg]", "RMS pointing [deg]",
            "RMS window [s]", "final abs(dq_R)", "peak abs(dq_R)", "RMS abs(dq_R)", "peak abs(m) [A m^2]",
            "RMS abs(m) [A m^2]", "samples truth/dipole", "bag integrity"]
    rows = []
    for name, s in summary.items():
        integ = _integrity_cell(s["integrity"])
        lo, hi = s["rms_window"]
        rows.append([name, s["label"], f"{s['orbits']:.3f}", f"{s['final_deg']:.4f}", f"{s['peak_deg']:.4f}",
                     f"{s['rms_deg']:.4f}", f"{lo:.0f}-{hi:.0f}", f"{s['final_dq']:.4e}", f"{s['peak_dq']:.4e}",
                     f"{s['rms_dq']:.4e}", f"{s['peak_m']:.4g}", f"{s['rms_m']:.4g}",
                     f"{s['truth_samples']}/{s['dipole_samples']}", integ])
    return head, rows


def _notes(T: float, win: dict, detail: list[str], dipole_limit: float) -> list[str]:
    a, b = win["fig2"]
    notes = [f"Orbit period T = {T} s. Pointing error = rotation angle of the body w.r.t. the orbital "
             "axes, 2 asin(abs(dq_R)) [deg]; abs(dq_R) = norm of the quaternion vector part (truth); "
             "abs(m) = commanded dipole. RMS over orbits 2-5 (t in [T, 5T]); a run not longer than one "
             "orbit uses all of it: the RMS window of each run is in the table.",
             f"Fig. 2: t = {a:.2f}-{b:.2f} orbits" + ("" if b >= 1.0 else " (every run is shorter than one orbit)")
             + ". " + (f"Fig. 3: t = {win['fig3'][0]:.2f}-{win['fig3'][1]:.2f} orbits." if win["fig3"] else
                       f"Fig. 3 not drawn: no run is longer than one orbit (longest {win['longest_orbits']:.2f})."),
             f"Figs. 4-5: {', '.join(detail)}; dashed lines = per-axis dipole limit +-{dipole_limit:g} A m^2."]
    return notes


def _markdown(summary: dict, detail: list[str], T: float, win: dict, dipole_limit: float) -> str:
    head, rows = _rows(summary)
    lines = ["# magtune run report", "", *[n + "\n" for n in _notes(T, win, detail, dipole_limit)],
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    lines += [f"\n{name}: {s['integrity']['note']}." for name, s in summary.items() if s["integrity"].get("note")]
    lines += report_modes.markdown(summary)
    figs = ", ".join(f"`{f}`" for f in FIGURES if f != FIGURES[1] or win["fig3"])
    lines += ["", f"Figures: {figs} (Figs. 2-5); all in one file: `report.html`.", ""]
    return "\n".join(lines)


def _html(summary: dict, out: Path, T: float, win: dict, detail: list[str], dipole_limit: float,
          extra: tuple = ()) -> str:
    """One self-contained HTML page: the notes, the summary table and the figures inlined as
    base64 PNG (no external file, script or style sheet)."""
    head, rows = _rows(summary)
    esc = html.escape
    table = ("<table><thead><tr>" + "".join(f"<th>{esc(h)}</th>" for h in head) + "</tr></thead><tbody>"
             + "".join("<tr>" + "".join(f"<td>{esc(c)}</td>" for c in r) + "</tr>" for r in rows)
             + "</tbody></table>")
    figs = []
    for f in FIGURES + extra:
        path = out / f
        if path.is_file():
            data = base64.b64encode(path.read_bytes()).decode("ascii")
            figs.append(f'<figure><img alt="{esc(f)}" src="data:image/png;base64,{data}">'
                        f"<figcaption>{esc(f)}</figcaption></figure>")
    notes = "".join(f"<p>{esc(n)}</p>" for n in _notes(T, win, detail, dipole_limit))
    style = ("body{font-family:sans-serif;margin:1.5em;max-width:1300px}table{border-collapse:collapse;"
             "font-size:13px}th,td{border:1px solid #bbb;padding:3px 6px;text-align:right}"
             "th{background:#eee}td:nth-child(-n+2){text-align:left}img{max-width:100%}")
    return (f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>magtune run report</title>"
            f"<style>{style}</style></head><body><h1>magtune run report</h1>{notes}{table}"
            f"{report_modes.html_section(summary)}{''.join(figs)}"
            "</body></html>\n")
