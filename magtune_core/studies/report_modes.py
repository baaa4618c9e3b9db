"""The flight modes of a recorded run in ``magtune report``: coloured bands on the pointing-error plot
and the transitions listed in the report text.

A bag recorded with ``magtune sil --modes`` holds the mode manager's ``mode`` topic
(magtune_interfaces/Mode: the mode, the previous one, the reason, stamped with the sim time the
mode was entered; transient-local, so the first message is the initial mode). Decoded without
rclpy (the message's definition is registered from :data:`MODE_DEFINITION`); a bag without the
topic has no modes and its report is unchanged.
"""
from __future__ import annotations

import html
from dataclasses import dataclass
from pathlib import Path

from .. import bags as baglib
from ..bags.decode import Decoder, stamp_ns
from ..base.topics import MODE, TOPIC_MODE
from ..onboard.modes import ACQUISITION, DETUMBLE, POINTING, SAFE

MODE_TYPE = "magtune_interfaces/msg/Mode"
#: The fields of ros2_ws/src/magtune_interfaces/msg/Mode.msg (constants left out: not needed to decode).
MODE_DEFINITION = "std_msgs/Header header\nuint8 mode\nstring label\nuint8 previous\nstring reason\n"
#: Band colour of each mode (matplotlib names): the band is drawn at BAND_ALPHA behind the curves.
MODE_COLORS = {DETUMBLE: "tab:orange", ACQUISITION: "tab:purple", POINTING: "tab:green", SAFE: "tab:red"}
BAND_ALPHA = 0.15


@dataclass(frozen=True)
class ModeChange:
    """One message of the mode topic: sim time [s] the mode was entered, the mode, the one before, why."""

    t: float
    mode: str
    previous: str
    reason: str


def attach(runs: list, bag) -> list:
    """Set ``run.modes`` (:func:`load_modes` of its mode topic) on each run of ``bag``; returns ``runs``."""
    for r in runs:
        r.modes = load_modes(bag, mode_topic(Path(bag).name, r.name))
    return runs


def mode_topic(bag_name: str, run_name: str) -> str:
    """The mode topic of a run of :func:`magtune_core.studies.report.load_runs` (``<bag>/<ns>``: ``/<ns>/mode``)."""
    ns = run_name[len(bag_name):] if run_name.startswith(bag_name) else ""
    return f"{ns}/{TOPIC_MODE}" if ns else MODE


def load_notices(path, topic: str = MODE) -> list[ModeChange]:
    """The mode manager's fault notices of a bag: the mode republished unchanged with a unit's fault as its reason.

    Returns
    -------
    list of ModeChange
        In stamp order; ``mode`` the mode in force (unchanged), ``reason`` the unit's message.
    """
    out, last = [], None
    for c in _mode_messages(path, topic):
        if last is not None and c.mode == last.mode and c.reason != last.reason and c.t != last.t:
            out.append(c)
        last = c
    return out


def load_modes(path, topic: str = MODE) -> list[ModeChange]:
    """The mode changes of a bag in stamp order (repeats of the same mode dropped: a transient-local copy, a fault
    notice), [] without the topic.

    Returns
    -------
    list of ModeChange
        The initial mode first (its reason "start"), then one entry per transition.
    """
    kept = []
    for c in _mode_messages(path, topic):  # a repeat of the mode (a late-joining subscriber's transient-local
        # copy, or the manager's notice of a unit's fault, which republishes the mode with the fault as its reason)
        if not kept or c.mode != kept[-1].mode:
            kept.append(c)
    return kept


def _mode_messages(path, topic: str) -> list[ModeChange]:
    """Every message of the mode topic, in stamp order (the bag's time origin subtracted)."""
    path = Path(path)
    if topic not in baglib.topics_of(path):
        return []
    d = Decoder()
    d.learn(MODE_TYPE, MODE_DEFINITION)
    origin = 0
    try:
        origin = int((baglib.read_metadata(path).get("custom_data") or {}).get("time_origin_ns", 0))
    except (OSError, KeyError, TypeError, ValueError, AttributeError):
        pass
    out = []
    for msg in baglib.iter_messages(path, topics=[topic]):
        o = d.decode(msg.data, MODE_TYPE)
        s = stamp_ns(o)
        out.append(ModeChange(((msg.log_time if s is None else s) - origin) * 1e-9, str(o.label),
                              _label(o.previous), str(o.reason)))
    out.sort(key=lambda c: c.t)
    return out


def _label(i: int) -> str:
    from ..onboard.modes import MODES

    return MODES[i] if 0 <= int(i) < len(MODES) else str(i)


def spans(changes: list[ModeChange], t_end: float) -> list[tuple[float, float, str]]:
    """(start, end [s], mode) of each mode interval up to ``t_end`` (the run's last sample).

    Returns
    -------
    list of tuple
        Contiguous intervals in time order; empty without mode messages.
    """
    out = []
    for c, nxt in zip(changes, changes[1:] + [None]):
        end = t_end if nxt is None else nxt.t
        if end > c.t or nxt is None:
            out.append((c.t, max(end, c.t), c.mode))
    return out


def draw_bands(ax, mode_spans: list[tuple[float, float, str]], T: float, lo: float, hi: float) -> list:
    """Coloured bands (``axvspan``) of ``mode_spans`` on ``ax`` within [lo, hi] [s], x in orbits of ``T`` [s];
    each mode labelled once (the figure's legend shows them).

    Returns
    -------
    list of tuple
        (start, end [orbits], mode, colour) of each band drawn: the figure's data, for tests.
    """
    drawn, labelled = [], {label.removeprefix("mode ") for label in ax.get_legend_handles_labels()[1]}
    for a, b, mode in mode_spans:
        a, b = max(a, lo), min(b, hi)
        if b <= a:
            continue
        color = MODE_COLORS.get(mode, "tab:gray")
        ax.axvspan(a / T, b / T, color=color, alpha=BAND_ALPHA, lw=0,
                   label=None if mode in labelled else f"mode {mode}")
        labelled.add(mode)
        drawn.append((a / T, b / T, mode, color))
    return drawn


def transitions_table(changes: list[ModeChange]) -> list[dict]:
    """The transitions (the initial mode excluded) as rows: t [s], from, to, reason."""
    return [{"t": c.t, "from": c.previous, "to": c.mode, "reason": c.reason} for c in changes[1:]]


def markdown(summary: dict) -> list[str]:
    """The report text's "Flight modes" section: for each run with modes, its initial mode and transitions."""
    runs = {name: s for name, s in summary.items() if s.get("modes")}
    if not runs:
        return []
    lines = ["", "## Flight modes", "", "Bands on the pointing-error plots (Figs. 2-3): "
             + ", ".join(f"{m} {c.removeprefix('tab:')}" for m, c in MODE_COLORS.items()) + ".", ""]
    for name, s in runs.items():
        m = s["modes"]
        lines += [f"{name}: starts in {m['initial']}; {len(m['transitions'])} transition(s).", "",
                  "| t [s] | from | to | reason |", "|---|---|---|---|"]
        lines += [f"| {r['t']:.1f} | {r['from']} | {r['to']} | {r['reason']} |" for r in m["transitions"]]
        lines.append("")
    return lines[:-1]


def html_section(summary: dict) -> str:
    """:func:`markdown`'s section as HTML (tables of the transitions)."""
    esc = html.escape
    out = []
    for name, s in summary.items():
        m = s.get("modes")
        if not m:
            continue
        rows = "".join(f"<tr><td>{r['t']:.1f}</td><td>{esc(r['from'])}</td><td>{esc(r['to'])}</td>"
                       f"<td>{esc(r['reason'])}</td></tr>" for r in m["transitions"])
        out.append(f"<h2>Flight modes: {esc(name)}</h2><p>starts in {esc(m['initial'])}</p><table><thead><tr>"
                   f"<th>t [s]</th><th>from</th><th>to</th><th>reason</th></tr></thead><tbody>{rows}</tbody></table>")
    return "".join(out)


def summary_entry(changes: list[ModeChange], t_end: float) -> dict | None:
    """What summary.json keeps of a run's modes (None without): initial mode, transitions, spans."""
    if not changes:
        return None
    return {"initial": changes[0].mode, "transitions": transitions_table(changes),
            "spans": [list(s) for s in spans(changes, t_end)]}
