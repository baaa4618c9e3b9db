"""``magtune verify``: pass/fail against the design spec's pointing requirements, exit statuses,
the report, and --record (the only way the gains file changes)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from magtune_core.cli import main as cli_main
from magtune_core.design.gains import load_gains

REPO = Path(__file__).resolve().parents[2]
#: a shipped gain (tuned under config/design.yaml: margin 4 over 1-30 s): meets every requirement
PASSING = REPO / "config/gains/sigma_120.yaml"
#: the unconstrained optimum of J at sigma = 60: commands 230 A m^2 at t = 0 and is unstable held at 20 s
SATURATING = REPO / "config/gains/unconstrained/sigma_60.yaml"
#: few runs, in-process (no cluster): each period's 6 five-orbit runs take ~1 s of CPU
FAST = ["--runs", "6", "--scheduler", "synchronous", "--no-progress"]


def test_a_gain_that_meets_the_requirements_passes(tmp_path, capsys):
    before = PASSING.read_bytes()
    assert cli_main(["verify", str(PASSING), "--out", str(tmp_path / "v"), "--also-ts", "20", *FAST]) == 0
    out = capsys.readouterr().out
    assert "| 1 | settling time | 2 orbits |" in out and "| 30 | saturation fraction after settling | 0.01 |" in out
    assert "| 20 | settling time | 2 orbits |" in out  # --also-ts: the asked period is flown too
    assert "FAIL" not in out and "PASS" in out
    rec = json.loads((tmp_path / "v" / "verify.json").read_text())
    assert rec["passed"] and rec["periods"] == [1.0, 20.0, 30.0] and rec["runs"] == 6
    assert all(v == 1.0 for per in rec["fractions"].values() for v in per.values())
    assert PASSING.read_bytes() == before  # never written without --record


def test_a_saturating_gain_fails_with_status_3(tmp_path, capsys):
    assert cli_main(["verify", str(SATURATING), "--out", str(tmp_path / "v"), *FAST]) == 3
    out = capsys.readouterr().out
    rows = {tuple(c.strip() for c in line.split("|")[1:3]): line for line in out.splitlines() if line.startswith("| ")}
    assert "FAIL" in rows[("1", "saturation fraction after settling")]  # held at 1 s it saturates
    assert "FAIL" in rows[("30", "settling time")] and "never" in rows[("30", "settling time")]  # diverges at 30 s


def test_record_writes_the_verdict_into_the_provenance(tmp_path):
    g = tmp_path / "g.yaml"
    g.write_bytes(PASSING.read_bytes())
    assert cli_main(["verify", str(g), "--out", str(tmp_path / "v"), "--record", *FAST]) == 0
    gains = load_gains(g)
    assert gains.provenance["verification"]["passed"] is True
    assert (gains.K == load_gains(PASSING).K).all()
    assert g.read_text().splitlines()[2] == PASSING.read_text().splitlines()[2]  # the header is kept


@pytest.mark.parametrize("argv, field", [
    (["--runs", "0"], "--runs"),
    (["--spec", "nope.yaml"], "nope.yaml"),
    (["--campaign", "nope.yaml"], "nope.yaml"),
    (["--also-ts", "20,x"], "--also-ts"),
    (["--also-ts", "45"], "--also-ts"),
])
def test_bad_input_is_one_line_and_status_2(tmp_path, capsys, argv, field):
    assert cli_main(["verify", str(PASSING), "--out", str(tmp_path / "v"), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and field in err[0]
    assert not (tmp_path / "v").exists()
