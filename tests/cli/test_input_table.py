"""What a user types, refused before any work (issue 57): a table of inputs, the exit status and the one line.

Each row failed before its change: a null or empty ``tle_file`` flew the default circular orbit with exit 0; an
epoch outside IGRF-14's years passed validation and ended a full-environment SIL with a traceback after its
nodes started (fit-field printed one); ``fit-field --harmonics 100000`` computed without end and
``--harmonics 300 --days 0.1`` fitted 601 unknowns to 433 samples with a residual of 0.00; ``campaign --workers
1000`` on 2 cores started hundreds of processes (load 57) and no run finished. The rows run in
this process (``magtune`` main): no node is started, so a row that got past the checks would fail on its time or
its exit status, not hang.
"""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from cli_errors import one_line_exit2  # tests/support

from magtune_core.base.ament import ROOT

GAINS = str(ROOT / "config" / "gains" / "sigma_60.yaml")
CAMPAIGN = str(ROOT / "config" / "campaigns" / "example.yaml")
SPACECRAFT = ROOT / "config" / "spacecraft.yaml"


def spacecraft(tmp_path: Path, **orbit) -> str:
    """config/spacecraft.yaml with ``orbit`` set in its ``/**`` section (None: a YAML null)."""
    doc = yaml.safe_load(SPACECRAFT.read_text())
    doc["/**"]["ros__parameters"].update(orbit)
    out = tmp_path / "sc.yaml"
    out.write_text(yaml.safe_dump(doc))
    return str(out)


#: (spacecraft file keys or None, the command after ``--config FILE``, the field or option named, words of the line)
ROWS = [
    (dict(tle_file=None), ["analyze", GAINS], "tle_file", "null: give it a value"),
    (dict(tle_file=""), ["analyze", GAINS], "tle_file", "empty: give the element set"),
    (dict(tle=[]), ["analyze", GAINS], "tle", "empty: give the element set"),
    (dict(altitude=None), ["analyze", GAINS], "altitude", "null: give it a value"),
    (dict(epoch="2031-01-01T00:00:00"), ["analyze", GAINS], "epoch", "outside the years of the field model, IGRF-14"),
    (dict(epoch="1899-06-01T00:00:00"), ["sil", "--gains", GAINS, "--environment", "full", "--steps", "10"], "epoch",
     "outside the years of the field model"),
    # inside the years at the start, outside at the run's end: refused before a node starts
    (dict(epoch="2029-12-31T12:00:00"), ["sil", "--gains", GAINS, "--environment", "full", "--orbits", "20"],
     "epoch (the run's last step", "2030-01-01T19:10:25 is outside"),
    (None, ["fit-field", "--harmonics", "100000"], "--harmonics 100000", "resolves at most 70 harmonics"),
    (None, ["fit-field", "--harmonics", "60", "--days", "0.05"], "--harmonics 60",
     "121 unknowns per axis need at least 242 samples, --days 0.05 every --step 20 s gives 217"),
    (None, ["fit-field", "--epoch", "2031-01-01"], "--epoch", "outside the years of the field model"),
    (None, ["fit-field", "--epoch", "2029-12-30"], "--days (the fit's last sample)", "2030-01-02T00:00:00 is outside"),
    # a file given is a file read and validated, whether or not the command uses it this time
    (None, ["analyze", GAINS, "--hardware", "/nonexistent.yaml"], "--hardware", "is read with --requirements only"),
    (None, ["analyze", GAINS, "--requirements", "--hardware", "{tmp}/empty.yaml"], "empty.yaml",
     "expected a mapping with at least one of the sections"),
    (None, ["analyze", GAINS, "--requirements", "--hardware", "{tmp}/null_section.yaml"], "field 'gyro'",
     "null: give the section's fields"),
    # an output that is a dangling symbolic link: export made its directory after the work and died on it
    (None, ["export", GAINS, "--out", "{tmp}/dangling"], "dangling", "is a symbolic link to"),
    # export-check of a vectors file with its header and no row: a traceback (numpy's min of nothing)
    (None, ["export-check", "{tmp}/header_only.csv", "{tmp}/one_row.csv"], "VECTORS: field 'step'", "no rows"),
    (None, ["export-check", "{tmp}/one_row.csv", "{tmp}/header_only.csv"], "header_only.csv: field 'step'", "no rows"),
    # a stuck torquer beyond its rod's limit, and two overlapping faults of one kind on one unit, passed
    (None, ["sil", "--gains", GAINS, "--steps", "50", "--fault", "torquer_stuck@10,axis=x,value=5000"], "field 'value'",
     "5000 A m^2 is beyond the rod's dipole_limit 50 A m^2"),
    (None, ["sil", "--gains", GAINS, "--steps", "50", "--fault", "torquer_stuck@10,axis=x,value=5", "--fault",
            "torquer_stuck@20,axis=x,value=3"], "torquer_stuck@20.0", "overlaps torquer_stuck@10.0"),
    (None, ["sil", "--gains", GAINS, "--steps", "50", "--fault", "mag_spike@10,axis=y", "--fault", "mag_spike@10,axis=y"],
     "mag_spike@10.0", "overlaps mag_spike@10.0"),
    # more local workers than cores: campaign --workers 1000 started hundreds of processes on 2 cores (load 57)
    (None, ["campaign", CAMPAIGN, "--runs", "1", "--out", "{tmp}/c", "--workers", "1000"], "--workers",
     "1000 local workers on"),
    (None, ["verify", GAINS, "--runs", "1", "--out", "{tmp}/v", "--workers", "1000"], "--workers", "--oversubscribe"),
    (None, ["tune", "--sigma", "60", "--out", "{tmp}/g.yaml", "--workers", "1000"], "--workers", "--oversubscribe"),
    (None, ["sampling", "--out-dir", "{tmp}/s", "--workers", "1000"], "--workers", "--oversubscribe"),
]


#: The input files the rows name (made by the test), not outputs.
INPUTS = ("empty.yaml", "null_section.yaml", "sc.yaml", "dangling", "header_only.csv", "one_row.csv")


@pytest.mark.parametrize("keys, command, named, words", ROWS, ids=[f"{r[1][0]}-{r[2]}" for r in ROWS])
def test_refused_with_one_line_and_exit_2(tmp_path, capsys, keys, command, named, words):
    (tmp_path / "empty.yaml").write_text("")
    (tmp_path / "null_section.yaml").write_text("gyro:\n")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere" / "out")
    (tmp_path / "header_only.csv").write_text("step,t,m_x\n")
    (tmp_path / "one_row.csv").write_text("step,t,m_x\n0,0,1\n")
    command = [a.replace("{tmp}", str(tmp_path)) for a in command]
    argv = (["--config", spacecraft(tmp_path, **keys)] if keys is not None else []) + command
    if command[0] == "fit-field":
        argv += ["--out", str(tmp_path / "field.yaml")]
    line = one_line_exit2(capsys, argv)
    assert named in line and words in line, line
    made = sorted(p.name for p in tmp_path.iterdir() if p.name not in INPUTS)
    assert made == [], f"work was done before the refusal: {made}"


def test_a_byte_order_mark_before_the_header_is_read_as_nothing(tmp_path, capsys):
    """A spreadsheet's CSV starts with a UTF-8 BOM: its header read as "no 'step' column" (issue 57); now the same
    rows with and without it compare equal (export-check exit 0)."""
    from magtune_core.cli import main as cli_main

    (tmp_path / "v.csv").write_text("step,t,m_x\n0,0,1\n1,1,2\n")
    (tmp_path / "o.csv").write_bytes(b"\xef\xbb\xbfstep,t,m_x\n0,0,1\n1,1,2\n")
    assert cli_main(["export-check", str(tmp_path / "v.csv"), str(tmp_path / "o.csv")]) == 0, capsys.readouterr().err
