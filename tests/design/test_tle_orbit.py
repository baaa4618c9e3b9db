"""The orbit of a spacecraft file given by a TLE (magtune_core.design.params): tle / tle_file, the epoch rule,
the age warning, the design commands' eccentricity bound, bad TLEs as one line and exit 2, and files without
a TLE unchanged bit for bit."""
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
import yaml
from cli_errors import one_line_exit2  # tests/support

from magtune_core.base.errors import ConfigError
from magtune_core.cli import main as cli_main
from magtune_core.design.fitfield import field_for_spacecraft, load_field_model
from magtune_core.design.params import (
    ECCENTRICITY_MAX,
    SpacecraftParams,
    check_design_orbit,
    load_spacecraft,
    tle_warning,
)
from magtune_core.env.earth import julian_date
from magtune_core.env.orbit import (
    OrbitConfig,
    argument_of_latitude,
    inclination,
    initial_state,
    mean_frame_period,
    raan,
)
from magtune_core.env.tle import MAX_AGE_DAYS, checksum, parse_tle

ROOT = Path(__file__).resolve().parents[2]
SPACECRAFT = ROOT / "config" / "spacecraft.yaml"
EXAMPLE = ROOT / "config" / "examples" / "cubesat12u"
GAINS = ROOT / "config" / "gains" / "sigma_60.yaml"
ISS = ("1 25544U 98067A   08264.51782528 -.00002182  00000-0 -11606-4 0  2927",
       "2 25544  51.6416 247.4627 0006703 130.5360 325.0288 15.72125391563537")


def _fix(line: str) -> str:
    return line[:68] + str(checksum(line))


def _spacecraft(tmp_path, name="sc.yaml", **orbit) -> Path:
    """config/spacecraft.yaml with its orbit (the circular elements, epoch, orbit_period) replaced by ``orbit``."""
    doc = yaml.safe_load(SPACECRAFT.read_text())
    params = doc["/**"]["ros__parameters"]
    for k in ("altitude", "inclination", "raan", "arg_latitude", "epoch", "orbit_period"):
        params.pop(k, None)
    params.update(orbit)
    out = tmp_path / name
    out.write_text(yaml.safe_dump(doc))
    return out


def test_file_without_tle_gives_exactly_the_old_orbit():
    """No TLE: the OrbitConfig, the initial state and the period the code gave before TLEs existed (numbers of
    commit 2821441), bit for bit - the shipped gains, the reference bag and the docs' figures rest on them."""
    p = load_spacecraft(SPACECRAFT)
    assert p.tle is None and p.state0 is None and p.eccentricity == 0.0
    assert p.orbit_config() == OrbitConfig(altitude=450e3, inclination_deg=87.0, raan_deg=0.0, arg_lat_deg=0.0,
                                           epoch=datetime(2026, 3, 20))
    r, v = initial_state(p.orbit_config())
    assert r.tolist() == [6828136.3, 0.0, 0.0] and v.tolist() == [-0.0, 399.8692061817884, 7629.958980368059]
    assert p.orbit_period == 5614.8
    q = load_spacecraft(EXAMPLE / "spacecraft.yaml")
    cfg = OrbitConfig(altitude=550e3, inclination_deg=97.6, raan_deg=258.8, arg_lat_deg=0.0, epoch=datetime(2027, 1, 1))
    assert q.orbit_config() == cfg and q.orbit_period == 5734.85887744588 == mean_frame_period(cfg)
    # an element left out is still the paper's
    p = SpacecraftParams.from_mapping({"inertia": [35.0, 17.0, 25.0], "wheel_inertia": 0.01, "wheel_speed": -200.0})
    assert p.orbit_config() == OrbitConfig()


def test_tle_file_is_found_beside_the_spacecraft_file(tmp_path, monkeypatch):
    (tmp_path / "orbits").mkdir()
    (tmp_path / "orbits" / "iss.tle").write_text("ISS (ZARYA)\r\n" + "\r\n".join(ISS) + "\r\n\r\n")
    sc = _spacecraft(tmp_path, tle_file="orbits/iss.tle")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # not the spacecraft file's directory
    p = load_spacecraft(sc)
    assert p.tle.name == "ISS (ZARYA)" and (p.tle.line1, p.tle.line2) == ISS and p.tle_field == "tle_file"
    inline = load_spacecraft(_spacecraft(tmp_path, "inline.yaml", tle=list(ISS)))
    assert inline.state0 == p.state0 and inline.orbit_period == p.orbit_period and inline.tle_field == "tle"
    # without the file's directory (a node's parameters) a relative path is refused, an absolute one is read
    values = yaml.safe_load(sc.read_text())["/**"]["ros__parameters"]
    with pytest.raises(ConfigError, match="field 'tle_file': relative path 'orbits/iss.tle'"):
        SpacecraftParams.from_mapping(values, "node")
    values["tle_file"] = str(tmp_path / "orbits" / "iss.tle")
    assert SpacecraftParams.from_mapping(values, "node").state0 == p.state0


def test_epoch_defaults_to_the_tle_epoch_and_the_orbit_starts_from_sgp4(tmp_path, capsys):
    tle = parse_tle(ISS)
    p = load_spacecraft(_spacecraft(tmp_path, tle=list(ISS)))
    assert p.epoch == tle.epoch == datetime(2008, 9, 20, 12, 25, 40, 104192)
    assert p.orbit_config().jd0 == julian_date(tle.epoch)
    r, v = tle.state(0.0)
    assert p.state0 == tuple(np.r_[r, v]) and np.array_equal(initial_state(p.orbit_config())[0], r)
    # the elements describe SGP4's state (osculating) and the mean motion (altitude)
    assert p.inclination_deg == pytest.approx(np.degrees(inclination(r, v)), abs=0) and abs(p.inclination_deg - 51.64) < 0.05
    assert p.raan_deg == pytest.approx(np.degrees(raan(r, v)) % 360.0) and abs(p.raan_deg - 247.46) < 0.05
    assert p.arg_lat_deg == pytest.approx(np.degrees(argument_of_latitude(r, v)))
    assert p.eccentricity == 0.0006703 and tle_warning(p) is None
    # the LTP period from the mean motion: keplerian = 2 pi / n; j2_mean = the mean orbital-frame rate of the
    # J2 orbit from SGP4's state (the nodal period: 2 pi / n moved by the J2 secular rates of the perigee and the
    # mean anomaly, -0.022 % at 51.6 deg, +0.13 % for the 12U example's 97.6 deg)
    assert p.orbit_period == pytest.approx(2 * np.pi / tle.mean_motion, rel=1e-12)
    j2 = load_spacecraft(_spacecraft(tmp_path, "j2.yaml", tle=list(ISS), period_model="j2_mean"))
    assert j2.orbit_period == mean_frame_period(j2.orbit_config())
    assert -3e-4 < j2.orbit_period / p.orbit_period - 1.0 < -1.5e-4
    assert capsys.readouterr().err == ""
    # an explicit epoch: SGP4's state then; older than MAX_AGE_DAYS -> one warning line naming the field per load
    # (none with warn=False: a worker's job after the command's front end warned)
    later = tle.epoch + timedelta(days=2)
    q = load_spacecraft(_spacecraft(tmp_path, "later.yaml", tle=list(ISS), epoch=later.isoformat()))
    assert q.state0 == tuple(np.concatenate(tle.state(2 * 86400.0))) and capsys.readouterr().err == ""
    old = _spacecraft(tmp_path, "old.yaml", tle=list(ISS), epoch=(tle.epoch + timedelta(days=MAX_AGE_DAYS + 3)).isoformat())
    load_spacecraft(old)
    load_spacecraft(old, warn=False)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "warning: field 'tle': the TLE of NORAD 25544" in err and "10.0 days old" in err


def test_orbit_overrides_turn_the_tle_state():
    """Campaigns pass the file's own RAAN and argument of latitude (the undispersed orbit: the same state), or
    others: the state turned about the pole / along its plane; an epoch override only moves the date."""
    p = SpacecraftParams.from_mapping({"inertia": [35.0, 17.0, 25.0], "wheel_inertia": 0.01, "wheel_speed": -200.0,
                                       "tle": list(ISS)})
    same = p.orbit_config(raan_deg=p.raan_deg, arg_lat_deg=p.arg_lat_deg, zonal_degree=4)
    assert same.state0 is p.state0 and same.zonal_degree == 4
    moved = p.orbit_config(raan_deg=p.raan_deg + 10.0, arg_lat_deg=p.arg_lat_deg + 90.0, epoch=datetime(2009, 1, 1))
    r, v = initial_state(moved)
    r0, v0 = initial_state(p.orbit_config())
    assert np.degrees(raan(r, v)) % 360 == pytest.approx(p.raan_deg + 10.0, abs=1e-9)
    assert np.degrees(argument_of_latitude(r, v)) == pytest.approx((p.arg_lat_deg + 90.0) % 360, abs=1e-9)
    assert np.degrees(inclination(r, v)) == pytest.approx(p.inclination_deg, abs=1e-9)
    assert np.linalg.norm(r) == pytest.approx(np.linalg.norm(r0), rel=1e-14) and np.dot(r, v) == pytest.approx(np.dot(r0, v0))
    assert moved.epoch == datetime(2009, 1, 1)
    with pytest.raises(ValueError, match="override only raan_deg, arg_lat_deg, epoch"):
        p.orbit_config(altitude=500e3)


@pytest.mark.parametrize("orbit, field, words", [
    (dict(tle=list(ISS), altitude=450e3), "altitude", "given together with tle: the TLE gives the orbit; remove altitude"),
    (dict(tle=list(ISS), arg_latitude=0.0), "arg_latitude", "remove arg_latitude"),
    (dict(tle=list(ISS), tle_file="x.tle"), "tle_file", "given together with tle: keep one of them"),
    (dict(tle_file="missing.tle"), "tle_file", "missing.tle: file not found"),
    # given but empty or null: refused, not the default circular orbit (issue 57)
    (dict(tle_file=None), "tle_file", "null: give it a value"),
    (dict(tle_file=""), "tle_file", "empty: give the element set, or remove the key"),
    (dict(tle=[]), "tle", "empty: give the element set, or remove the key"),
    (dict(tle=None), "tle", "null: give it a value"),
    (dict(altitude=None), "altitude", "null: give it a value"),
    (dict(tle=[ISS[0], ISS[1][:68] + "0"]), "tle", "line 2 checksum: column 69 holds '0', the line tallies to 7"),
    (dict(tle=[ISS[0]]), "tle", "expected the 2 lines of a TLE"),
    # a fullwidth digit (U+FF13) passed isdigit() and the checksum and reached SGP4 (issue 57)
    (dict(tle=[ISS[0], ISS[1][:10] + "\uff13" + ISS[1][11:]]), "tle", "line 2, column 11 holds '\uff13' (U+FF13)"),
    (dict(tle=[ISS[0], _fix(ISS[1][:52] + "16.60000000" + ISS[1][63:])]), "tle", "below 150 km (decayed or re-entering"),
    (dict(tle=[ISS[0], _fix(ISS[1][:43] + "325.a288" + ISS[1][51:])]), "tle", "line 2, columns 44-51 (mean anomaly)"),
    # SGP4's error code at the simulation epoch: a huge drag term (B* 0.128) has decayed the orbit 15 days on
    (dict(tle=[_fix(ISS[0][:53] + " 12808-1" + ISS[0][61:]), ISS[1]], epoch="2008-10-05T12:00:00"), "tle",
     "SGP4 error 6 for NORAD 25544 +14.98 days from its epoch"),
])
def test_bad_tle_is_one_line_and_exit_2(tmp_path, capsys, orbit, field, words):
    sc = _spacecraft(tmp_path, **orbit)
    err = one_line_exit2(capsys, ["--config", str(sc), "analyze", str(GAINS)])
    assert f"field '{field}': " in err and words in err, err


def test_design_commands_refuse_an_eccentric_orbit(tmp_path, capsys):
    """e = 0.02 (perigee 212 km, apogee 482 km): a LEO orbit the SIL flies, but not one the circular LTP model
    represents (ECCENTRICITY_MAX = 0.01, derived in design/params.py). One line naming the field and the fix."""
    eccentric = [ISS[0], _fix(ISS[1][:26] + "0200000" + ISS[1][33:])]
    sc = _spacecraft(tmp_path, tle=eccentric)
    p = load_spacecraft(sc)  # the spacecraft file itself is valid (sil, campaigns)
    assert p.eccentricity == 0.02 > ECCENTRICITY_MAX
    for argv in (["--config", str(sc), "analyze", str(GAINS)], ["--config", str(sc), "verify", str(GAINS), "--out", str(tmp_path / "v")],
                 ["fit-field", "--spacecraft", str(sc), "--out", str(tmp_path / "f.yaml")]):
        err = one_line_exit2(capsys, argv)
        assert "field 'tle': eccentricity 0.0200 > 0.01: the circular LTP model cannot represent this orbit" in err
        assert "design for a near-circular orbit" in err
    assert not (tmp_path / "f.yaml").exists()
    # typical LEO TLEs pass: the ISS (e = 0.00067) and the 12U example's (e = 0.0012)
    check_design_orbit(load_spacecraft(_spacecraft(tmp_path, "iss.yaml", tle=list(ISS))), "iss.yaml")
    check_design_orbit(load_spacecraft(EXAMPLE / "spacecraft_tle.yaml"), "12u")


def test_fit_field_along_the_tle_orbit(tmp_path, capsys):
    """fit-field --spacecraft: IGRF sampled along the J2 orbit from SGP4's state (a short arc here); the file records
    the TLE and is accepted as the design field of that spacecraft; the orbit options conflict with it."""
    sc = EXAMPLE / "spacecraft_tle.yaml"
    out = tmp_path / "f.yaml"
    assert cli_main(["fit-field", "--spacecraft", str(sc), "--days", "0.25", "--step", "60", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "orbit from the TLE of MAGTUNE-12U EXAMPLE" in err and "e = 0.0012000" in err
    p = load_spacecraft(sc)
    field, meta = load_field_model(out, with_meta=True)
    assert meta["eccentricity"] == 0.0012 and meta["tle_line1"] == p.tle.line1 and meta["epoch"] == "2027-01-01T00:00:00"
    assert field_for_spacecraft(out, p).omega == field.omega
    # the fitted rate is the nodal rate of that orbit: the j2_mean period within 0.05 % (a quarter-day arc)
    assert abs(field.period / p.orbit_period - 1.0) < 5e-4
    err = one_line_exit2(capsys, ["fit-field", "--spacecraft", str(sc), "--altitude", "500", "--out", str(out), "--force"])
    assert "--altitude: the orbit comes from --spacecraft" in err


def test_spacecraft_with_a_tle_pickles():
    """Campaigns and verify send the spacecraft parameters to Dask workers by pickle: a TLE's SGP4 record
    (a Satrec, which does not pickle) travels as its lines and gives the same state there."""
    import pickle

    p = load_spacecraft(EXAMPLE / "spacecraft_tle.yaml", warn=False)
    q = pickle.loads(pickle.dumps(p))
    assert q.tle == p.tle and q.tle.label == "MAGTUNE-12U EXAMPLE"
    assert all(np.array_equal(a, b) for a, b in zip(q.tle.state(600.0), p.tle.state(600.0)))
