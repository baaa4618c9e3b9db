"""The torquer watch in campaigns (``estimator.torquer_watch``): asked for in the spec, validated like the other
keys, replayed over every run (sim/batch_torquer.py) into the rows torquer_unit / torquer_time / torquer_kind /
torquer_verdicts, and summarized by campaign-report per injected torquer fault (detected %, time to detect) or, without
one, as false detections."""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from magtune_core.base.errors import ConfigError
from magtune_core.studies import campaign, campaign_report

RUNS = 3
ONSET = 900.0
#: The estimator in the loop without modes (a campaign with modes starts from a tumble): the watch runs wherever the
#: estimate exists; 1500 steps of 1 s (the watch's first test needs 540 s of data, then up to 600 s after the onset).
SPEC = dict(
    campaign=dict(name="tw", seed=3, gains="config/gains/sigma_60.yaml", environment="full", orbits=1500.0 / 5670.0,
                  ts=1.0, batch_size=RUNS, history_step=60.0, attitude="estimator"),
    dispersions=dict(attitude_max_deg=2.0, rate_max=[2e-4, 2e-4, 2e-4], epoch_min="2026-03-01T00:00:00",
                     epoch_max="2026-04-01T00:00:00", raan_min_deg=0.0, raan_max_deg=360.0, mag_noise_std=1e-7,
                     gyro_arw=1e-4, gyro_rrw=1e-6, gyro_bias_std=3e-4, sun_noise_std=math.radians(0.5),
                     dipole_limit_min=50.0),
    criteria=dict(settle_threshold_deg=12.0, max_settling_orbits=0.1, max_pointing_deg=90.0),
    estimator=dict(gyro_arw=1e-4, gyro_rrw=1e-6, torquer_watch=True),
)


def _spec(tmp_path, raw, name="spec.yaml"):
    p = tmp_path / name
    p.write_text(yaml.safe_dump(raw))
    return p


def test_torquer_watch_key_validated_and_off_by_default(tmp_path):
    """A value other than true/false is one line naming the key; without the key no run records or replays anything."""
    with pytest.raises(ConfigError, match=r"torquer_watch.*true or false"):
        campaign.load_spec(_spec(tmp_path, dict(SPEC, estimator=dict(torquer_watch="yes"))))
    plain = campaign.load_spec(_spec(tmp_path, dict(SPEC, estimator=dict(gyro_arw=1e-4)), "plain.yaml"))
    assert plain.batch_estimator().torquer_watch is False
    assert campaign.load_spec(_spec(tmp_path, SPEC, "on.yaml")).batch_estimator().torquer_watch is True


def _run(tmp_path_factory, name, faults):
    tmp = tmp_path_factory.mktemp(name)
    raw = dict(SPEC, faults=list(faults)) if faults else SPEC
    out = tmp / "out"
    campaign.run_campaign(campaign.load_spec(_spec(tmp, raw)), RUNS, out, scheduler="synchronous", progress=False)
    return out


@pytest.fixture(scope="module")
def stuck(tmp_path_factory):
    return _run(tmp_path_factory, "stuck", [f"torquer_stuck@{ONSET:g},axis=y,value=25"])


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    return _run(tmp_path_factory, "clean", [])


def test_rows_and_report_with_a_stuck_torquer(stuck):
    """Every run names torquer y first, after the onset and within 600 s of it (measured: 119, 359 and 359 s), and
    declares no other axis; the report's row for the fault says 3 / 3 with the delays' p50 / p95, none early or on
    another axis first, all named stuck."""
    cols = campaign.read_runs(stuck)
    assert list(cols["status"]) == ["ok"] * RUNS
    assert list(cols["torquer_unit"]) == ["torquer y"] * RUNS, cols["torquer_unit"]
    t = cols["torquer_time"].astype(float)
    assert np.all((t > ONSET) & (t <= ONSET + 600.0)), t
    assert np.all(cols["torquer_verdicts"] >= 1) and list(cols["torquer_kind_y"]) == list(cols["torquer_kind"])
    assert np.array_equal(cols["torquer_time_y"], t) and np.all(np.isnan(cols["torquer_time_x"].astype(float)))
    md = campaign_report.write_report(stuck)
    p50, p95 = np.percentile(t - ONSET, (50.0, 95.0))
    assert "## Torquer watch" in md
    assert list(cols["torquer_kind"]) == ["stuck"] * RUNS
    assert f"| torquer_stuck@900.0,axis=y,value=25.0 | 3 / 3 (100.0 %) | {p50:.4g} / {p95:.4g} | 0 | 0 | stuck 3 |" in md, md


def test_rows_and_report_without_a_fault(clean):
    """The same runs fault-free: no torquer named, and the report says so (0 false detections)."""
    cols = campaign.read_runs(clean)
    assert list(cols["torquer_unit"]) == [""] * RUNS and np.all(np.isnan(cols["torquer_time"].astype(float)))
    assert list(cols["torquer_verdicts"]) == [0] * RUNS
    md = campaign_report.write_report(clean)
    assert f"No torquer fault injected: **0 / {RUNS}** ok runs named a torquer (false detections)." in md
    assert any("torquer watch: 0 of 3" in line for line in campaign_report.summary_lines(
        campaign_report.json.loads((clean / "campaign.json").read_text()), cols))
