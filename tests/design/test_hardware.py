"""The hardware file (magtune_core.design.hardware): datasheet units converted to the models' parameters,
the shipped files reproduce today's parameters bit for bit, a bad file is one line naming the field, and
the file's figures reach the nodes' parameter files (checked on the scenario's files: no process starts)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from support.cli_errors import one_line_exit2

from magtune_core.base import paramfile
from magtune_core.base.ament import ROOT
from magtune_core.base.errors import ConfigError
from magtune_core.base.schema import parse
from magtune_core.design import hardware as hwm
from magtune_core.design.hardware import Hardware, load_hardware
from magtune_core.design.node_params import SIL_NODE_FIELDS
from magtune_core.design.requirements import Requirements, spacecraft_dipole_limit
from magtune_core.design.sensors import SensorSuite, default_suite
from magtune_core.onboard.params import ESTIMATOR_FIELDS
from magtune_core.ros.scenario import SilRequest, SilScenario, check_attitude_arguments

SHIPPED = ROOT / "config" / "hardware.yaml"
EXAMPLE = ROOT / "config" / "examples" / "cubesat12u"
GAINS = ROOT / "config" / "gains" / "sigma_60.yaml"
NODES = ("simulator", "controller", "attitude_sensors", "attitude_estimator")


def _parsed(node: str, params: dict) -> dict:
    """What ``node`` makes of ``params``: its schema's values (defaults filled in), as the node validates them."""
    return parse({k: v for k, v in params.items() if k in {f.name for f in SIL_NODE_FIELDS[node]}},
                 SIL_NODE_FIELDS[node], node)


def _same(a: dict, b: dict) -> list:
    """Names whose values differ in any bit (arrays element by element; float64 == is bitwise for finite values)."""
    return [k for k in a if not np.array_equal(np.asarray(a[k]), np.asarray(b[k]))]


def _nodes(sc: SilScenario, tmp_path: Path) -> dict:
    """Each node's parsed parameters, read back from the files the scenario writes (what the node reads)."""
    sat = sc.satellites[0]
    tmp_path.mkdir(parents=True, exist_ok=True)
    files = sc.write_parameter_files(sat, tmp_path, Path("r.npz"))  # one results path: the files differ only in what is compared
    return {n: _parsed(n, paramfile.check_ros_params(f, n)) for n, f in files.items() if n in NODES}


# ---------------------------------------------------------------- conversions (hand calculations)
def test_angle_random_walk_to_farrenkopf_sigma_v():
    # 1 deg/sqrt(h) = (pi/180 rad) / sqrt(3600 s) = 0.017453292519943295 / 60 = 2.908882086657216e-4 rad/s^0.5;
    # a tactical MEMS gyro of 0.15 deg/sqrt(h) (ADIS16465-class datasheet figure): 4.363323129985824e-5.
    # rel 1e-15: the same three correctly rounded operations in another order differ by at most a few ulp.
    assert hwm.arw_to_sigma_v(1.0) == pytest.approx(2.908882086657216e-4, rel=1e-15)
    assert hwm.arw_to_sigma_v(0.15) == pytest.approx(4.363323129985824e-5, rel=1e-15)
    # and the inverse of the estimator's default sigma_v 1e-4 is the docs' 0.34 deg/sqrt(h)
    assert 1e-4 / hwm.arw_to_sigma_v(1.0) == pytest.approx(0.3437746770784939, rel=1e-15)


def test_rate_random_walk_and_deg_per_hour():
    # 1 deg/h = 1 arcsec/s = pi / 648000 rad/s = 4.84813681109536e-6 rad/s
    assert hwm.deg_per_hour_to_rad_per_s(1.0) == pytest.approx(math.pi / 648000.0, rel=1e-15)
    assert hwm.deg_per_hour_to_rad_per_s(1.0) == pytest.approx(4.84813681109536e-6, rel=1e-14)
    # 1 deg/h/sqrt(h) = 4.84813681109536e-6 rad/s / 60 sqrt(s) = 8.0802280184922666e-8 rad/s^1.5
    assert hwm.rrw_to_sigma_u(1.0) == pytest.approx(8.080228018492267e-8, rel=1e-14)


def test_bias_instability_to_rate_random_walk_meets_the_allan_floor():
    # IEEE Std 952 Annex C: the floor is sqrt(2 ln 2 / pi) B = 0.664 B (published to 3 digits)
    assert hwm.ALLAN_FLOOR == pytest.approx(0.664, abs=5e-4)
    # B = 10 deg/h, tau = 300 s: sigma_u = 0.66428 x 4.8481368e-5 rad/s x sqrt(3/300) = 3.2205e-6 rad/s^1.5 (hand)
    su = hwm.bias_instability_to_sigma_u(10.0, 300.0)
    assert su == pytest.approx(3.2205e-6, rel=1e-4)  # 5 digits of the hand calculation
    # the defining property: the walk's Allan deviation sigma_u sqrt(tau/3) equals the floor at tau
    assert su * math.sqrt(300.0 / 3.0) == pytest.approx(hwm.ALLAN_FLOOR * 10.0 * math.pi / 180.0 / 3600.0, rel=1e-14)


def test_noise_density_and_accuracy():
    # 10 nT/sqrt(Hz) over a 100 Hz bandwidth: 10 x 10 = 100 nT, exactly (sqrt(100) is exact)
    assert hwm.noise_density_to_std(10.0, 100.0) == 100.0
    # a coarse sun sensor of 0.3 deg at 3 sigma: 0.1 deg = 1.7453292519943296e-3 rad at 1 sigma
    assert hwm.sigma_of_accuracy(0.3, 3) == pytest.approx(1.7453292519943296e-3, rel=1e-15)
    assert hwm.nano_to_si(100.0) == 100e-9  # bit for bit: a division by an exact power of ten


# ---------------------------------------------------------------- the shipped file: today's values, bit for bit
def test_shipped_file_gives_todays_defaults_bit_for_bit():
    hw = load_hardware(SHIPPED)
    params = hw.node_parameters()
    # the sensors node: the estimator runs' default suite, as the scenario hands it today
    today, _ = check_attitude_arguments("estimator", None, None, None)
    assert not _same(_parsed("attitude_sensors", today), _parsed("attitude_sensors", params["attitude_sensors"]))
    assert SensorSuite.from_values(_parsed("attitude_sensors", params["attitude_sensors"])) == default_suite()
    # the estimator's noise model: its schema's defaults
    est = _parsed("attitude_estimator", params["attitude_estimator"])
    defaults = {f.name: f.default for f in ESTIMATOR_FIELDS}
    assert params["attitude_estimator"] and all(est[k] == defaults[k] for k in params["attitude_estimator"])
    # the simulator and the controller: the schemas' defaults (dipole_limit 50, residual 1, no coupling)
    for node in ("simulator", "controller"):
        assert not _same(_parsed(node, {}), _parsed(node, params[node]))
    # the design spec's dipole limit: the spacecraft file's (the onboard default)
    assert hw.dipole_limit == spacecraft_dipole_limit(ROOT / "config" / "spacecraft.yaml")
    # verify's torquer range: the design spec's budget to its limit, as without a hardware file
    req = Requirements.from_mapping({}, hw.dipole_limit)
    disp = hw.verify_dispersions(req.dipole_budget, req.dipole_limit)
    assert (disp["dipole_limit_min"], disp["dipole_limit_max"]) == (req.dipole_budget, req.dipole_limit)


def test_shipped_file_through_the_scenario_changes_no_node_parameter(tmp_path):
    """magtune sil --attitude estimator with and without --hardware config/hardware.yaml: every node reads the same
    values bit for bit (truth mode differs by design: there the sensors node flies ideal sensors without a file)."""
    req = dict(steps=5, attitude="estimator")
    base = _nodes(SilScenario.build({"": GAINS}, SilRequest(**req)), tmp_path / "a")
    with_hw = _nodes(SilScenario.build({"": GAINS}, SilRequest(hardware=SHIPPED, **req)), tmp_path / "b")
    assert set(base) == set(NODES)
    for node in NODES:
        assert not _same(base[node], with_hw[node]), node


def test_12u_hardware_file_replaces_the_spacecraft_node_sections(tmp_path):
    """The 12U's hardware file gives its spacecraft file's torquers: a spacecraft file without the node sections plus
    the hardware file flies what the spacecraft file flies today; the file with its sections agrees with it."""
    doc = yaml.safe_load((EXAMPLE / "spacecraft.yaml").read_text())
    bare = tmp_path / "spacecraft_bare.yaml"
    bare.write_text(yaml.safe_dump({"/**": doc["/**"]}))
    req = dict(steps=5, attitude="estimator")
    today = _nodes(SilScenario.build({"": GAINS}, SilRequest(spacecraft=EXAMPLE / "spacecraft.yaml", **req)), tmp_path / "a")
    hw = EXAMPLE / "hardware.yaml"
    replaced = _nodes(SilScenario.build({"": GAINS}, SilRequest(spacecraft=bare, hardware=hw, **req)), tmp_path / "b")
    both = _nodes(SilScenario.build({"": GAINS}, SilRequest(spacecraft=EXAMPLE / "spacecraft.yaml", hardware=hw, **req)),
                  tmp_path / "c")
    assert list(today["simulator"]["dipole_limit"]) == [0.2] * 3 and list(today["simulator"]["residual_dipole"]) == [0.05] * 3
    for node in NODES:
        assert not _same(today[node], replaced[node]), node
        assert not _same(today[node], both[node]), node
    assert load_hardware(hw).dipole_limit == spacecraft_dipole_limit(EXAMPLE / "spacecraft.yaml") == 0.2


def test_spacecraft_section_disagreeing_with_the_hardware_file_is_refused(tmp_path):
    with pytest.raises(ConfigError) as exc:
        SilScenario.build({"": GAINS}, SilRequest(steps=5, spacecraft=EXAMPLE / "spacecraft.yaml", hardware=SHIPPED))
    assert "field 'dipole_limit'" in str(exc.value) and "\n" not in str(exc.value)


# ---------------------------------------------------------------- the figures reach the nodes
HARDWARE = {
    "torquers": {"max_dipole": [30.0, 35.0, 40.0], "residual_dipole": [0.5, -0.2, 0.1], "scale_factor_error": 25.0,
                 "coupling": [200.0, 0, 0, 0, -100.0, 0, 0, 0, -100.0]},
    "magnetometer": {"noise_density": 20.0, "bandwidth": 25.0, "range": 100.0, "resolution": 13.0, "bias": [50.0, 0, -50.0]},
    "gyro": {"angle_random_walk": 0.15, "bias_instability": 10.0, "bias_instability_time": 300.0,
             "initial_bias": [100.0, 0.0, -100.0]},
    "sun_sensor": {"accuracy": 1.5, "accuracy_sigma": 3, "fov_half_angle": 60.0, "boresight": [0.0, 0.0, -1.0]},
    "gnss": {"position_std": 5.0},
}


def test_hardware_figures_reach_every_node(tmp_path):
    path = tmp_path / "hw.yaml"
    path.write_text(yaml.safe_dump(HARDWARE))
    sc = SilScenario.build({"": GAINS}, SilRequest(steps=5, attitude="estimator", hardware=path))
    v = _nodes(sc, tmp_path / "logs")
    deg = math.pi / 180.0
    for node in ("simulator", "controller"):
        assert list(v[node]["dipole_limit"]) == [30.0, 35.0, 40.0]
        assert v[node]["torquer_coupling"][0] == 2e-7 and v[node]["torquer_coupling"][4] == -1e-7
    assert list(v["simulator"]["residual_dipole"]) == [0.5, -0.2, 0.1]
    s = v["attitude_sensors"]
    assert s["mag_noise_std"] == 100e-9 and s["mag_quantum"] == 13e-9 and list(s["mag_bias"]) == [50e-9, 0.0, -50e-9]
    assert s["gyro_arw"] == pytest.approx(0.15 * deg / 60.0, rel=1e-15)
    assert s["gyro_rrw"] == pytest.approx(3.2205e-6, rel=1e-4)  # the hand calculation above
    assert s["gyro_bias"][0] == pytest.approx(100.0 * deg / 3600.0, rel=1e-15)
    assert s["sun_noise_std"] == pytest.approx(0.5 * deg, rel=1e-15) and s["sun_fov_half_angle"] == pytest.approx(60 * deg)
    assert list(s["sun_boresight"]) == [0.0, 0.0, -1.0] and s["position_noise_std"] == 5.0
    assert s["velocity_noise_std"] == 0.0  # not given: the node's default
    e = v["attitude_estimator"]
    # the filter's magnetometer variance includes the quantization: 100^2 + 13^2 / 12 nT^2
    assert e["mag_noise_std"] == pytest.approx(math.sqrt(100.0**2 + 13.0**2 / 12.0) * 1e-9, rel=1e-14)
    assert (e["gyro_arw"], e["gyro_rrw"], e["sun_noise_std"]) == (s["gyro_arw"], s["gyro_rrw"], s["sun_noise_std"])
    # verify: the weakest rod 30 x 0.75 = 22.5 A m^2 lies below the 80 % budget of 30: it is flown
    hw = load_hardware(path)
    assert hw.dipole_limit == 30.0
    disp = hw.verify_dispersions(0.8 * 30.0, 30.0)
    assert disp["dipole_limit_min"] == 22.5 and disp["dipole_limit_max"] == 30.0 and disp["gyro_noise_std"] == 0.0


def test_truth_mode_sensors_take_the_hardware_file(tmp_path):
    path = tmp_path / "hw.yaml"
    path.write_text(yaml.safe_dump({"magnetometer": {"noise_std": 50.0}}))
    v = _nodes(SilScenario.build({"": GAINS}, SilRequest(steps=5, hardware=path)), tmp_path / "logs")
    assert v["attitude_sensors"]["mag_noise_std"] == 50e-9 and v["attitude_sensors"]["gyro_arw"] == 0.0
    assert list(v["simulator"]["dipole_limit"]) == [50.0] * 3  # no torquers section: the node's default


# ---------------------------------------------------------------- bad files: one line naming the field, exit 2
BAD = [
    ({"gyros": {}}, "gyros"),
    ({"gyro": {"angle_random_walk": 0.1, "rate_randomwalk": 1.0}}, "gyro.rate_randomwalk"),
    ({"gyro": {"rate_random_walk": 1.0}}, "gyro.angle_random_walk"),
    ({"gyro": {"angle_random_walk": 0.1, "bias_instability": 3.0}}, "gyro.bias_instability_time"),
    ({"gyro": {"angle_random_walk": 0.1}}, "gyro.rate_random_walk"),
    ({"gyro": {"angle_random_walk": 1000.0, "rate_random_walk": 1.0}}, "gyro.angle_random_walk"),
    ({"magnetometer": {"noise_std": 100.0, "noise_density": 10.0, "bandwidth": 10.0}}, "magnetometer.noise_std"),
    ({"magnetometer": {"noise_density": 10.0}}, "magnetometer.bandwidth"),
    ({"sun_sensor": {"accuracy": 0.5, "accuracy_sigma": 2.5}}, "sun_sensor.accuracy_sigma"),
    ({"sun_sensor": {"accuracy": 0.5, "accuracy_sigma": 1, "boresight": [0, 0, 0]}}, "sun_sensor.boresight"),
    ({"torquers": {"max_dipole": [50.0, 50.0]}}, "torquers.max_dipole"),
    ({"torquers": "50"}, "torquers"),
]


@pytest.mark.parametrize("doc, field", BAD)
def test_bad_hardware_file_is_one_config_error(doc, field):
    with pytest.raises(ConfigError) as exc:
        Hardware.from_mapping(doc, "hw.yaml")
    assert exc.value.field == field and "\n" not in str(exc.value)


@pytest.mark.parametrize("command", [
    ["sil", "--gains", str(GAINS), "--steps", "5"],
    ["export", str(EXAMPLE / "gains_sigma120.yaml"), "--config", str(EXAMPLE / "spacecraft.yaml"), "--out", "OUT"],
    ["analyze", str(GAINS), "--requirements"],
])
def test_bad_hardware_file_on_the_command_line_is_one_line_exit_2(tmp_path, capsys, command):
    bad = tmp_path / "hw.yaml"
    bad.write_text("gyro:\n  angle_random_walk: 0.1\n  rate_random_walk: -1.0\n")
    argv = [str(tmp_path / "out") if a == "OUT" else a for a in command] + ["--hardware", str(bad)]
    line = one_line_exit2(capsys, argv)
    assert "field 'gyro.rate_random_walk'" in line and str(bad) in line
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


# ---------------------------------------------------------------- export and verify
def test_export_table_takes_the_hardware_file_between_spacecraft_and_gains():
    from magtune_core.studies import flight_table as ft

    gains = EXAMPLE / "gains_sigma120.yaml"
    today = ft.build_table(gains, EXAMPLE / "spacecraft.yaml")
    t = ft.build_table(gains, EXAMPLE / "spacecraft.yaml", hardware_path=EXAMPLE / "hardware.yaml")
    for node in ft.FLIGHT_NODES:  # the 12U's hardware file moves no flight value
        assert not _same(today.values[node], t.values[node]), node
    assert t.sources["controller"]["dipole_limit"] == ft.HARDWARE and t.sources["controller"]["gain"] == ft.GAINS
    assert t.sources["attitude_estimator"]["gyro_arw"] == ft.HARDWARE and "hardware" in t.files
    assert today.residual_dipole == t.residual_dipole == (0.05, 0.05, 0.05)


def test_verify_flies_the_hardware_files_sensors_and_torquer_range(tmp_path):
    from dataclasses import replace

    from magtune_core.studies.campaign import load_spec
    from magtune_core.studies.verify import campaign_for

    spec = load_spec(ROOT / "config" / "campaigns" / "example.yaml")
    req = Requirements.from_mapping({}, 50.0)
    today = campaign_for(spec, GAINS, 1.0, req).dispersions
    shipped = campaign_for(spec, GAINS, 1.0, replace(req, hardware=load_hardware(SHIPPED))).dispersions
    assert (shipped["dipole_limit_min"], shipped["dipole_limit_max"]) == (today["dipole_limit_min"], today["dipole_limit_max"])
    assert today["gyro_noise_std"] == 1e-5 and shipped["gyro_noise_std"] == 0.0 and shipped["gyro_arw"] == 1e-4
    assert shipped["mag_bias_std"] == today["mag_bias_std"]  # what the hardware file does not give stays the campaign's


def test_explicit_options_stay_above_the_hardware_file(tmp_path):
    """--scenario's torquers and --estimator-param win over the hardware file, in every node that takes them."""
    path = tmp_path / "hw.yaml"
    path.write_text(yaml.safe_dump(HARDWARE))
    coupling = [1e-7, 0, 0, 0, 1e-7, 0, 0, 0, 1e-7]
    sc = SilScenario.build({"": GAINS}, SilRequest(steps=5, attitude="estimator", hardware=path,
                                                   torquers={"torquer_coupling": coupling},
                                                   estimator_params={"gyro_arw": 2e-4}))
    v = _nodes(sc, tmp_path / "logs")
    for node in ("simulator", "controller", "attitude_sensors"):
        assert list(v[node]["torquer_coupling"]) == coupling, node
    assert v["attitude_estimator"]["gyro_arw"] == 2e-4 and list(v["controller"]["dipole_limit"]) == [30.0, 35.0, 40.0]
