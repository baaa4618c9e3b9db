"""Bad input anywhere: one line naming the field and the fix, exit status 2, before any work.

Each case is a probe of issue #10 that ended in a traceback, a wrong success or a silent
acceptance. The CLI is called in-process (``magtune_core.cli.main``), so no node is started;
``magtune sil`` validates everything before it looks for the ROS workspace.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from cli_errors import one_line_exit2  # tests/support

from magtune_core.base.errors import ConfigError
from magtune_core.base.schema import Field, parse
from magtune_core.cli import main as cli_main
from magtune_core.design.gains import Gains, load_gains
from magtune_core.design.params import SpacecraftParams, check_sample_period

ROOT = Path(__file__).resolve().parents[2]
GAINS = ROOT / "config" / "gains" / "sigma_60.yaml"
SPACECRAFT = ROOT / "config" / "spacecraft.yaml"


def _edit(tmp_path, src: Path, name: str, **changes) -> Path:
    doc = yaml.safe_load(src.read_text())
    section = next(iter(doc))
    doc[section]["ros__parameters"].update(changes)
    out = tmp_path / name
    out.write_text(yaml.safe_dump(doc))
    return out


def test_bounds_are_checked_per_element():
    f = Field("b", "float[]", "field [T]", size=3, bounds=(-1e-3, 1e-3), unit="T")
    assert parse({"b": [1e-5, 0.0, -1e-5]}, [f], "x.yaml")["b"].tolist() == [1e-5, 0.0, -1e-5]
    with pytest.raises(ConfigError, match=r"field 'b': expected numbers in \[-0.001, 0.001\] T"):
        parse({"b": [1e-5, 1e308, 0.0]}, [f], "x.yaml")


@pytest.mark.parametrize("key, value", [("sigma", 1e300), ("ts", 1e300), ("gain", [1e300] * 18)])
def test_huge_gains_values_are_rejected(tmp_path, capsys, key, value):
    """Why #5: huge but finite values ended in tracebacks."""
    bad = _edit(tmp_path, GAINS, "g.yaml", **{key: value})
    err = one_line_exit2(capsys, ["analyze", str(bad)])
    assert f"field '{key}'" in err


@pytest.mark.parametrize("key, value", [("orbit_period", 1e300), ("constant_field", [1e308, 0.0, 0.0]),
                                        ("inertia", [1e300, 17.0, 25.0]), ("wheel_speed", -1e300)])
def test_huge_spacecraft_values_are_rejected(tmp_path, capsys, key, value):
    """Why #5/#7: orbit_period near 1e300, a 1e308 T field accepted and not counted."""
    bad = _edit(tmp_path, SPACECRAFT, "sc.yaml", **{key: value})
    err = one_line_exit2(capsys, ["--config", str(bad), "analyze", str(GAINS)])
    assert f"field '{key}'" in err and "expected" in err


def test_min_field_bound_and_misspelling(tmp_path):
    """Why #5/#7: min_field near 1e300 crashed; misspelled min_feild was kept as provenance."""
    with pytest.raises(ConfigError, match=r"field 'min_field': expected a number in"):
        load_gains(_edit(tmp_path, GAINS, "a.yaml", min_field=1e300))
    with pytest.raises(ConfigError, match="field 'min_feild': unknown parameter; did you mean 'min_field'"):
        load_gains(_edit(tmp_path, GAINS, "b.yaml", min_feild=1e-6))
    with pytest.raises(ConfigError, match="field 'orbit_perod': unknown parameter; did you mean 'orbit_period'"):
        SpacecraftParams.from_mapping(dict(yaml.safe_load(SPACECRAFT.read_text())["/**"]["ros__parameters"],
                                           orbit_perod=5600.0), "sc.yaml", strict=True)
    ok = load_gains(_edit(tmp_path, GAINS, "c.yaml", min_field=2e-7, dipole_limit=[10.0, 10.0, 10.0]))
    assert set(ok.provenance) <= set(Gains.PROVENANCE)  # node options are not provenance


def test_shipped_files_pass_the_strict_checks():
    for f in sorted((ROOT / "config" / "gains").glob("*.yaml")):
        assert load_gains(f).provenance, f
    with pytest.raises(ValueError, match="add it there"):   # what we write we can read back
        from magtune_core.design.gains import save_gains
        save_gains(Path("/nonexistent/never.yaml"), Gains(np.zeros((3, 6)), 1.0, 1.0, {"bogus": 1}))


def test_sample_period_must_resolve_nutation():
    """Why #6: --ts 100 made RK4 diverge and sil exited 0. The paper's spacecraft nutates with
    2 pi sqrt(Ixx Iyy) / (J |W|) = 2 pi sqrt(35 * 17) / 2 = 76.63 s; ts must be below half."""
    p = SpacecraftParams()
    assert p.nutation_period == pytest.approx(2 * np.pi * np.sqrt(35.0 * 17.0) / 2.0, rel=1e-12)
    check_sample_period(30.0, p)  # the sampling study's largest Ts
    with pytest.raises(ConfigError, match="does not resolve the nutation period 76.6 s; use ts < 38.3 s"):
        check_sample_period(100.0, p)


@pytest.mark.parametrize("extra, words", [
    (["--orbits", "-1"], "--orbits"), (["--orbits", "nan"], "--orbits"), (["--steps", "0"], "--steps"),
    (["--ts", "100"], "nutation"), (["--ts", "-1"], "sample period"), (["--substeps", "0"], "--substeps"),
    # nan/inf reached the sub-step rule before validation (traceback, exit 1); 1e-300 passed the runner and
    # the controller refused it (exit 1): all refused by the runner now, naming --ts
    (["--ts", "nan"], "--ts: expected a positive finite"), (["--ts", "inf"], "--ts: expected a positive finite"),
    (["--ts", "0"], "--ts: expected a positive finite"), (["--ts", "1e-300"], "--ts: expected a sample period in"),
    (["--timeout", "-5"], "--timeout"), (["--rtf", "inf"], "--rtf"), (["--lockstep-timeout", "0"], "--lockstep-timeout"),
    (["--results", "/proc/no/such.npz"], "--results"), (["--log-dir", "/proc/version/logs"], "--log-dir"),
])
def test_sil_rejects_bad_arguments_before_starting(tmp_path, capsys, extra, words):
    """Why #5/#6: --orbits -1 'timed out after 0 s'; an unwritable --results/--log-dir was
    discovered after the whole run. Now: exit 2 at once, nothing created."""
    err = one_line_exit2(capsys, ["sil", "--quiet", "--gains", str(GAINS), "--log-dir", str(tmp_path / "logs"), *extra])
    assert words in err
    if "--log-dir" not in extra:
        assert not (tmp_path / "logs").exists()  # rejected before any work


def test_sil_bad_gains_file_exits_2(tmp_path, capsys):
    """Why #7: sil exited 1 on a bad gains file where the README promises 2."""
    err = one_line_exit2(capsys, ["sil", "--quiet", "--gains", str(_edit(tmp_path, GAINS, "g.yaml", sigma=-60.0))])
    assert "field 'sigma'" in err
    err = one_line_exit2(capsys, ["sil", "--quiet", "--gains", str(tmp_path / "missing.yaml")])
    assert "file not found" in err


def test_huge_gain_analyzes_as_unstable(tmp_path, capsys):
    """Why #5: a gain of 10 per entry crashed analyze (overflow in the monodromy). It is a valid
    (if absurd) gain: the loop is reported unstable with rho = inf, printed as strict JSON
    (``null``, never ``Infinity``/``NaN``, which strict parsers reject)."""
    g = _edit(tmp_path, GAINS, "g10.yaml", gain=[10.0] * 18)
    assert cli_main(["analyze", "--json", str(g)]) == 0
    out = capsys.readouterr().out

    def strict(name):
        raise ValueError(f"not JSON: {name}")

    d = json.loads(out.strip().splitlines()[-1], parse_constant=strict)
    assert d["stable"] is False and d["rho"] is None


def test_same_error_same_exit_code_everywhere(tmp_path, capsys):
    """A missing input file is exit 2 in every command that reads one."""
    missing = str(tmp_path / "nope")
    for argv in (["analyze", missing], ["sil", "--quiet", "--gains", missing], ["bag", "info", missing],
                 ["bag", "recover", missing], ["replay", missing]):
        err = one_line_exit2(capsys, argv)
        assert re.search(r"nope", err), err


def test_node_parameters_come_from_the_schemas():
    """The SIL nodes declare parameters only from schemas (no hand-declared name in their
    sources), and NODE_PARAMETERS (what a spacecraft/gains file may set besides the spacecraft
    schema) is exactly the union of the nodes' schemas plus use_sim_time."""
    from magtune_core.design.node_params import NODE_PARAMETERS, SIL_NODE_FIELDS

    pkg = ROOT / "ros2_ws" / "src" / "magtune_ros" / "magtune_ros"
    for name in ("simulator", "attitude_sensors", "controller", "recorder"):
        src = (pkg / f"{name}.py").read_text()
        assert not re.findall(r'declare_parameter\(\s*"', src), name
        assert "c.declare(" not in src, name
    names = {f.name for fields in SIL_NODE_FIELDS.values() for f in fields}
    assert set(NODE_PARAMETERS) == names | {"use_sim_time"}
    # what the hand-kept list held before it was derived (37), plus the 8 sensor-model fields of issue 31,
    # plus issue 30's: 12 mode fields, 2 B-dot fields, initial_mode, 4 mode-manager fields, autostart,
    # plus the estimator's own 4 (gate_probability, init_angle, initial_bias_std, sun_wait; its other
    # fields are the other nodes' names), plus the faults of issue 30 (frozen_time, faults), plus the 4
    # torquer fields of issue 30 item 6 (coupling, off time, decay time, compensation), plus the estimator's
    # magnetometer-bias states of issue 31 (initial_mag_bias_std, mag_bias_rw), plus the simulator's
    # max_substeps (the sub-steps re-chosen from the rate), plus issue 44's full stack: the mode logic's
    # attitude_loss_time, the estimator's 5 validity fields and its sun_loss_samples, its 5 sensor-watch fields and
    # its torquer_watch switch, plus issue 60's bringup_limit of the mode manager
    assert len(NODE_PARAMETERS) == 37 + 8 + 12 + 2 + 1 + 4 + 1 + 4 + 2 + 4 + 2 + 1 + 1 + 5 + 1 + 5 + 1 + 1
    assert {"initial_quaternion", "mag_quantum", "min_field", "seed"} <= names


def test_example_files_pass_the_strict_checks():
    for f in sorted((ROOT / "config").rglob("*.yaml")):
        text = f.read_text()
        if re.search(r"^\s*gain:", text, re.M):  # a gains file (not bdot_gain: of a campaign's modes)
            load_gains(f)
        elif "ros__parameters" in text and "inertia:" in text:
            from magtune_core.design.params import load_spacecraft
            load_spacecraft(f)


def test_packaged_sil_defaults_are_the_schemas():
    """ros2_ws/src/magtune_ros/config/sil.yaml (installed beside the nodes as a template) holds
    each node's schema defaults, validated by that schema; only the run length differs (5 orbits,
    as `magtune sil`)."""
    import numpy as np

    from magtune_core.base.paramfile import read_ros_params
    from magtune_core.base.schema import parse
    from magtune_core.design.node_params import SIL_NODE_FIELDS

    path = ROOT / "ros2_ws" / "src" / "magtune_ros" / "config" / "sil.yaml"
    for node, fields in SIL_NODE_FIELDS.items():
        given = {k: v for k, v in read_ros_params(path, node).items() if k != "use_sim_time"}
        assert given, node
        parsed, defaults = parse(given, fields, path, allowed=()), parse({}, fields, path)
        differ = sorted(k for k in given if not np.array_equal(parsed[k], defaults[k]))
        assert differ == (["orbits"] if node == "simulator" else []), (node, differ)


@pytest.mark.parametrize("keep", [6, 10, 20, 23])
def test_truncated_gains_file_is_one_line(tmp_path, capsys, keep):
    """Why: a gains file cut short (a write that failed half-way) must not load: the gain list is
    short or sigma is missing; one line, exit 2 (cut at 6: inside the header, 10/20: inside the
    18-entry gain, 23: after the gain, before sigma)."""
    bad = tmp_path / "g.yaml"
    bad.write_text("".join(GAINS.read_text().splitlines(keepends=True)[:keep]))
    err = one_line_exit2(capsys, ["analyze", str(bad)])
    assert "field 'gain'" in err or "field 'sigma'" in err, err


# --- issue 32: undecodable files, symlink loops, duplicate keys, impossible inertia -------------

def _message(err: str) -> str:
    """The error line without its ``magtune COMMAND: error:`` prefix (to compare commands)."""
    return err.strip().split(": error: ", 1)[1]


def _not_utf8(tmp_path, src: Path, name: str) -> Path:
    bad = tmp_path / name
    bad.write_bytes(src.read_bytes().replace(b"ros__parameters:", b"ros__parameters: # \xff\xfe caf\xe9", 1))
    return bad


def test_non_utf8_gains_and_spacecraft_files_are_one_line(tmp_path, capsys):
    """Why: a non-UTF-8 gains or spacecraft file was a UnicodeDecodeError traceback."""
    g, sc = _not_utf8(tmp_path, GAINS, "g.yaml"), _not_utf8(tmp_path, SPACECRAFT, "sc.yaml")
    a = one_line_exit2(capsys, ["analyze", str(g)])
    offset = g.read_bytes().index(b"\xff")
    line = g.read_bytes()[:offset].count(b"\n") + 1
    assert _message(a) == f"{g}: not UTF-8 text (byte 0xff at line {line}, offset {offset}); save the file as UTF-8"
    s = one_line_exit2(capsys, ["sil", "--quiet", "--gains", str(g)])
    assert _message(s) == _message(a)                       # the same wording from every command
    a = one_line_exit2(capsys, ["analyze", str(GAINS), "--config", str(sc)])
    s = one_line_exit2(capsys, ["sil", "--quiet", "--gains", str(GAINS), "--spacecraft", str(sc)])
    assert _message(s) == _message(a) and "not UTF-8 text" in a


def test_symlink_loops_are_one_line_everywhere(tmp_path, capsys):
    """Why: a --bag (or any file argument) that is a symbolic link loop was an ELOOP traceback."""
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    expected = f"{loop}: symbolic link loop (too many levels of symbolic links); point it at a real file"
    for argv in (["analyze", str(loop)], ["sil", "--quiet", "--gains", str(loop)], ["bag", "info", str(loop)],
                 ["bag", "recover", str(loop)], ["replay", str(loop)], ["report", str(loop), "--out", str(tmp_path / "r")],
                 ["tune", "--sigma", "60", "--out", str(loop)], ["analyze", str(GAINS), "--config", str(loop)]):
        assert _message(one_line_exit2(capsys, argv)) == expected, argv


def test_sil_bag_symlink_loop_leaks_no_temporary_directory(tmp_path, capsys, monkeypatch):
    """Why: ``magtune sil --bag LOOP`` also left its temporary log directory behind."""
    import tempfile

    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    err = one_line_exit2(capsys, ["sil", "--gains", str(GAINS), "--bag", str(loop), "--orbits", "0.01"])
    assert "symbolic link loop" in err and "starting the nodes" not in err
    assert list(tmp.iterdir()) == []


@pytest.mark.parametrize("text, key, lines", [
    ("/**:\n  ros__parameters:\n    sigma: 60.0\n    ts: 1.0\n    sigma: 120.0\n", "sigma", (5, 3)),
    ("/**:\n  ros__parameters:\n    sigma: 60.0\n/**:\n  ros__parameters:\n    ts: 1.0\n", "/**", (4, 1)),
])
def test_duplicate_keys_are_rejected_with_key_and_lines(tmp_path, capsys, text, key, lines):
    """Why: duplicate keys in a parameter file: the last one won silently (a SIL flew the second
    gain under a header naming the first)."""
    f = tmp_path / "dup.yaml"
    f.write_text(text)
    second, first = lines
    want = f"{f}: malformed YAML at line {second}, column 1" if key == "/**" else f"{f}: malformed YAML at line {second}, column 5"
    for argv in (["analyze", str(f)], ["sil", "--quiet", "--gains", str(f)], ["analyze", str(GAINS), "--config", str(f)]):
        msg = _message(one_line_exit2(capsys, argv))
        assert msg == f"{want}: duplicate key {key!r} (first given at line {first}; keep one)", (argv, msg)


def test_duplicate_key_in_campaign_spec(tmp_path):
    from magtune_core.studies.campaign import load_spec

    f = tmp_path / "c.yaml"
    f.write_text("campaign:\n  name: a\n  name: b\n")
    with pytest.raises(ConfigError, match=r"line 3, column 3: duplicate key 'name' \(first given at line 2"):
        load_spec(f)


@pytest.mark.parametrize("inertia, words", [
    ([50.0, 17.0, 25.0], "Ixx = 50 > Iyy + Izz = 42"), ([1.0, 10.0, 2.0], "Iyy = 10 > Izz + Ixx = 3"),
    ([1.0, 1.0, 2.5], "Izz = 2.5 > Ixx + Iyy = 2")])
def test_inertia_violating_the_triangle_inequality_is_rejected(tmp_path, capsys, inertia, words):
    """Why: Ixx > Iyy + Izz (no rigid body has it) was accepted."""
    sc = _edit(tmp_path, SPACECRAFT, "sc.yaml", inertia=inertia)
    a = one_line_exit2(capsys, ["analyze", str(GAINS), "--config", str(sc)])
    assert words in a and "field 'inertia'" in a and "not a rigid body" in a
    s = one_line_exit2(capsys, ["sil", "--quiet", "--gains", str(GAINS), "--spacecraft", str(sc)])
    assert _message(s) == _message(a)
    SpacecraftParams.from_mapping({**yaml.safe_load(SPACECRAFT.read_text())["/**"]["ros__parameters"],
                                   "inertia": [2.0, 1.0, 1.0]}, "flat plate")  # equality: a flat plate is allowed


@pytest.mark.parametrize("extra, words", [
    (["--fault", "mag_dropout@10"], "--fault mag_dropout@10: field 'duration': required for mag_dropout"),
    (["--fault", "mag_stuk@10"], "field 'kind': expected one of mag_stuck"),
    (["--fault", "gyro_bias@1,axis=w"], "field 'axis': expected one of x, y, z"),
    (["--fault", "mag_bias@1,value=1"], "field 'value': expected a nonzero number within +-0.001 T"),
    (["--fault", "torquer_dead"], "expected KIND@T[:DURATION]"),
    (["--fault", "mag_stuck@10", "--epoch-time"], "not with --epoch-time"),
])
def test_sil_rejects_bad_faults_before_starting(tmp_path, capsys, extra, words):
    """A bad --fault: one line naming the field and the fix, exit 2, no log directory created."""
    err = one_line_exit2(capsys, ["sil", "--quiet", "--gains", str(GAINS), "--log-dir", str(tmp_path / "logs"), *extra])
    assert words in err, err
    assert not (tmp_path / "logs").exists()


@pytest.mark.parametrize("text, words", [
    ("faults:\n  - {kind: mag_stuck, t: 10}\n  - {kind: mag_dropout, t: 20}\n",
     "faults[1]: field 'duration': required for mag_dropout"),
    ("faults:\n  - {kind: mag_stuck, t: 10, when: 3}\n", "faults[0]: field 'when': unknown parameter"),
    ("faults: mag_stuck@10\n", "expected a list of faults"),
    ("fault:\n  - {kind: mag_stuck, t: 10}\n", "field 'fault': unknown parameter; did you mean 'faults'"),
    ("- 1\n", "expected a mapping with faults"),
    ("torquers:\n  torquer_off_time: 1.5\n", "field 'torquer_off_time': expected less than the sample period"),
    ("torquers:\n  torquer_off_time: 1.234567e-4\n", "multiple of ts/1000"),
    ("torquers:\n  torquer_coupling: [1.0, 0, 0, 0, 0, 0, 0, 0, 0]\n", "field 'torquer_coupling': expected numbers in"),
    ("torquers:\n  duty_cycle: 0.8\n", "field 'duty_cycle': unknown parameter"),
    ("torquers: 0.2\n", "field 'torquers': expected a mapping of torquer_coupling"),
])
def test_sil_rejects_bad_scenario_files(tmp_path, capsys, text, words):
    scen = tmp_path / "scenario.yaml"
    scen.write_text(text)
    err = one_line_exit2(capsys, ["sil", "--quiet", "--gains", str(GAINS), "--scenario", str(scen)])
    assert words in err and str(scen) in err, err
    err = one_line_exit2(capsys, ["sil", "--quiet", "--gains", str(GAINS), "--scenario", str(tmp_path / "no.yaml")])
    assert "file not found" in err


def test_scenario_file_and_cli_faults_reach_the_nodes(tmp_path):
    """A valid scenario file and --fault specs become the nodes' ``faults`` parameters: sensor faults for
    attitude_sensors, torquer faults and the kill for the simulator (exact specs)."""
    from magtune_core.ros.scenario import SilRequest, SilScenario, load_scenario_file

    scen = tmp_path / "scenario.yaml"
    scen.write_text("faults:\n  - {kind: mag_dropout, t: 3000, duration: 30}\n  - {kind: torquer_dead, t: 5, axis: y}\n")
    faults = list(load_scenario_file(scen)["faults"]) + ["sensors_killed@200"]
    sc = SilScenario.build({"": GAINS}, SilRequest(steps=4000, faults=faults))  # every fault inside the run
    params = sc.node_parameters(sc.satellites[0], tmp_path / "r.npz")
    assert params["attitude_sensors"]["faults"] == ["mag_dropout@3000.0:30.0"]
    assert params["simulator"]["faults"] == ["torquer_dead@5.0,axis=y", "sensors_killed@200.0"]
    assert "faults" not in params["controller"]


def test_scenario_torquers_reach_simulator_sensors_and_controller(tmp_path):
    """A scenario's torquers section: the same values for the three nodes that model them (one schema)."""
    from magtune_core.ros.scenario import SilRequest, SilScenario, load_scenario_file

    scen = tmp_path / "scenario.yaml"
    scen.write_text("torquers:\n  torquer_off_time: 0.2\n  torquer_coupling: [2.0e-7, 0, 0, 0, -1.0e-7, 0, 0, 0, -1.0e-7]\n")
    sc = SilScenario.build({"": GAINS}, SilRequest(steps=10, torquers=load_scenario_file(scen)["torquers"]))
    params = sc.node_parameters(sc.satellites[0], tmp_path / "r.npz")
    for node in ("simulator", "attitude_sensors", "controller"):
        assert params[node]["torquer_off_time"] == 0.2 and params[node]["torquer_coupling"][4] == -1e-7, node
