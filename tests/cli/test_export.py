"""``magtune export`` and ``magtune export-check``: the flight table and its equivalence vectors.

One export of the 12U example (a short run: DETUMBLE's persistence shortened by a --params file, so
B-dot, the mode change and eq. 17 all appear in 300 samples) is shared by the tests. The C header is
compiled by the machine's ``cc``; a machine without one fails here (scripts/bootstrap.sh installs
Debian's gcc): the header's compilation is never skipped.
"""
from __future__ import annotations

import hashlib
import json
import re
import shutil
import struct
import subprocess

import numpy as np
import pytest

from magtune_core.base.ament import ROOT
from magtune_core.base.paramfile import check_ros_params
from magtune_core.base.schema import parse
from magtune_core.cli import main as cli_main
from magtune_core.design.gains import Gains, load_gains
from magtune_core.design.params import SpacecraftParams, load_spacecraft
from magtune_core.onboard.modes import ACQUISITION, DETUMBLE, MODES, POINTING
from magtune_core.studies import flight_table as ft
from magtune_core.studies import flight_vectors as fv

EXAMPLE = ROOT / "config" / "examples" / "cubesat12u"
GAINS = EXAMPLE / "gains_sigma120.yaml"
SPACECRAFT = EXAMPLE / "spacecraft.yaml"
STEPS = 300
FILES = {"flight_params.yaml", "flight_table.json", "flight_table.h", "flight_vectors.csv", "flight_vectors.parquet",
         "README.md"}


@pytest.fixture(scope="module")
def export(tmp_path_factory):
    """(output directory, --params file) of one export of the 12U example."""
    d = tmp_path_factory.mktemp("export")
    params = d / "modes.yaml"
    params.write_text("/**/mode_manager:\n  ros__parameters:\n    detumble_exit_time: 100.0\n")
    out = d / "out"
    assert cli_main(["export", str(GAINS), "--spacecraft", str(SPACECRAFT), "--params", str(params), "--steps",
                     str(STEPS), "--out", str(out)]) == 0
    return out, params


def _bits(x: float) -> bytes:
    return struct.pack("<d", float(x))


def _one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    return lines[0]


# ---------------------------------------------------------------- files, overwrite, JSON hash
def test_export_writes_every_file_and_refuses_to_overwrite(export, capsys):
    out, params = export
    assert {p.name for p in out.iterdir()} == FILES
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    capsys.readouterr()
    argv = ["export", str(GAINS), "--spacecraft", str(SPACECRAFT), "--params", str(params), "--steps", str(STEPS),
            "--out", str(out)]
    assert cli_main(argv) == 2
    line = _one_line(capsys.readouterr().err)
    assert "--force" in line and str(out) in line, line
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # nothing was touched
    # --force rewrites; the export is reproducible: the same inputs give the same bytes (no time stamp)
    assert cli_main(argv + ["--force"]) == 0
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_json_hash_is_the_sha256_of_the_canonical_content(export):
    out, _ = export
    doc = json.loads((out / "flight_table.json").read_text())
    # the definition of docs/export.md, written out here independently of the module
    rest = {k: v for k, v in doc.items() if k != "sha256"}
    canonical = json.dumps(rest, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    assert hashlib.sha256(canonical.encode("ascii")).hexdigest() == doc["sha256"]
    assert ft.content_hash(doc) == doc["sha256"]
    rest["nodes"]["controller"]["sigma"]["value"] = 121.0  # any change moves the hash
    assert ft.content_hash(rest) != doc["sha256"]
    assert doc["format"] == ft.FORMAT and doc["schema_version"] == ft.SCHEMA_VERSION
    for name, sha in doc["files"].items():  # the files written beside it, as written
        assert hashlib.sha256((out / name).read_bytes()).hexdigest() == sha, name
    for role, src in doc["sources"].items():
        assert hashlib.sha256((ROOT / src["path"]).read_bytes() if role != "params" else
                              (out.parent / "modes.yaml").read_bytes()).hexdigest() == src["sha256"], role
    g = load_gains(GAINS)
    assert doc["design"]["J"] == g.provenance["J"] and doc["design"]["sigma"] == g.sigma
    assert doc["nodes"]["mode_manager"]["detumble_exit_time"] == {**doc["nodes"]["mode_manager"]["detumble_exit_time"],
                                                                  "value": 100.0, "source": "--params"}
    assert "mode_manager.handover_angle" in doc["defaults"]  # what no file sets is named as a default
    assert doc["vectors"]["coverage"]["steps"] == STEPS


# ---------------------------------------------------------------- the ROS 2 parameter file
def test_parameter_file_is_what_the_nodes_load(export):
    """Each flight node's section, read by the project's rcl-compatible reader, passes the node's schemas;
    the gain is the gains file's bit for bit."""
    out, _ = export
    path = out / "flight_params.yaml"
    K = load_gains(GAINS).K
    for node in ft.FLIGHT_NODES:
        params = check_ros_params(path, node)
        SpacecraftParams.from_mapping(params, path)  # the mission data every node declares
        v = parse(params, ft.NODE_FIELDS[node], path)
        assert v["ts"] == 1.0
        if node == "controller":
            g = Gains.from_mapping(params, path)
            assert g.K.tobytes() == K.tobytes()
            assert list(v["dipole_limit"]) == [0.2, 0.2, 0.2]  # the spacecraft file's controller section
    table = ft.read_parameter_file(path)
    assert table.values["mode_manager"]["detumble_exit_time"] == 100.0
    assert table.values["attitude_estimator"]["validity_gate"] is True


# ---------------------------------------------------------------- the C header
_DOUBLE = re.compile(r"static const double (\w+)(\[[^=]*\])? = \{?([^;]*?)\}?;", re.S)


def _header_doubles(text: str) -> dict:
    """name -> list of the double literals of the header."""
    return {m.group(1): [float(x) for x in re.split(r"[,\s{}]+", m.group(3)) if x] for m in _DOUBLE.finditer(text)}


def test_header_doubles_parse_back_bit_for_bit(export):
    out, _ = export
    text = (out / "flight_table.h").read_text()
    table = ft.read_parameter_file(out / "flight_params.yaml")
    d = _header_doubles(text)
    K = load_gains(GAINS).K
    assert [_bits(x) for x in d["MAGTUNE_CTRL_K"]] == [_bits(x) for x in K.ravel()]
    assert _bits(d["MAGTUNE_EST_MAG_NOISE_STD"][0]) == _bits(table.values["attitude_estimator"]["mag_noise_std"])
    assert _bits(d["MAGTUNE_CTRL_ORBIT_RATE"][0]) == _bits(table.orbit_rate)
    # every literal is printed with 17 significant digits or is exact in fewer (0.0, 120.0)
    for name, vals in d.items():
        for x in vals:
            assert _bits(float(ft.c_double(x))) == _bits(x), name
    for x in (0.1, 1 / 3, 5e-324, 1.7976931348623157e308, -2.2250738585072014e-308, 8.366374949312711e-05):
        assert _bits(float(ft.c_double(x))) == _bits(x)
    assert text.count("#ifndef MAGTUNE_FLIGHT_TABLE_H") == 1 and "#endif" in text
    # the wheel's comment states the sign its value uses (it said h = J_wheel * w_wheel over -J w; issue 57)
    sc = load_spacecraft(SPACECRAFT)
    h = d["MAGTUNE_SC_WHEEL_MOMENTUM"]
    assert "h = (0, 0, -wheel_inertia * wheel_speed)" in text
    assert h == [0.0, 0.0, -sc.wheel_inertia * sc.wheel_speed] and sc.wheel_speed != 0  # the 12U: -400 rad/s, h_z > 0


def test_header_compiles_strictly_and_its_values_are_python_s(export, tmp_path):
    """Never skipped: no compiler is a failure (CI installs gcc, scripts/bootstrap.sh)."""
    cc = shutil.which("cc") or shutil.which("gcc")
    assert cc, "no C compiler (cc): scripts/bootstrap.sh installs Debian's gcc; the flight header must be compiled"
    out, _ = export
    main = tmp_path / "main.c"
    main.write_text('#include <stdio.h>\n#include "flight_table.h"\n#include "flight_table.h"\n'  # the guard holds
                    "int main(void) {\n  int i, j;\n"
                    '  for (i = 0; i < 3; ++i) for (j = 0; j < 6; ++j) printf("%.17g\\n", MAGTUNE_CTRL_K[i][j]);\n'
                    '  printf("%.17g\\n%.17g\\n%.17g\\n%.17g\\n%.17g\\n", MAGTUNE_CTRL_TS, MAGTUNE_CTRL_DIPOLE_LIMIT[1], '
                    "MAGTUNE_CTRL_BDOT_GAIN_FLOWN, MAGTUNE_MODES_DETUMBLE_EXIT_RATE, MAGTUNE_EST_GYRO_ARW);\n"
                    '  printf("%d %d %lld %s\\n", MAGTUNE_MODE_ID_ACQUISITION, MAGTUNE_EST_VALIDITY_GATE, '
                    "MAGTUNE_EST_TIME_ORIGIN_NS, MAGTUNE_CTRL_INITIAL_MODE);\n  return 0;\n}\n")
    exe = tmp_path / "main"
    r = subprocess.run([cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-I", str(out), str(main),
                        "-o", str(exe)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    lines = subprocess.run([str(exe)], capture_output=True, text=True, timeout=30, check=True).stdout.split("\n")
    table = ft.read_parameter_file(out / "flight_params.yaml")
    v = table.values
    want = list(load_gains(GAINS).K.ravel()) + [v["controller"]["ts"], v["controller"]["dipole_limit"][1],
                                                table.bdot_gain, v["mode_manager"]["detumble_exit_rate"],
                                                v["attitude_estimator"]["gyro_arw"]]
    assert [_bits(float(x)) for x in lines[:len(want)]] == [_bits(x) for x in want]
    assert lines[len(want)] == (f"1 1 {v['attitude_estimator']['time_origin_ns']} DETUMBLE")


# ---------------------------------------------------------------- the vectors
def _write_outputs(path, cols: dict, names) -> None:
    path.write_text(fv.csv_text({n: cols[n] for n in ("step", *names)}))


def test_vectors_cover_the_laws_and_their_readme_names_every_column(export):
    out, _ = export
    ref = fv.read_columns(out / "flight_vectors.csv")
    assert tuple(ref) == fv.NAMES
    par = fv.read_columns(out / "flight_vectors.parquet")
    for n in fv.NAMES:  # the Parquet file holds the same numbers
        assert np.array_equal(ref[n], par[n], equal_nan=True), n
    modes = {MODES[int(m)] for m in ref["mode"]}
    assert {DETUMBLE, ACQUISITION} <= modes, modes
    m = np.stack([ref[f"dipole_{a}"] for a in "xyz"], 1)
    assert np.abs(m).max() > 0.1 and np.all(np.abs(m) <= 0.2)
    readme = (out / "README.md").read_text()
    for n, unit, _, _ in fv.COLUMNS:
        assert f"| `{n}` | {unit} |" in readme, n


def test_onboard_library_recomputed_from_the_inputs_passes_export_check(export, tmp_path, capsys):
    """The flight nodes' code, configured by the exported parameter file and fed only the vectors' inputs,
    reproduces every output column: export-check exit 0. The vectors file itself is a valid OUTPUTS."""
    out, _ = export
    vec = out / "flight_vectors.csv"
    ref = fv.read_columns(vec)
    table = ft.read_parameter_file(out / "flight_params.yaml")
    got = fv.recompute(table, {n: ref[n] for n in fv.INPUTS})
    outputs = tmp_path / "outputs.csv"
    _write_outputs(outputs, {"step": ref["step"], **got}, fv.OUTPUTS)
    capsys.readouterr()
    assert cli_main(["export-check", str(vec), str(outputs)]) == 0
    assert "PASS" in capsys.readouterr().out
    assert cli_main(["export-check", str(vec), str(vec)]) == 0
    assert cli_main(["export-check", str(out / "flight_vectors.parquet"), str(outputs)]) == 0


def test_a_gain_changed_in_its_fourth_digit_fails_and_names_the_first_diverging_step(export, tmp_path, capsys):
    out, _ = export
    vec = out / "flight_vectors.csv"
    ref = fv.read_columns(vec)
    table = ft.read_parameter_file(out / "flight_params.yaml")
    K = np.array(table.values["controller"]["gain"], dtype=float)
    i = int(np.argmax(np.abs(K)))
    K[i] = float(f"{K[i]:.4g}") + np.sign(K[i]) * 10.0 ** (np.floor(np.log10(abs(K[i]))) - 3)  # +1 in digit 4
    assert 1e-4 < abs(K[i] / table.values["controller"]["gain"][i] - 1) < 2e-3
    got = fv.recompute(table, {n: ref[n] for n in fv.INPUTS}, gain=K)
    outputs = tmp_path / "perturbed.csv"
    _write_outputs(outputs, {"step": ref["step"], **got}, ("dipole_x", "dipole_y", "dipole_z"))
    capsys.readouterr()
    assert cli_main(["export-check", str(vec), str(outputs)]) == 3
    line = _one_line(capsys.readouterr().out)
    # the first step where eq. 17 (the only user of K) flies on a valid estimate and an axis is unsaturated
    m = np.stack([ref[f"dipole_{a}"] for a in "xyz"], 1)
    law = np.isin(ref["mode"], [MODES.index(ACQUISITION), MODES.index(POINTING)]) & (ref["est_valid"] == 1)
    free = np.any(np.abs(m) < 0.2 * (1 - 1e-9), axis=1)
    first = int(np.argmax(law & free))
    assert law[first] and free[first]
    assert re.match(rf"FAIL at step {first}, column dipole_[xyz]: ", line), (line, first)
    # the gain as exported passes (the comparison is about the gain, nothing else)
    same = fv.recompute(table, {n: ref[n] for n in fv.INPUTS}, gain=table.values["controller"]["gain"])
    assert all(np.array_equal(same[f"dipole_{a}"], ref[f"dipole_{a}"]) for a in "xyz")


def test_tolerance_is_relative_with_a_floor_near_zero():
    ref = {"step": np.arange(3.0), "dipole_x": np.array([0.1, 1e-12, -0.2]), "mode": np.array([0.0, 1.0, 1.0])}
    ok = {"step": ref["step"], "dipole_x": ref["dipole_x"] * (1 + 5e-10)}
    assert fv.compare(ref, ok).passed
    near_zero = {"step": ref["step"], "dipole_x": np.array([0.1, 1.5e-10, -0.2])}  # 0.2 x 1e-9 floor = 2e-10
    assert fv.compare(ref, near_zero).passed
    far = {"step": ref["step"], "dipole_x": np.array([0.1, 1e-12, -0.2 * (1 + 2e-9)])}
    res = fv.compare(ref, far)
    assert (res.step, res.column) == (2, "dipole_x")
    assert fv.compare(ref, {"step": ref["step"], "mode": np.array([0.0, 1.0, 2.0])}).step == 2  # integers exact
    nan = {"step": np.arange(1.0), "est_gyro_bias_x": np.array([np.nan])}
    assert fv.compare(nan, nan).passed and not fv.compare(nan, {"step": nan["step"], "est_gyro_bias_x": [0.0]}).passed


@pytest.mark.parametrize("text, words", [
    ("dipole_x,dipole_y\n0.0,0.0\n", "'step'"),
    ("step,dipole_q\n0,0.0\n", "'dipole_q': not a column of the vectors"),
    ("step,dipole_x\n100000,0.0\n", "no step in common"),
    ("step,dipole_x\n0,abc\n", "not a number"),
    ("step,dipole_x\n0,0.0\n0,0.0\n", "a step is given twice"),
    ("step,dipole_x\n0\n", "row 2 has 1 cells"),
    ("", "empty"),
])
def test_export_check_bad_outputs_are_one_line_and_exit_2(export, tmp_path, capsys, text, words):
    out, _ = export
    bad = tmp_path / "bad.csv"
    bad.write_text(text)
    capsys.readouterr()
    assert cli_main(["export-check", str(out / "flight_vectors.csv"), str(bad)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith("magtune export-check: error: ") and words in line, line


def test_export_bad_input_is_one_line_and_exit_2_before_any_work(tmp_path, capsys):
    out = tmp_path / "out"
    params = tmp_path / "p.yaml"
    params.write_text("/**/mode_manager:\n  ros__parameters:\n    detumble_exit_tme: 100.0\n")
    for argv, words in ((["--params", str(params)], "detumble_exit_tme"), (["--steps", "0"], "--steps"),
                        (["--params", str(tmp_path / "missing.yaml")], "file not found")):
        capsys.readouterr()
        assert cli_main(["export", str(GAINS), "--spacecraft", str(SPACECRAFT), "--out", str(out), *argv]) == 2
        line = _one_line(capsys.readouterr().err)
        assert words in line, line
        assert not out.exists() or not any(out.iterdir())
    params.write_text("/**/attitude_estimator:\n  ros__parameters:\n    ts: 2.0\n")
    assert cli_main(["export", str(GAINS), "--spacecraft", str(SPACECRAFT), "--out", str(out), "--params", str(params)]) == 2
    assert "'ts'" in _one_line(capsys.readouterr().err)
