"""Monte Carlo verification of gains against the design spec's pointing requirements.

``magtune verify GAINS`` flies the gains on the campaign engine (:mod:`.campaign`: batched,
Dask) in the campaign spec's environment and dispersions (default ``config/campaigns/example.yaml``:
full environment, 10 deg initial attitude, inertia, residual dipole, sensor noise, torquer
limits), at three sample periods: the ends of the spec's range and the period where the hold
margin is tightest (the minimum of the dense scan, ``design.pipeline.requirement_provenance``;
the gains file's ``hold_tightest_ts`` when it has one). The criteria come from the design spec's
``pointing`` section, never from what a gain happens to do. A requirement passes at a period when
at least ``pass_fraction`` of the runs meet it; the gains pass when every requirement passes at
every period and no run failed to complete.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..design.gains import load_gains
from ..design.requirements import Requirements
from .campaign import CampaignSpec, load_spec, read_runs, run_campaign

#: Percentiles of each figure in the table.
PERCENTILES = (50.0, 95.0, 99.0)
#: Exit statuses of ``magtune verify`` (documented in docs/cli.md).
PASSED, RUN_FAILED, BAD_INPUT, REQUIREMENT_FAILED = 0, 1, 2, 3


@dataclass(frozen=True)
class Row:
    """One requirement at one sample period: its per-run values' percentiles and the pass fraction."""

    ts: float
    name: str
    unit: str
    limit: float
    percentiles: tuple
    worst: float
    fraction: float     # fraction of runs meeting it
    required: float     # the spec's pass_fraction

    @property
    def ok(self) -> bool:
        """At least the required fraction of runs meets the requirement."""
        return self.fraction >= self.required


def criteria_of(req: Requirements) -> dict:
    """The campaign criteria of the design spec's pointing requirements (the limits verify applies). A campaign
    that flies the modes (the full stack) must also be settled in POINTING within the spec's settling time."""
    p = req.pointing
    return dict(settle_threshold_deg=p["settle_threshold_deg"], max_settling_orbits=p["max_settling_orbits"],
                max_deployment_orbits=p["max_settling_orbits"],
                max_pointing_deg=p["max_pointing_deg"], max_rms_pointing_deg=p["max_rms_pointing_deg"],
                max_steady_saturation_fraction=p["max_saturation_fraction"],
                max_saturation_fraction=p["max_total_saturation_fraction"], max_peak_dipole=None)


def verify_periods(req: Requirements, tightest: float | None, extra=()) -> list:
    """ts_min, the tightest period of the hold scan (if inside the range) and ts_max, ascending,
    distinct, with the ``extra`` periods [s] a user asks for too (e.g. the flight computer's own)."""
    lo, hi = float(req.sampling["ts_min"]), float(req.sampling["ts_max"])
    ts = {lo, hi} | {float(t) for t in extra}
    # the tightest period, unless it is an end (within 1 %: T / round(T / Ts) moves Ts by up to Ts / 2T)
    if tightest is not None and lo <= tightest <= hi and min(abs(tightest / t - 1.0) for t in ts) > 0.01:
        ts.add(round(float(tightest), 4))
    return sorted(ts)


def campaign_for(spec: CampaignSpec, gains_path, ts: float, req: Requirements, p=None) -> CampaignSpec:
    """``spec`` flying the gains of ``gains_path`` at ``ts`` under the requirements' criteria, on
    spacecraft ``p`` (default the campaign's). What the design spec states is what is flown: the
    initial rate and the residual dipole of its ``dipole`` section (its +- radius as 3 sigma) and
    torquers anywhere between the budget and the limit (the weakest torquer the design holds for);
    the campaign keeps the rest (environment, epochs, attitude, inertia, sensor noise). The hardware file
    the design spec was resolved against (``req.hardware``, ``--hardware``) replaces the sensor noise figures
    and the torquers' range with its own (:meth:`magtune_core.design.hardware.Hardware.verify_dispersions`)."""
    g = load_gains(gains_path)
    d = req.dipole
    disp = dict(spec.dispersions, rate_mean=np.asarray(d["rate_nominal"], float),
                rate_max=np.asarray(d["rate_radius"], float), residual_dipole_mean=np.asarray(d["residual_nominal"], float),
                residual_dipole_std=np.asarray(d["residual_radius"], float) / 3.0,
                dipole_limit_min=float(req.dipole_budget or req.dipole_limit), dipole_limit_max=float(req.dipole_limit))
    if req.hardware is not None:
        disp.update(req.hardware.verify_dispersions(req.dipole_budget, req.dipole_limit))
    camp = dict(spec.campaign, ts=float(ts))
    if p is not None:
        camp["arg_lat_deg"] = float(p.arg_lat_deg)
    return replace(spec, campaign=camp, dispersions=disp, gains_files=[str(gains_path)], p=p or spec.p,
                   K=np.asarray(g.K, dtype=float).reshape(1, 3, 6), criteria=criteria_of(req))


def _rows(ts: float, cols: dict, req: Requirements, period: np.ndarray) -> list:
    """The requirement rows of one period's runs (``cols``: runs.parquet columns)."""
    p = req.pointing
    ok = cols["status"] == "ok"
    settle = np.where(ok, cols["settling_time"] / period, np.inf)  # in orbits; nan (never) -> inf below
    settle = np.where(np.isfinite(settle), settle, np.inf)
    items = [("settling time", "orbits", p["max_settling_orbits"], settle),
             ("peak pointing error after settling", "deg", p["max_pointing_deg"], cols["max_pointing_deg"]),
             ("RMS pointing error after settling", "deg", p["max_rms_pointing_deg"], cols["rms_pointing_deg"]),
             ("saturation fraction after settling", "-", p["max_saturation_fraction"],
              cols["steady_saturation_fraction"])]
    if p["max_total_saturation_fraction"] is not None:
        items.append(("saturation fraction (whole run)", "-", p["max_total_saturation_fraction"],
                      cols["saturation_fraction"]))
    out = []
    for name, unit, limit, v in items:
        v = np.where(ok & np.isfinite(v), v, np.inf).astype(float)
        meets = v <= limit
        out.append(Row(ts, name, unit, float(limit), tuple(float(np.percentile(v, q, method="higher")) for q in PERCENTILES),
                       float(v.max()), float(meets.mean()), float(p["pass_fraction"])))
    peak = np.where(ok, cols["peak_dipole"], np.inf).astype(float)
    out.append(Row(ts, "peak |m| (informational)", "A m^2", math.inf,
                   tuple(float(np.percentile(peak, q, method="higher")) for q in PERCENTILES), float(peak.max()), 1.0, 0.0))
    if p["max_total_saturation_fraction"] is None:
        tot = np.where(ok, cols["saturation_fraction"], np.inf).astype(float)
        out.append(Row(ts, "saturation fraction, whole run (informational)", "-", math.inf,
                       tuple(float(np.percentile(tot, q, method="higher")) for q in PERCENTILES), float(tot.max()),
                       1.0, 0.0))
    return out


def run_verify(gains_path, req: Requirements, campaign_path, runs: int, out, *, tightest: float | None = None,
               p=None, scheduler: str | None = None, workers: int | None = None, progress: bool = False,
               tls=None, extra_periods=()) -> dict:
    """Fly ``gains_path`` on spacecraft ``p`` (:func:`campaign_for`) at :func:`verify_periods` on
    ``runs`` dispersed runs each; write each period's campaign under ``out/ts_<Ts>/``.
    ``scheduler``, ``workers`` and ``tls`` (a :class:`.cluster.TlsFiles` of a tls:// scheduler)
    are :func:`.campaign.run_campaign`'s; ``extra_periods`` [s] are flown too.

    Returns
    -------
    dict
        ``rows`` (list of :class:`Row`), ``passed`` (every requirement at every period),
        ``failed_runs`` (runs that did not complete: status failed), ``periods``, ``runs``,
        ``seconds`` and the campaign directories.
    """
    import time

    t0 = time.perf_counter()
    base = load_spec(campaign_path)
    out = Path(out)
    rows, failed, dirs = [], 0, []
    periods = verify_periods(req, tightest, extra_periods)
    for ts in periods:
        spec = campaign_for(base, gains_path, ts, req, p)
        d = out / f"ts_{ts:g}"
        run_campaign(spec, runs, d, scheduler=scheduler, workers=workers, progress=progress, tls=tls)
        cols = read_runs(d)
        failed += int(np.sum(cols["status"] == "failed"))
        rows += _rows(ts, cols, req, np.asarray(cols["orbit_period"], dtype=float))
        dirs.append(str(d))
    passed = failed == 0 and all(r.ok for r in rows)
    return dict(rows=rows, passed=passed, failed_runs=failed, periods=periods, runs=runs,
                seconds=time.perf_counter() - t0, dirs=dirs, campaign=str(campaign_path))


def table(result: dict) -> str:
    """The pass/fail table of :func:`run_verify` (markdown)."""
    head = "| Ts [s] | requirement | limit | " + " | ".join(f"p{q:g}" for q in PERCENTILES) + \
        " | worst | runs meeting it | verdict |"
    lines = [head, "|" + "---|" * (7 + len(PERCENTILES) - 1)]
    for r in result["rows"]:
        cells = [f"{r.ts:g}", r.name] + ["-"] + [_num(v) for v in r.percentiles] + [_num(r.worst), "-", "-"]
        if math.isfinite(r.limit):
            cells[2] = f"{r.limit:g} {r.unit}" if r.unit != "-" else f"{r.limit:g}"
            cells[-2:] = [f"{r.fraction:.1%} (>= {r.required:.0%})", "pass" if r.ok else "FAIL"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _num(v: float) -> str:
    return "never" if v == math.inf else f"{v:.3g}"


def summary(result: dict) -> dict:
    """A JSON-able record of the verification (what ``--record`` writes into the gains' provenance).

    Returns
    -------
    dict
        passed, runs, periods, failed_runs, campaign and per period the fraction of runs meeting each requirement.
    """
    per = {}
    for r in result["rows"]:
        if math.isfinite(r.limit):
            per.setdefault(f"ts_{r.ts:g}", {})[r.name] = round(r.fraction, 4)
    return dict(passed=bool(result["passed"]), runs=int(result["runs"]), periods=[float(t) for t in result["periods"]],
                failed_runs=int(result["failed_runs"]), campaign=result["campaign"], fractions=per)
