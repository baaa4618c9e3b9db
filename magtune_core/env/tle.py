"""Two-line element sets (TLE): strict parsing and SGP4 states in our ECI, through the ``sgp4`` package.

SGP4 itself is Vallado's implementation (``sgp4`` on PyPI, the C++ of Vallado, Crawford, Hujsak &
Kelso 2006, "Revisiting Spacetrack Report #3", AIAA 2006-6753), with the WGS-72 constants a TLE is
fitted with; this module only checks the lines (format, checksums, ranges: one line naming the line,
the columns and the element) and converts units.

Frames. SGP4 gives positions in TEME (true equator, mean equinox of date). Our ECI
(:mod:`magtune_core.env.earth`) is turned into ECEF by R_z(GMST), which is exactly SGP4's TEME ->
pseudo-Earth-fixed rotation (Vallado et al. 2006, sec. "Coordinate frames"): taken as our ECI,
the TEME state puts the satellite over the right point of the Earth (IGRF, atmosphere) with no
conversion. What the identity leaves out is the tilt between the true pole of TEME and the mean
pole of our ECI of date, which only the Sun direction sees: the nutation in obliquity and
Delta psi sin(eps) (IAU 1980: 9.2" and 6.9" at most), <= 0.0032 deg.

A TLE's epoch is a fraction of a day with 8 decimals; :attr:`TLE.epoch` is it rounded to the
microsecond (<= 0.5 us, 4 mm along the orbit), and the time since the TLE epoch is counted from
that datetime, so a simulation at the TLE's epoch starts from SGP4's state at tsince = 0 exactly.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from datetime import datetime, timedelta

import numpy as np
from sgp4.api import SGP4_ERRORS, WGS72, Satrec

from ..base.errors import ConfigError
from .earth import GM_EARTH, R_EARTH

#: A TLE older (or younger) than this at the simulation epoch gets a warning [days]. SGP4 errors of
#: LEO TLEs grow by about 1-3 km per day from ~1 km at the epoch (drag-dominated, growing faster than
#: linearly; Vallado et al. 2006 sec. "Accuracy", Kelso 2007 against GPS ephemerides): after a week
#: the along-track error reaches ~10-20 km, 0.1-0.2 deg of orbital position, the size of the
#: orbital-frame errors the design already tolerates.
MAX_AGE_DAYS = 7.0

# (line, first column, last column (1-based, inclusive), element name, pattern)
_NUMBER = r"[ +-]?\d*\.?\d+"
_COLUMNS = (
    (1, 19, 20, "epoch year", r"\d\d"),
    (1, 21, 32, "epoch day", r" *\d{1,3}\.\d+"),
    (1, 34, 43, "first derivative of the mean motion", r" *[+-]?\.\d+| *[+-]?0?\.\d+"),
    (1, 45, 52, "second derivative of the mean motion", r"[ +-]\d{5}[ +-]\d"),
    (1, 54, 61, "drag term B*", r"[ +-]\d{5}[ +-]\d"),
    (2, 9, 16, "inclination", r" *\d+\.\d+"),
    (2, 18, 25, "right ascension of the ascending node", r" *\d+\.\d+"),
    (2, 27, 33, "eccentricity", r"\d{7}"),
    (2, 35, 42, "argument of perigee", r" *\d+\.\d+"),
    (2, 44, 51, "mean anomaly", r" *\d+\.\d+"),
    (2, 53, 63, "mean motion", r" *\d+\.\d+"),
)


def checksum(line: str) -> int:
    """The TLE checksum of a line: its digits plus one per minus sign over columns 1-68, modulo 10.

    Parameters
    ----------
    line : str
        One TLE line (at least the first 68 characters are used).

    Returns
    -------
    int
        The checksum digit 0-9.
    """
    return sum(int(c) if c.isdigit() else c == "-" for c in line[:68]) % 10


@dataclass(frozen=True)
class TLE:
    """A checked two-line element set and its SGP4 record (WGS-72, improved mode as in the verification set)."""

    line1: str
    line2: str
    name: str = ""
    satrec: Satrec = field(default=None, compare=False, repr=False)

    def __reduce__(self):
        """Pickled as its lines (a ``Satrec`` does not pickle): Dask sends spacecraft parameters with a
        TLE to campaign and verify workers, which rebuild the same SGP4 record from them."""
        return (_from_lines, (self.line1, self.line2, self.name))

    @property
    def satnum(self) -> str:
        """Catalogue number (columns 3-7 of both lines)."""
        return self.line1[2:7].strip()

    @property
    def label(self) -> str:
        """The name line if given, else ``NORAD <number>``: how messages name the object."""
        return self.name or f"NORAD {self.satnum}"

    @property
    def epoch(self) -> datetime:
        """The TLE epoch (UTC, naive), rounded to the microsecond."""
        yy = int(self.line1[18:20])
        year = 2000 + yy if yy < 57 else 1900 + yy  # the TLE convention: 57-99 -> 19xx
        day = float(self.line1[20:32])
        return datetime(year, 1, 1) + timedelta(microseconds=round((day - 1.0) * 86400e6))

    @property
    def eccentricity(self) -> float:
        """Mean eccentricity (line 2, columns 27-33)."""
        return float(self.satrec.ecco)

    @property
    def inclination_deg(self) -> float:
        """Mean inclination [deg]."""
        return math.degrees(self.satrec.inclo)

    @property
    def revs_per_day(self) -> float:
        """Mean motion as written in the TLE (Kozai) [rev/day]."""
        return float(self.line2[52:63])

    @property
    def mean_motion(self) -> float:
        """SGP4's mean motion (Brouwer, un-Kozai'd: the theory's own n) [rad/s]."""
        return float(self.satrec.a ** -1.5 / self.satrec.tumin / 60.0)

    @property
    def semi_major_axis(self) -> float:
        """a = (GM / n^2)^(1/3) [m] of :attr:`mean_motion` with the JGM-3 GM: 2 pi sqrt(a^3/GM) = 2 pi / n."""
        return float((GM_EARTH / self.mean_motion**2) ** (1.0 / 3.0))

    @property
    def perigee_altitude(self) -> float:
        """a (1 - e) - R [m] above the JGM-3 equatorial radius."""
        return self.semi_major_axis * (1.0 - self.eccentricity) - R_EARTH

    @property
    def apogee_altitude(self) -> float:
        """a (1 + e) - R [m] above the JGM-3 equatorial radius."""
        return self.semi_major_axis * (1.0 + self.eccentricity) - R_EARTH

    def state(self, seconds: float, where="spacecraft parameters", name="tle") -> tuple[np.ndarray, np.ndarray]:
        """SGP4 position [m] and velocity [m/s] in our ECI (= TEME, module docstring) at ``seconds`` after the epoch.

        Parameters
        ----------
        seconds : float
            Time since :attr:`epoch` [s] (negative: before it).
        where : str
            File or context named in an error message.
        name : str
            Field named in an error message.

        Returns
        -------
        r, v : ndarray (3,)
            Position [m] and velocity [m/s].

        Raises
        ------
        ConfigError
            If SGP4 returns an error code (decayed, eccentricity out of range, ...) at that time.
        """
        err, r, v = self.satrec.sgp4_tsince(float(seconds) / 60.0)
        if err:
            when = "at its epoch" if seconds == 0 else f"{seconds / 86400.0:+.2f} days from its epoch"
            raise ConfigError(where, name, f"SGP4 error {err} for {self.label} {when}: {SGP4_ERRORS.get(err, 'unknown')} "
                                           "(a decayed or wrong TLE: use a current one)")
        return np.array(r) * 1e3, np.array(v) * 1e3


def _from_lines(line1: str, line2: str, name: str) -> TLE:
    """A :class:`TLE` of already checked lines with its SGP4 record (unpickling, :meth:`TLE.__reduce__`)."""
    return TLE(line1, line2, name, Satrec.twoline2rv(line1, line2, WGS72))


def split_lines(text: str) -> list[str]:
    """The non-blank lines of a TLE text, right-stripped (CR LF and trailing blanks removed).

    Parameters
    ----------
    text : str
        File content or lines joined by newlines.

    Returns
    -------
    list of str
        The lines that hold anything.
    """
    return [ln.rstrip() for ln in text.splitlines() if ln.strip()]


def parse_tle(lines, where="spacecraft parameters", name="tle") -> TLE:
    """Check a TLE given as [line 1, line 2] or [name, line 1, line 2] and initialize SGP4 with it.

    Checked, each with one line naming the TLE line, its columns and the element: the number of
    lines, each line's number and length (69 characters), the checksum (column 69), the catalogue
    number of both lines, the format of every element, the angles' and the eccentricity's ranges,
    a positive mean motion, and SGP4's initialization error code. No range of orbits is imposed
    here (the verification set has deep-space objects): :func:`check_leo` does that.

    Parameters
    ----------
    lines : sequence of str
        Two lines, or a name line (``0 `` prefix of the 3LE form allowed) and two lines.
    where : str
        File or context named in error messages.
    name : str
        Field named in error messages (``tle`` or ``tle_file``).

    Returns
    -------
    TLE
        The checked element set with its SGP4 record.

    Raises
    ------
    ConfigError
        If any check fails.
    """
    lines = [str(ln).rstrip("\r\n ") for ln in lines]
    if len(lines) not in (2, 3):
        raise ConfigError(where, name, f"expected the 2 lines of a TLE (or a name line and 2 lines), got {len(lines)} lines")
    title = lines[0][2:].strip() if len(lines) == 3 and lines[0].startswith("0 ") else lines[0].strip() if len(lines) == 3 else ""
    l1, l2 = lines[-2], lines[-1]
    for k, ln in ((1, l1), (2, l2)):
        if not ln.startswith(f"{k} "):
            raise ConfigError(where, name, f"line {k} must start with '{k} ', got {ln[:12]!r}")
        bad = next((i for i, c in enumerate(ln) if not (c.isascii() and c.isprintable())), None)
        if bad is not None:  # fullwidth digits pass isdigit() and int(): they reached SGP4 as "nm is less than zero"
            raise ConfigError(where, name, f"line {k}, column {bad + 1} holds {ln[bad]!r} (U+{ord(ln[bad]):04X}): a TLE is "
                                           "printable ASCII; retype the line or copy it from the source again")
        if len(ln) != 69:
            raise ConfigError(where, name, f"line {k} has {len(ln)} characters, a TLE line has 69 (checksum in column 69)")
        if not ln[68].isdigit() or int(ln[68]) != checksum(ln):
            raise ConfigError(where, name, f"line {k} checksum: column 69 holds {ln[68]!r}, the line tallies to "
                                           f"{checksum(ln)} (a mistyped or truncated line)")
    if l1[2:7] != l2[2:7]:
        raise ConfigError(where, name, f"catalogue numbers differ: line 1 has {l1[2:7]!r}, line 2 {l2[2:7]!r}")
    for k, c0, c1, what, pattern in _COLUMNS:
        text = (l1, l2)[k - 1][c0 - 1:c1]
        if not re.fullmatch(pattern, text):
            raise ConfigError(where, name, f"line {k}, columns {c0}-{c1} ({what}): not a TLE number: {text!r}")
    day = float(l1[20:32])
    checks = ((1.0 <= day < 367.0, 1, "21-32", "epoch day", f"{day:g}, expected 1 .. 366.99"),
              (float(l2[8:16]) <= 180.0, 2, "9-16", "inclination", f"{float(l2[8:16]):g} deg, expected 0 .. 180"),
              (float(l2[17:25]) < 360.0, 2, "18-25", "right ascension of the ascending node", f"{float(l2[17:25]):g} deg"),
              (float(l2[34:42]) < 360.0, 2, "35-42", "argument of perigee", f"{float(l2[34:42]):g} deg"),
              (float(l2[43:51]) < 360.0, 2, "44-51", "mean anomaly", f"{float(l2[43:51]):g} deg"),
              (float(l2[52:63]) > 0.0, 2, "53-63", "mean motion", f"{float(l2[52:63]):g} rev/day, expected > 0"))
    for ok, k, cols, what, got in checks:
        if not ok:
            raise ConfigError(where, name, f"line {k}, columns {cols} ({what}): out of range: {got}")
    sat = Satrec.twoline2rv(l1, l2, WGS72)
    if sat.error:
        raise ConfigError(where, name, f"SGP4 cannot start from this TLE (error {sat.error}: "
                                       f"{SGP4_ERRORS.get(sat.error, 'unknown')})")
    return TLE(l1, l2, title, sat)


def check_leo(tle: TLE, altitude_range: tuple[float, float], where="spacecraft parameters", name="tle") -> None:
    """ConfigError unless perigee and apogee lie within ``altitude_range`` (the LEO band magtune models).

    Parameters
    ----------
    tle : TLE
        The element set.
    altitude_range : (float, float)
        Lowest perigee and highest apogee altitude [m] above the equatorial radius.
    where : str
        File or context named in the error message.
    name : str
        Field named in the error message.

    Raises
    ------
    ConfigError
        Naming the mean motion (line 2, columns 53-63): perigee below the band (decayed or re-entering) or apogee above it.
    """
    lo, hi = altitude_range
    n, e = tle.revs_per_day, tle.eccentricity
    per, apo = tle.perigee_altitude, tle.apogee_altitude
    if per < lo:
        raise ConfigError(where, name, f"line 2, mean motion {n:.8g} rev/day, e = {e:.7f}: perigee at {per / 1e3:.0f} km, "
                                       f"below {lo / 1e3:g} km (decayed or re-entering within days): use a current TLE of a LEO orbit")
    if apo > hi:
        raise ConfigError(where, name, f"line 2, mean motion {n:.8g} rev/day, e = {e:.7f}: apogee at {apo / 1e3:.0f} km, "
                                       f"above {hi / 1e3:g} km: not a LEO orbit (magnetic control needs {lo / 1e3:g} .. "
                                       f"{hi / 1e3:g} km)")
