"""TLEs (magtune_core.env.tle): SGP4 against the published verification set, the checks of the lines,
and our J2 propagation started from SGP4's state against SGP4 itself."""
from importlib import resources

import numpy as np
import pytest

from magtune_core.base.errors import ConfigError
from magtune_core.env.orbit import Orbit, OrbitConfig, eci_to_orbital
from magtune_core.env.tle import check_leo, checksum, parse_tle

#: The sgp4 package ships the verification set of Vallado, Crawford, Hujsak & Kelso (2006), "Revisiting
#: Spacetrack Report #3" (AIAA 2006-6753): the TLEs (SGP4-VER.TLE) and the reference C++ output (tcppver.out).
VER = resources.files("sgp4").joinpath("SGP4-VER.TLE").read_text().splitlines()
OUT = resources.files("sgp4").joinpath("tcppver.out").read_text().splitlines()
#: The ISS TLE of 2008-09-20 (the example of the TLE format on Wikipedia and in CelesTrak's documentation).
ISS = ("1 25544U 98067A   08264.51782528 -.00002182  00000-0 -11606-4 0  2927",
       "2 25544  51.6416 247.4627 0006703 130.5360 325.0288 15.72125391563537")


def _ver_tle(num: int):
    """The verification TLE of catalogue number ``num`` (columns 1-69: line 2 carries the run's times after them)."""
    l1 = next(ln for ln in VER if ln.startswith(f"1 {num:05d}"))[:69]
    l2 = next(ln for ln in VER if ln.startswith(f"2 {num:05d}"))[:69]
    return parse_tle([l1, l2], "SGP4-VER.TLE")


def _ver_rows(num: int) -> np.ndarray:
    """tcppver.out rows of ``num``: tsince [min], r [km], v [km/s]."""
    i = OUT.index(f"{num} xx")
    rows = []
    for ln in OUT[i + 1:]:
        if ln.endswith("xx"):
            break
        rows.append([float(x) for x in ln.split()[:7]])
    return np.array(rows)


def _with_checksum(line: str) -> str:
    return line[:68] + str(checksum(line))


@pytest.mark.parametrize("num", [5, 6251])
def test_sgp4_positions_match_the_verification_set(num):
    """00005: the TEME example (e = 0.186, 3 days); 06251: a LEO object with moderate drag (perigee 377 km, e = 0.003),
    the kind of orbit magtune takes. tcppver.out prints km to 8 decimals (10 um) and km/s to 9 (1 um/s): agreement
    within one unit of the last printed digit (measured: 5 um, 0.5 um/s) is the reference reproduced. Failing is easy:
    WGS-84 instead of WGS-72 constants moves 00005 by 33 m, a unit slip (km as m) by kilometres."""
    tle, rows = _ver_tle(num), _ver_rows(num)
    assert len(rows) >= 13
    for row in rows:
        r, v = tle.state(row[0] * 60.0, "SGP4-VER.TLE")
        assert np.max(np.abs(r - row[1:4] * 1e3)) < 1e-5, row[0]
        assert np.max(np.abs(v - row[4:7] * 1e3)) < 1e-6, row[0]


def test_tle_elements_and_epoch():
    tle = parse_tle(["0 ISS (ZARYA)", *ISS])
    assert tle.name == "ISS (ZARYA)" and tle.satnum == "25544" and tle.label == "ISS (ZARYA)"
    # epoch 2008, day 264.51782528: 2008-09-20 12:25:40.104192 UTC (rounded to the microsecond)
    assert tle.epoch.isoformat() == "2008-09-20T12:25:40.104192"
    assert tle.eccentricity == 0.0006703 and tle.inclination_deg == pytest.approx(51.6416, abs=1e-12)
    assert tle.revs_per_day == 15.72125391
    # 2 pi / n of SGP4's (Brouwer) mean motion is the Keplerian period of the derived semi-major axis
    assert 2 * np.pi * np.sqrt(tle.semi_major_axis**3 / 3.986004415e14) == pytest.approx(2 * np.pi / tle.mean_motion, rel=1e-14)
    assert 340e3 < tle.perigee_altitude < tle.apogee_altitude < 370e3


def test_tle_pickles_with_its_sgp4_record():
    """Dask pickles the spacecraft parameters to campaign and verify workers (a Satrec does not pickle):
    the TLE travels as its lines and SGP4 gives the same state on the other side."""
    import pickle

    tle = parse_tle(["0 ISS (ZARYA)", *ISS])
    back = pickle.loads(pickle.dumps(tle))
    assert back == tle and back.name == tle.name
    for t in (0.0, 5400.0):
        assert all(np.array_equal(a, b) for a, b in zip(back.state(t), tle.state(t)))


@pytest.mark.parametrize("edit, words", [
    (lambda l1, l2: [l1], "expected the 2 lines of a TLE (or a name line and 2 lines), got 1 lines"),
    (lambda l1, l2: [l2, l1], "line 1 must start with '1 '"),
    (lambda l1, l2: [l1[:68], l2], "line 1 has 68 characters, a TLE line has 69"),
    (lambda l1, l2: [l1, l2[:68] + "0"], "line 2 checksum: column 69 holds '0', the line tallies to 7"),
    (lambda l1, l2: [l1, _with_checksum(l2[:2] + "25545" + l2[7:])], "catalogue numbers differ"),
    (lambda l1, l2: [l1, _with_checksum(l2[:26] + "00067a3" + l2[33:])],
     "line 2, columns 27-33 (eccentricity): not a TLE number: '00067a3'"),
    (lambda l1, l2: [_with_checksum(l1[:53] + "-11606x4" + l1[61:]), l2], "line 1, columns 54-61 (drag term B*)"),
    (lambda l1, l2: [l1, _with_checksum(l2[:8] + "181.6416" + l2[16:])],
     "line 2, columns 9-16 (inclination): out of range: 181.642 deg"),
    (lambda l1, l2: [l1, _with_checksum(l2[:52] + " 0.00000000" + l2[63:])], "(mean motion): out of range: 0 rev/day"),
])
def test_bad_tle_is_one_line_naming_the_line_and_element(edit, words):
    with pytest.raises(ConfigError) as exc:
        parse_tle(edit(*ISS), "sc.yaml")
    assert exc.value.field == "tle" and words in exc.value.expected and "\n" not in str(exc.value)


def test_leo_band_refuses_decayed_and_high_orbits():
    check_leo(parse_tle(ISS), (150e3, 2000e3))
    decayed = _with_checksum(ISS[1][:52] + "16.60000000" + ISS[1][63:])  # perigee ~ 120 km
    with pytest.raises(ConfigError, match=r"perigee at 1\d\d km, below 150 km \(decayed or re-entering"):
        check_leo(parse_tle([ISS[0], decayed]), (150e3, 2000e3), "sc.yaml", "tle_file")
    with pytest.raises(ConfigError, match="apogee at .* km, above 2000 km: not a LEO orbit"):
        check_leo(_ver_tle(5), (150e3, 2000e3))  # 00005: apogee ~3900 km
    # SGP4's own error codes: a huge drag term (B* 0.128) decays the orbit in 11 days (error 6, "mrt is less than 1.0")
    heavy = parse_tle([_with_checksum(ISS[0][:53] + " 12808-1" + ISS[0][61:]), ISS[1]])
    heavy.state(86400.0)
    with pytest.raises(ConfigError, match=r"SGP4 error 6 for NORAD 25544 \+15.00 days from its epoch: .*decayed"):
        heavy.state(15 * 86400.0, "sc.yaml")


@pytest.mark.parametrize("lines, num", [(ISS, None), (None, 6251)])
def test_j2_propagation_from_the_sgp4_state_stays_near_sgp4(lines, num):
    """The full environment propagates our J2 model from SGP4's state at the epoch (docs/decisions.md). Over one
    orbit (10 s samples) it stays within 0.5 km of SGP4 and its orbital frame within 0.01 deg. Measured: ISS 2008
    0.13 km / 0.0011 deg, 06251 0.29 km / 0.0024 deg; the difference is what the two models do not share (SGP4's
    drag, J3/J4 and its first-order short-period terms, WGS-72 vs JGM-3 constants), 0.5 km bounds it with
    margin, and a frame error fails it by far (the TEME state rotated by GMST, as if it were Earth-fixed:
    13,000 km; the state taken in km: no orbit)."""
    tle = parse_tle(lines) if lines else _ver_tle(num)
    r0, v0 = tle.state(0.0)
    T = 2 * np.pi / tle.mean_motion
    t = np.arange(0.0, T, 10.0)
    orbit = Orbit(OrbitConfig(epoch=tle.epoch, state0=tuple(np.r_[r0, v0])), T + 100.0)
    r, v = orbit.state(t)
    ref = [tle.state(x) for x in t]
    R, V = np.array([a for a, _ in ref]), np.array([b for _, b in ref])
    assert np.max(np.linalg.norm(r - R, axis=1)) < 500.0
    dR = np.einsum("nij,nkj->nik", eci_to_orbital(r, v), eci_to_orbital(R, V))
    angle = np.degrees(np.arccos(np.clip((np.trace(dR, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)))
    assert np.max(angle) < 0.01
