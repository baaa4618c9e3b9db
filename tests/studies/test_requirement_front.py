"""``magtune front --over ts_max|dipole_limit``: one tuned point per (sigma, level), the reference
gains at every level, an infeasible level named, outputs written; tiny budgets on the constant field."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from magtune_core.cli import main
from magtune_core.design.requirements import Requirements
from magtune_core.studies.requirement_front import at_level, hardest_first

REPO = Path(__file__).resolve().parents[2]
#: a coarse spec: 3 checked and 12 scanned periods, a certificate grid of 0.05, keep each point to a few seconds
SPEC = """sampling: {ts_min: 1.0, ts_max: 20.0, gain_margin: 4.0, check_periods: 3, scan_periods: 12, scale_step: 0.05}
dipole: {horizon_orbits: 1.0}
"""
TINY = ["--field-model", "constant", "--popsize", "4", "--max-evals", "8", "--workers", "1"]


@pytest.fixture
def spec(tmp_path):
    p = tmp_path / "design.yaml"
    p.write_text(SPEC)
    return p


def test_levels_move_one_requirement_and_run_hardest_first():
    req = Requirements.from_mapping({}, 50.0)
    assert at_level(req, "ts_max", 30).sampling["ts_max"] == 30 and at_level(req, "ts_max", 30).dipole_limit == 50
    assert at_level(req, "dipole_limit", 20).dipole_budget == pytest.approx(16.0)  # 0.8 x 20
    assert at_level(req, "dipole_limit", 20).sampling == req.sampling
    assert hardest_first("ts_max", [1, 35, 20]) == [35, 20, 1]
    assert hardest_first("dipole_limit", [50, 10, 30]) == [10, 30, 50]


def test_ts_max_front_writes_points_and_references(tmp_path, spec):
    out = tmp_path / "f"
    assert main(["front", "--over", "ts_max", "--levels", "1,20", "--sigmas", "60", "--spec", str(spec),
                 "--out-dir", str(out), *TINY]) == 0
    rec = json.loads((out / "front_ts_max.json").read_text())
    tuned = [p for p in rec["points"] if p["label"] == "tuned"]
    refs = [p for p in rec["points"] if p["label"] != "tuned"]
    assert [p["level"] for p in tuned] == [20.0, 1.0]  # continuation: hardest first
    assert [p["label"] for p in refs] == ["paper_method/sigma_60.yaml"] * 2
    # the reference's J does not depend on the level, its certified hold margin over 1..ts_max does
    assert refs[0]["J"] == refs[1]["J"] and refs[0]["hold_margin_min"] <= refs[1]["hold_margin_min"]
    for p in tuned:
        # met: certified stable for every k of the grid up to 4 x 1.005 (the guard) at every admissible period
        assert p["met"] and p["hold_margin_min"] >= 4.0 * 1.005 - 1e-9 and p["dipole_peak"] <= 0.8 * 50 + 1e-9
    assert (out / "front_ts_max.png").stat().st_size > 10000
    assert "| 60 | 20 | tuned |" in (out / "front_ts_max.md").read_text()


def test_an_infeasible_dipole_level_is_named(tmp_path, spec):
    out = tmp_path / "f"
    assert main(["front", "--over", "dipole_limit", "--levels", "0.01,50", "--sigmas", "60", "--spec", str(spec),
                 "--reference", "--out-dir", str(out), *TINY]) == 0
    pts = json.loads((out / "front_dipole_limit.json").read_text())["points"]
    bad = [p for p in pts if p["level"] == 0.01][0]
    assert bad["gain"] is None and "peak |m_" in bad["note"] and "binding" in bad["note"]
    good = [p for p in pts if p["level"] == 50][0]
    assert good["gain"] is not None and good["met"]


@pytest.mark.parametrize("argv, option", [
    (["--over", "ts_max", "--ts", "5"], "--ts"),
    (["--over", "ts_max", "--levels", "0.5"], "--levels"),
    (["--levels", "5"], "--levels"),
    (["--over", "ts_max", "--start", "missing.yaml"], "missing.yaml"),
])
def test_bad_options_are_one_line_and_status_2(tmp_path, capsys, argv, option):
    assert main(["front", *argv, "--out-dir", str(tmp_path / "x"), *TINY]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and option in err[0]


def test_resume_keeps_the_points_of_an_interrupted_front(tmp_path, spec, capsys):
    out = tmp_path / "f"
    args = ["front", "--over", "ts_max", "--levels", "1,20", "--sigmas", "60", "--spec", str(spec), "--reference",
            "--out-dir", str(out), *TINY]
    assert main(args) == 0
    first = json.loads((out / "front_ts_max.json").read_text())["points"]
    assert not (out / "front_ts_max.partial.json").exists()  # removed once the front is complete
    # an interruption after the first level: its partial record holds that point only
    (out / "front_ts_max.partial.json").write_text(json.dumps({"axis": "ts_max", "points": first[:1]}))
    assert main(args + ["--force", "--resume"]) == 0
    again = json.loads((out / "front_ts_max.json").read_text())["points"]
    assert again[0] == first[0]  # kept as recorded, not re-tuned
    assert [p["level"] for p in again] == [20.0, 1.0] and again[1]["gain"] is not None
    assert "resuming with 1 points" in capsys.readouterr().err
