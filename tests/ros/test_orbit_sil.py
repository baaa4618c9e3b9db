"""Any orbit and a fitted field in the SIL: the nodes fly the spacecraft file's orbit (RAAN, epoch,
argument of latitude) and `--field FILE`, exactly as the offline simulation; bad orbits are one line.

Every test isolates itself with a ROS_DOMAIN_ID reserved through DomainLock (inside run_sil) and
LOCALHOST discovery, and run_sil stops every process in ``finally``.
"""
import subprocess
import sys

import numpy as np
import pytest

from magtune_core.base.errors import ConfigError
from magtune_core.base.paramfile import read_ros_params
from magtune_core.design.fitfield import field_for_spacecraft
from magtune_core.design.gains import load_gains
from magtune_core.design.params import load_spacecraft
from magtune_core.ros import process, sil
from magtune_core.sim.fullenv import nominal_orbit_period
from magtune_core.sim.simulate import simulate

pytestmark = pytest.mark.ros
EXAMPLE = "config/examples/cubesat12u"




def test_sil_flies_the_spacecraft_orbit(tmp_path):
    """12U file: 550 km SSO, RAAN 258.8 deg, epoch 2027-01-01, its residual dipole and dipole limit."""
    sc = f"{EXAMPLE}/spacecraft.yaml"
    gains = f"{EXAMPLE}/gains_sigma120.yaml"
    run = sil.run_sil(gains, steps=300, environment="full", spacecraft=sc, log_dir=tmp_path, timeout=120)
    assert run.counters["missed_steps"] == 0
    p = load_spacecraft(sc)
    node = read_ros_params(sc, "simulator")
    off = simulate(load_gains(gains).K, p, steps=300, environment="full", dipole_limit=node["dipole_limit"],
                   residual_dipole=node["residual_dipole"])
    assert run.result.orbit_period == off.orbit_period == nominal_orbit_period(p)
    # same FullDynamics, same float64 arithmetic in node and offline: 1e-9 is a loose bound on 0
    for k in ("q", "w", "x", "m", "b"):
        assert np.max(np.abs(getattr(run.result, k) - getattr(off, k))) <= 1e-9, k
    # and it is not the default orbit: IGRF along RAAN 258.8 deg in 2027 differs by uT from RAAN 0 in 2026
    default = simulate(load_gains(gains).K, load_spacecraft("config/spacecraft.yaml"), steps=2, environment="full")
    assert np.max(np.abs(default.b[0] - off.b[0])) > 1e-6
    # the dipole limit of the file reached the controller: 0.2 A m^2 per axis
    assert np.max(np.abs(run.result.m)) <= 0.2 + 1e-12


def test_sil_field_file_in_the_paper_environment(tmp_path):
    field_file = "config/field_model.yaml"  # IGRF fit of the paper's orbit (magtune fit-field)
    gains = "config/gains/sigma_120.yaml"
    run = sil.run_sil(gains, steps=200, field=field_file, log_dir=tmp_path, timeout=120)
    p = load_spacecraft("config/spacecraft.yaml")
    off = simulate(load_gains(gains).K, p, steps=200, field=field_for_spacecraft(field_file, p))
    for k in ("q", "w", "x", "m", "b"):
        assert np.max(np.abs(getattr(run.result, k) - getattr(off, k))) <= 1e-9, k
    eq26 = simulate(load_gains(gains).K, p, steps=2)
    assert np.max(np.abs(eq26.b[0] - off.b[0])) > 1e-6  # really another field than eq. 26
    with pytest.raises(ConfigError, match="full environment uses IGRF"):
        sil.run_sil(gains, steps=10, field=field_file, environment="full")


def test_bad_orbit_one_line_in_cli_and_node(tmp_path):
    bad = tmp_path / "spacecraft.yaml"
    bad.write_text(open("config/spacecraft.yaml").read().replace("altitude: 450000.0", "altitude: 100000.0"))
    cli = subprocess.run([sys.executable, "-m", "magtune_core", "sil", "--gains", "config/gains/sigma_60.yaml",
                          "--config", str(bad), "--quiet"], capture_output=True, text=True, timeout=60)
    assert cli.returncode == 2 and len(cli.stderr.strip().splitlines()) == 1
    assert "field 'altitude': expected a number in [150000, 2e+06] m, got 100000" in cli.stderr
    with process.DomainLock() as lock:
        env = process.child_env(lock.domain_id, process.package_prefix())
        r = subprocess.run([str(process.resolve_executable("simulator")), "--ros-args", "--params-file", str(bad)],
                           env=env, capture_output=True, text=True, timeout=30)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines()[-1].startswith("simulator: parameter 'altitude': expected a number in [150000, 2e+06] m")


def test_sil_flies_the_tle_orbit(tmp_path):
    """The 12U example given by a TLE (tle_file beside the spacecraft file): the nodes get its lines and fly
    SGP4's state at the epoch through the J2 model, exactly as the offline simulation."""
    sc = f"{EXAMPLE}/spacecraft_tle.yaml"
    gains = f"{EXAMPLE}/gains_sigma120.yaml"
    run = sil.run_sil(gains, steps=100, environment="full", spacecraft=sc, log_dir=tmp_path, timeout=120)
    p = load_spacecraft(sc)
    node = read_ros_params(sc, "simulator")
    off = simulate(load_gains(gains).K, p, steps=100, environment="full", dipole_limit=node["dipole_limit"],
                   residual_dipole=node["residual_dipole"])
    assert run.result.orbit_period == off.orbit_period == nominal_orbit_period(p)
    for k in ("q", "w", "x", "m", "b"):  # same FullDynamics and arithmetic: 1e-9 is a loose bound on 0
        assert np.max(np.abs(getattr(run.result, k) - getattr(off, k))) <= 1e-9, k
    circular = simulate(load_gains(gains).K, load_spacecraft(f"{EXAMPLE}/spacecraft.yaml"), steps=100, environment="full")
    assert np.max(np.abs(circular.b - off.b)) > 1e-8  # another orbit than the circular one (e = 0.0012, osculating state)


@pytest.mark.parametrize("extra, field, words", [
    ('    tle: ["1 25544U 98067A   08264.51782528 -.00002182  00000-0 -11606-4 0  2927",\n'
     '          "2 25544  51.6416 247.4627 0006703 130.5360 325.0288 15.72125391563530"]\n',
     "tle", "line 2 checksum: column 69 holds '0', the line tallies to 7"),
    ('    tle: ["1 25544U 98067A   08264.51782528 -.00002182  00000-0 -11606-4 0  2927",\n'
     '          "2 25544  51.6416 247.4627 0006703 130.5360 325.0288 15.72125391563537"]\n',
     "altitude", "given together with tle: the TLE gives the orbit; remove altitude"),
])
def test_bad_tle_same_line_in_cli_and_node(tmp_path, extra, field, words):
    """A bad TLE (or one given with the circular elements) is the same one line in the CLI and in a node
    started by hand with the file (the schema's defaults leave the circular elements unset in both)."""
    bad = tmp_path / "spacecraft.yaml"
    text = open("config/spacecraft.yaml").read()
    for key in ("inclination", "raan", "arg_latitude", "epoch", "orbit_period"):  # altitude stays in the file
        text = "\n".join(ln for ln in text.splitlines() if not ln.strip().startswith(f"{key}:")) + "\n"
    bad.write_text(text.replace("  ros__parameters:\n", "  ros__parameters:\n" + extra, 1))
    if field == "tle":
        bad.write_text(bad.read_text().replace("    altitude: 450000.0", "    # altitude: given by the TLE"))
    cli = subprocess.run([sys.executable, "-m", "magtune_core", "sil", "--gains", "config/gains/sigma_60.yaml",
                          "--config", str(bad), "--quiet"], capture_output=True, text=True, timeout=60)
    assert cli.returncode == 2 and len(cli.stderr.strip().splitlines()) == 1, cli.stderr
    assert f"field '{field}': {words}" in cli.stderr
    with process.DomainLock() as lock:
        env = process.child_env(lock.domain_id, process.package_prefix())
        r = subprocess.run([str(process.resolve_executable("simulator")), "--ros-args", "--params-file", str(bad)],
                           env=env, capture_output=True, text=True, timeout=30)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines()[-1].startswith(f"simulator: parameter '{field}': {words}")
