"""Spacecraft and orbit parameters (paper section 5): the schema of ``config/spacecraft.yaml``.

Parameter files use the standard ROS 2 layout ``node_name: {ros__parameters: {...}}``;
``/**`` applies to every node. Every loader error names the file, the field and what was
expected, so a user can fix the file without reading code.

The orbit is a first-class parameter set: a **circular** orbit (eccentricity 0; magtune's LTP
model of paper section 3 assumes a constant orbital rate) given by ``altitude`` (above the
JGM-3 equatorial radius; 150 km .. 2000 km), ``inclination`` (0 .. 180 deg), ``raan`` and
``arg_latitude`` at ``epoch`` (UTC, ISO 8601). The nominal period T (W0 = 2 pi/T of the design
model and of the controller's state) is *derived* from them, so no two parameters can disagree:

* ``period_model: keplerian`` (default): T = 2 pi sqrt(a^3/GM), the paper's choice (its
  5614.8 s at 450 km is the Keplerian period, to 0.4 s);
* ``period_model: j2_mean``: 2 pi / (mean orbital-frame rate of the J2-propagated orbit), the
  nominal period the full environment uses (:func:`magtune_core.env.orbit.mean_frame_period`;
  5611.2 s at 450 km/87 deg). Choose it when flying on IGRF along the real orbit: the
  fitted field's rate (``magtune fit-field``) is the same mean rate.

``orbit_period`` may still be given (older files, the paper's 5614.8 s): it is then used as T
but must lie within :data:`PERIOD_TOLERANCE` (0.5 %) of the Keplerian period of ``altitude``
- wider than the J2 mean-rate offset anywhere in 150-2000 km (0.05 % .. 0.31 %, largest for
equatorial orbits at 150 km) plus rounding, narrower than an altitude off by 23 km
(dT/T = 1.5 da/a = 0.022 % per km).

**Orbit from a TLE.** ``tle`` (the two lines, or a name line and the two lines) or ``tle_file`` (a
file holding them, relative to the spacecraft file) replaces the circular elements: giving
``altitude``, ``inclination``, ``raan`` or ``arg_latitude`` as well is an error, and so is giving
both ``tle`` and ``tle_file``. ``epoch`` is the simulation epoch and defaults to the TLE's; the
orbit starts from SGP4's state at it (:mod:`magtune_core.env.tle`) and is propagated by the J2
model like any other (docs/decisions.md: the measured difference from SGP4). The derived elements
describe that state: ``altitude`` is the mean-motion altitude ((GM/n^2)^(1/3) - R, n the SGP4 mean
motion, so the Keplerian period is 2 pi / n), inclination, RAAN and argument of latitude are the
osculating ones; ``eccentricity`` is the TLE's. A TLE more than :data:`~magtune_core.env.tle.MAX_AGE_DAYS`
from the simulation epoch gets a warning (:func:`tle_warning`). The design commands refuse an
eccentricity above :data:`ECCENTRICITY_MAX` (:func:`check_design_orbit`).
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field, replace
from datetime import datetime
from pathlib import Path

import numpy as np

from ..base.errors import ConfigError
from ..base.paramfile import read_ros_params, read_user_text
from ..base.schema import Field, parse, parse_value
from ..env.earth import R_EARTH, decimal_year, julian_date
from ..env.igrf import igrf_years
from ..env.orbit import (
    DEFAULT_EPOCH,
    OrbitConfig,
    argument_of_latitude,
    inclination,
    keplerian_period,
    mean_frame_period,
    raan,
    rotate_state,
)
from ..env.tle import MAX_AGE_DAYS, TLE, check_leo, parse_tle, split_lines
from ..onboard.params import SAMPLE_PERIOD
from .field import FIELD_MODELS, FourierField, paper_field

#: Altitudes [m] the circular-orbit model accepts: below 150 km the orbit decays within hours,
#: above 2000 km is outside LEO (field too weak for magnetic control, IGRF fit of degree 10 only).
ALTITUDE_RANGE = (150e3, 2000e3)
#: How the nominal period is derived from the orbit (module docstring).
PERIOD_MODELS = ("keplerian", "j2_mean")
#: Largest relative difference between an explicit ``orbit_period`` and the Keplerian period.
PERIOD_TOLERANCE = 5e-3
#: The circular orbit of a file without a TLE when it leaves an element out (the paper's, section 5).
CIRCULAR_DEFAULTS = {"altitude": 450e3, "inclination": 87.0, "raan": 0.0, "arg_latitude": 0.0}
#: Largest eccentricity the design commands accept (:func:`check_design_orbit`). The periodic LTP model
#: has a constant orbital rate W0 and a field periodic in W0 t. An orbit of eccentricity e turns its
#: orbital frame at |h|/r^2 = n (1 + e cos nu)^2 / (1 - e^2)^1.5, i.e. W0 (1 +- 2e), runs ahead of and
#: behind W0 t by up to 2e rad (the equation of the centre), and sees |b| ~ r^-3 swing by +-3e. At
#: e = 0.01: +-2 % of W0, +-1.15 deg of orbital position, +-3 % of |b|: an order of magnitude below the
#: longitude-dependent part of the field that the periodic model already leaves out (the 2-harmonic
#: fit of the paper's orbit: residual 9.8 uT RMS against 38.2 uT of field, 26 %, docs/field_fit.md).
#: The bound keeps the eccentricity's terms (3e) within a tenth of that residual (e <= 0.0087, rounded
#: to 0.01). LEO TLEs (e of 1e-4 .. a few 1e-3) pass.
ECCENTRICITY_MAX = 0.01
#: Spacecraft-file names of the elements a TLE replaces.
CIRCULAR_ELEMENTS = ("altitude", "inclination", "raan", "arg_latitude")


def parse_epoch(text: str, where="spacecraft parameters", name="epoch") -> datetime:
    """ISO 8601 UTC date/time -> naive datetime (UTC); ConfigError naming ``name`` otherwise.

    Parameters
    ----------
    text : str
        ISO 8601 date/time; a trailing "Z" or an offset is converted to UTC.
    where : str
        File or context named in the error message.
    name : str
        Field name named in the error message.

    Returns
    -------
    datetime
        The instant as a naive datetime in UTC.

    Raises
    ------
    ConfigError
        If ``text`` is not an ISO 8601 date/time, or is outside the field model's years (:func:`check_field_epoch`).
    """
    try:
        d = datetime.fromisoformat(str(text).replace("Z", "+00:00"))
    except ValueError:
        raise ConfigError(where, name, f"expected an ISO 8601 UTC date/time like 2027-01-01T00:00:00, got {text!r}") \
            from None
    if d.tzinfo is not None:  # express in UTC, drop the offset (the orbit code takes naive UTC)
        d = (d - d.utcoffset()).replace(tzinfo=None)
    return check_field_epoch(d, where, name)


def check_field_epoch(epoch: datetime, where="spacecraft parameters", name="epoch") -> datetime:
    """``epoch`` if the field model (IGRF-14) is defined there, else ConfigError naming ``name``: an epoch outside
    its years passed validation and ended a full-environment SIL run with a traceback after its nodes started.

    Parameters
    ----------
    epoch : datetime
        Naive UTC.
    where : str
        File or context named in the error message.
    name : str
        Field name named in the error message.

    Returns
    -------
    datetime
        ``epoch``, unchanged.

    Raises
    ------
    ConfigError
        If its decimal year is outside :func:`magtune_core.env.igrf.igrf_years` (1900-2030).
    """
    first, last = igrf_years()
    year = float(decimal_year(julian_date(epoch)))
    if not first <= year <= last:
        raise ConfigError(where, name, f"{epoch.isoformat()} is outside the years of the field model, IGRF-14 "
                                       f"({first:.0f}-01-01 .. {last:.0f}-01-01)")
    return epoch


def check_orbit(altitude: float, inclination_deg: float, where="command line") -> None:
    """ConfigError unless altitude [m] and inclination [deg] are within the bounds of the schema
    (:attr:`SpacecraftParams.FIELDS`: 150 km .. 2000 km, 0 .. 180 deg), for an orbit given as
    command-line options (``magtune fit-field``, in km: the message says km).

    Parameters
    ----------
    altitude : float
        Circular-orbit altitude [m].
    inclination_deg : float
        Orbit inclination [deg].
    where : str
        Context named in the error message.

    Raises
    ------
    ConfigError
        If the altitude is not finite or outside 150 .. 2000 km, or the inclination is outside 0 .. 180 deg.
    """
    fields = {f.name: f for f in SpacecraftParams.FIELDS}
    lo, hi = fields["altitude"].bounds
    if not (math.isfinite(altitude) and lo <= altitude <= hi):
        raise ConfigError(where, "altitude", f"expected {lo / 1e3:g} .. {hi / 1e3:g} km (circular LEO), "
                                             f"got {altitude / 1e3:g} km")
    parse_value(fields["inclination"], float(inclination_deg), where)


def check_inertia(inertia, where) -> None:
    """ConfigError unless the principal moments are those of a rigid body: each at most the sum
    of the other two (the triangle inequality; equality is a flat plate). A body with
    Ixx > Iyy + Izz does not exist, and its dynamics would be meaningless.

    Parameters
    ----------
    inertia : array_like (3,)
        Principal moments Ixx, Iyy, Izz [kg m^2].
    where : str
        File or context named in the error message.

    Raises
    ------
    ConfigError
        If a moment exceeds the sum of the other two (relative tolerance 1e-12).
    """
    m = [float(x) for x in inertia]
    for i, axis in enumerate("xyz"):
        others = m[(i + 1) % 3] + m[(i + 2) % 3]
        if m[i] > others * (1.0 + 1e-12):
            o1, o2 = "xyz"[(i + 1) % 3], "xyz"[(i + 2) % 3]
            raise ConfigError(where, "inertia", f"I{axis}{axis} = {m[i]:g} > I{o1}{o1} + I{o2}{o2} = {others:g}: not a rigid "
                                                "body (each principal moment must be at most the sum of the other two)")


def read_tle(v: dict, where, base_dir=None) -> tuple[TLE | None, str]:
    """The TLE of parsed spacecraft parameters ``v`` (``tle`` or ``tle_file``), checked, and the field that gave it.

    Parameters
    ----------
    v : dict
        Parsed spacecraft parameters (:func:`magtune_core.base.schema.parse` of :attr:`SpacecraftParams.FIELDS`).
    where : str or Path
        File or context named in error messages.
    base_dir : str or Path or None
        Directory of the spacecraft file, against which a relative ``tle_file`` is resolved; None: refused.

    Returns
    -------
    (TLE or None, str)
        The element set (None without one) and ``"tle"`` or ``"tle_file"`` ("" without one).

    Raises
    ------
    ConfigError
        If both ``tle`` and ``tle_file`` are given, the file cannot be read, a circular element is given
        too, or the TLE fails a check of :func:`magtune_core.env.tle.parse_tle` or
        :func:`magtune_core.env.tle.check_leo` (LEO: perigee and apogee in 150 .. 2000 km).
    """
    lines, path = tuple(v.get("tle") or ()), v.get("tle_file") or ""
    if lines and path:
        raise ConfigError(where, "tle_file", "given together with tle: keep one of them")
    if not lines and not path:
        return None, ""
    name = "tle" if lines else "tle_file"
    if path:
        f = Path(path)
        if not f.is_absolute():
            if base_dir is None:
                raise ConfigError(where, "tle_file", f"relative path {path!r} but the spacecraft file's directory is "
                                                     "unknown here (node parameters): give an absolute path, or the "
                                                     "lines in tle (magtune sil hands the nodes the lines)")
            f = Path(base_dir) / f
        try:
            lines = tuple(split_lines(read_user_text(f, "expected a TLE file: 2 lines, or a name line and 2 lines")))
        except ConfigError as exc:
            raise ConfigError(where, "tle_file", f"{f}: {exc.expected}") from None
        where = f"{where} (tle_file {f})"
    given = [k for k in CIRCULAR_ELEMENTS if v.get(k) is not None]
    if given:
        raise ConfigError(where, given[0], f"given together with {name}: the TLE gives the orbit; remove {given[0]} "
                                           f"(or {name})")
    tle = parse_tle(lines, where, name)
    check_leo(tle, ALTITUDE_RANGE, where, name)
    return tle, name


def _circular_orbit(v: dict, where) -> dict:
    """SpacecraftParams' orbit keywords of the circular elements (the paper's where unset)."""
    e = {k: (CIRCULAR_DEFAULTS[k] if v[k] is None else v[k]) for k in CIRCULAR_ELEMENTS}
    epoch = DEFAULT_EPOCH if v["epoch"] is None else parse_epoch(v["epoch"], where)
    return dict(altitude=e["altitude"], inclination_deg=e["inclination"], raan_deg=e["raan"],
                arg_lat_deg=e["arg_latitude"], epoch=epoch)


def _tle_orbit(tle: TLE, name: str, v: dict, where) -> dict:
    """SpacecraftParams' orbit keywords of a TLE: SGP4's state at the simulation epoch (the TLE's by default)
    and the elements that describe it (module docstring)."""
    epoch = check_field_epoch(tle.epoch, where, name) if v["epoch"] is None else parse_epoch(v["epoch"], where)
    r, vel = tle.state((epoch - tle.epoch).total_seconds(), where, name)
    return dict(altitude=tle.semi_major_axis - R_EARTH, inclination_deg=float(np.degrees(inclination(r, vel))),
                raan_deg=float(np.degrees(raan(r, vel)) % 360.0),
                arg_lat_deg=float(np.degrees(argument_of_latitude(r, vel))), epoch=epoch, tle=tle, tle_field=name,
                eccentricity=tle.eccentricity, state0=tuple(float(x) for x in np.concatenate([r, vel])))


def tle_warning(p) -> str | None:
    """The one-line warning for a TLE more than :data:`~magtune_core.env.tle.MAX_AGE_DAYS` from the simulation epoch.

    Parameters
    ----------
    p : SpacecraftParams
        Spacecraft parameters (with or without a TLE).

    Returns
    -------
    str or None
        ``field 'tle': ...`` naming the age and the fix; None without a TLE or for a fresh one.
    """
    if p.tle is None:
        return None
    age = (p.epoch - p.tle.epoch).total_seconds() / 86400.0
    if abs(age) <= MAX_AGE_DAYS:
        return None
    when = f"is {age:.1f} days old at" if age > 0 else f"lies {-age:.1f} days after"
    return (f"field '{p.tle_field}': the TLE of {p.tle.label} (epoch {p.tle.epoch.isoformat()}) {when} the "
            f"simulation epoch {p.epoch.isoformat()} (more than {MAX_AGE_DAYS:g} days: SGP4 errors grow by ~1-3 km "
            "per day); use a TLE from within a week of the epoch, or leave epoch out (the TLE's)")


def warn_tle(p, where) -> None:
    """Print :func:`tle_warning` (if any) on stderr: ``<where>: warning: ...``.

    Parameters
    ----------
    p : SpacecraftParams
        Spacecraft parameters.
    where : str or Path
        The spacecraft file, named in the line.
    """
    text = tle_warning(p)
    if text:
        print(f"{where}: warning: {text}", file=sys.stderr, flush=True)


def check_design_orbit(p, where) -> None:
    """ConfigError unless the orbit is one the periodic circular LTP model represents: eccentricity at most
    :data:`ECCENTRICITY_MAX` (its derivation is at the constant). For the design commands, before any work.

    Parameters
    ----------
    p : SpacecraftParams
        Spacecraft parameters.
    where : str or Path
        The spacecraft file, named in the message.

    Raises
    ------
    ConfigError
        Naming ``tle``/``tle_file`` when the TLE's eccentricity exceeds the bound.
    """
    if p.eccentricity > ECCENTRICITY_MAX:
        e = p.eccentricity
        raise ConfigError(where, p.tle_field or "tle", f"eccentricity {e:.4f} > {ECCENTRICITY_MAX:g}: the circular LTP "
                                                       f"model cannot represent this orbit (orbital rate W0 +-{200 * e:.0f} %, "
                                                       f"|b| +-{300 * e:.0f} %); design for a near-circular orbit "
                                                       f"(e <= {ECCENTRICITY_MAX:g}) and verify on this one with magtune sil/campaign")


def orbit_summary(p) -> str:
    """One line on the orbit a design runs on: the TLE's object, epoch, age, eccentricity, mean motion and period.

    Parameters
    ----------
    p : SpacecraftParams
        Spacecraft parameters.

    Returns
    -------
    str
        The line (for a circular orbit: altitude, inclination and period).
    """
    T = f"T = {p.orbit_period:.1f} s ({p.period_model})"
    if p.tle is None:
        return f"circular orbit {p.altitude / 1e3:g} km, {p.inclination_deg:g} deg, {T}"
    t = p.tle
    age = (p.epoch - t.epoch).total_seconds() / 86400.0
    return (f"orbit from the TLE of {t.label} (epoch {t.epoch.isoformat()}, age {age:.1f} days at the simulation epoch): "
            f"e = {t.eccentricity:.7f}, mean motion {t.revs_per_day:.8g} rev/day (mean altitude {p.altitude / 1e3:.1f} km, "
            f"perigee {t.perigee_altitude / 1e3:.1f} km, apogee {t.apogee_altitude / 1e3:.1f} km), i = {t.inclination_deg:.4f} deg, {T}")


@dataclass(frozen=True)
class SpacecraftParams:
    """Inertia, wheel and orbit data of paper section 5 (SI units): a circular orbit, or a TLE's (module docstring)."""

    inertia: np.ndarray = field(default_factory=lambda: np.array([35.0, 17.0, 25.0]))
    wheel_inertia: float = 0.01
    wheel_speed: float = -200.0
    orbit_period: float = 5614.8
    altitude: float = 450e3
    inclination_deg: float = 87.0
    raan_deg: float = 0.0
    arg_lat_deg: float = 0.0
    epoch: datetime = DEFAULT_EPOCH
    period_model: str = "keplerian"
    box_dims: np.ndarray = field(default_factory=lambda: np.array([0.6, 1.0, 0.8]))
    cp_offset: np.ndarray = field(default_factory=lambda: np.full(3, 0.05 / np.sqrt(3.0)))
    field_model: str = "eq26"
    constant_field: np.ndarray = field(default_factory=lambda: np.array([2e-5, 0.0, 1e-5]))
    #: the TLE the orbit comes from (None: the circular elements), the field that gave it (tle or
    #: tle_file), its mean eccentricity and SGP4's ECI state at ``epoch`` (6 floats [m, m/s])
    tle: TLE | None = None
    tle_field: str = ""
    eccentricity: float = 0.0
    state0: tuple | None = None

    #: The schema of ``config/spacecraft.yaml``: CLI and nodes (magtune_ros.params) declare and
    #: validate exactly these parameters. The physical data are required; the orbit (circular)
    #: and field model default to the paper's section 5; the period is derived (module docstring).
    FIELDS = (
        # bounds: physically possible values (a typo or a unit error falls outside): a 1 g cubesat
        # to a space station; wheels up to 1e4 rad/s; |b| at most 1e-3 T per axis (the geomagnetic
        # field is below 7e-5 T); altitude: ALTITUDE_RANGE
        Field("inertia", "float[]", "principal moments Ixx, Iyy, Izz [kg m^2]", size=3, positive=True,
              bounds=(1e-6, 1e8), unit="kg m^2"),
        Field("wheel_inertia", "float", "pitch wheel inertia J [kg m^2]", positive=True, bounds=(1e-9, 1e4),
              unit="kg m^2"),
        Field("wheel_speed", "float", "nominal wheel speed Wwheel [rad/s]", bounds=(-1e4, 1e4), unit="rad/s"),
        # the circular elements have no schema default: unset, they are the paper's (CIRCULAR_DEFAULTS) without
        # a TLE and must stay unset with one; a node sees the same (an unset parameter is left out)
        Field("altitude", "float", "circular-orbit altitude above the equatorial radius [m], 150 km .. 2000 km "
              "(default 450 km; not with a TLE)", None, positive=True, bounds=ALTITUDE_RANGE, unit="m"),
        Field("inclination", "float", "orbit inclination [deg], 0 .. 180 (default 87; not with a TLE)", None,
              bounds=(0.0, 180.0), unit="deg"),
        Field("raan", "float", "right ascension of the ascending node at epoch [deg] (default 0; not with a TLE)",
              None, bounds=(-360.0, 360.0), unit="deg"),
        Field("arg_latitude", "float", "argument of latitude at epoch [deg] (angle from the ascending node; "
              "default 0; not with a TLE)", None, bounds=(-360.0, 360.0), unit="deg"),
        Field("epoch", "str", "UTC epoch of the orbit and of IGRF, ISO 8601 (default "
              f"{DEFAULT_EPOCH.isoformat()}, with a TLE the TLE's epoch)", None),
        Field("tle", "str[]", "the orbit as a two-line element set: [line 1, line 2] or [name, line 1, line 2] "
              "(replaces altitude, inclination, raan, arg_latitude)", ()),
        Field("tle_file", "str", "file holding the TLE (2 lines, or a name line and 2 lines), relative to the "
              "spacecraft file; instead of tle", ""),
        Field("period_model", "str", "nominal period: keplerian (paper) or j2_mean (mean rate of the J2 orbit)",
              "keplerian", choices=PERIOD_MODELS),
        Field("orbit_period", "float", "nominal period T [s]; optional: derived from the orbit by period_model, "
              "if given it must agree with the Keplerian period within 0.5 %", None, positive=True,
              bounds=(1e3, 1e7), unit="s"),
        Field("box_dims", "float[]", "full environment: edge lengths of the drag/SRP box along body X, Y, Z [m]",
              (0.6, 1.0, 0.8), size=3, positive=True, bounds=(1e-3, 100.0), unit="m"),
        Field("cp_offset", "float[]", "full environment: centre of pressure minus centre of mass, body axes [m]",
              (0.05 / 3.0 ** 0.5,) * 3, size=3, bounds=(-10.0, 10.0), unit="m"),
        Field("field_model", "str", "geomagnetic field model in orbital axes", "eq26", choices=FIELD_MODELS),
        Field("constant_field", "float[]", "field [T] in orbital axes for field_model = constant",
              (2e-5, 0.0, 1e-5), size=3, bounds=(-1e-3, 1e-3), unit="T"),
    )

    @classmethod
    def from_mapping(cls, params: dict, where="spacecraft parameters", strict: bool = False,
                     base_dir=None) -> "SpacecraftParams":
        """Validate a parameter mapping (file or declared node parameters) against :attr:`FIELDS`.

        ``strict``: a key that is neither a field nor a node parameter
        (:data:`magtune_core.design.node_params.NODE_PARAMETERS`, derived from the nodes' schemas)
        is an error with a "did you mean" (the CLI reading ``config/spacecraft.yaml``).
        Raises ConfigError naming ``where``, the field and what was expected.

        Parameters
        ----------
        params : dict
            Parameter name -> value (the ROS 2 ``ros__parameters`` mapping).
        where : str
            File or context named in error messages.
        strict : bool
            Reject keys that are neither fields nor node parameters.
        base_dir : str or Path or None
            Directory a relative ``tle_file`` is found in (the spacecraft file's); None: a relative
            ``tle_file`` is an error (a node does not know its parameter file's directory).

        Returns
        -------
        SpacecraftParams
            The validated parameters, ``orbit_period`` derived by ``period_model`` (or the checked explicit value).

        Raises
        ------
        ConfigError
            If a field is missing, malformed or out of bounds (also unknown keys when ``strict``), the
            inertia is not a rigid body's, an explicit ``orbit_period`` is more than 0.5 % off the Keplerian
            period, or the TLE is bad or given with the circular elements (:func:`read_tle`).
        """
        from .node_params import NODE_PARAMETERS  # below law/model, which import this module

        v = parse(params, cls.FIELDS, where, allowed=NODE_PARAMETERS if strict else None)
        for key in ("tle", "tle_file") if strict else ():  # a user's file: given but empty flew the circular orbit
            if key in params and not len(params[key]):  # (a node's declared parameters hold the empty defaults)
                raise ConfigError(where, key, "empty: give the element set, or remove the key for the circular orbit "
                                              "of altitude, inclination and raan")
        check_inertia(v["inertia"], where)
        tle, name = read_tle(v, where, base_dir)
        orbit = _circular_orbit(v, where) if tle is None else _tle_orbit(tle, name, v, where)
        p = cls(inertia=v["inertia"], wheel_inertia=v["wheel_inertia"], wheel_speed=v["wheel_speed"],
                period_model=v["period_model"], box_dims=v["box_dims"], cp_offset=v["cp_offset"],
                field_model=v["field_model"], constant_field=v["constant_field"], **orbit)
        kep = keplerian_period(p.altitude)
        T = v["orbit_period"]
        if T is None:
            T = kep if p.period_model == "keplerian" else mean_frame_period(p.orbit_config())
        elif abs(T - kep) > PERIOD_TOLERANCE * kep:
            raise ConfigError(where, "orbit_period", f"{T:g} s contradicts altitude {p.altitude / 1e3:g} km "
                                                     f"(Keplerian period {kep:.1f} s, tolerance 0.5 %): remove "
                                                     "orbit_period (it is derived) or fix altitude")
        return replace(p, orbit_period=float(T))

    def orbit_config(self, **overrides) -> OrbitConfig:
        """The circular orbit as :class:`magtune_core.env.orbit.OrbitConfig` (``overrides``: its fields).

        Parameters
        ----------
        **overrides : dict
            OrbitConfig fields replacing this orbit's values (None values are ignored).

        Returns
        -------
        OrbitConfig
            Altitude, inclination, RAAN, argument of latitude and epoch of this orbit, with the overrides.
            An orbit from a TLE carries SGP4's state at the epoch (``state0``); a RAAN or argument of
            latitude override turns that state (:func:`~magtune_core.env.orbit.rotate_state`: the same
            orbit moved along and about the pole), an epoch override only moves the date, as for a
            circular orbit (the state is not propagated by SGP4 to it).

        Raises
        ------
        ValueError
            If the altitude or the inclination of an orbit from a TLE is overridden.
        """
        kw = dict(altitude=float(self.altitude), inclination_deg=float(self.inclination_deg),
                  raan_deg=float(self.raan_deg), arg_lat_deg=float(self.arg_lat_deg), epoch=self.epoch)
        kw.update({k: v for k, v in overrides.items() if v is not None})
        if self.state0 is not None:
            if kw["altitude"] != self.altitude or kw["inclination_deg"] != self.inclination_deg:
                raise ValueError("the orbit of a TLE has its own altitude and inclination: override only "
                                 "raan_deg, arg_lat_deg, epoch")
            d_raan, d_u = kw["raan_deg"] - float(self.raan_deg), kw["arg_lat_deg"] - float(self.arg_lat_deg)
            kw["state0"] = self.state0 if d_raan == 0.0 and d_u == 0.0 else rotate_state(self.state0, d_raan, d_u)
        return OrbitConfig(**kw)

    @property
    def orbit_rate(self) -> float:
        """W0 = 2 pi / T [rad/s].

        Returns
        -------
        float
            Orbital rate [rad/s] of the nominal period ``orbit_period``.
        """
        return 2.0 * np.pi / self.orbit_period

    @property
    def wheel_momentum(self) -> np.ndarray:
        """Wheel angular momentum in body axes, h = [0, 0, -J Wwheel] (SPEC.md sign check).

        Returns
        -------
        ndarray (3,)
            h [N m s] in body axes.
        """
        return np.array([0.0, 0.0, -self.wheel_inertia * self.wheel_speed])

    @property
    def nutation_period(self) -> float:
        """Nutation period 2 pi sqrt(Ixx Iyy) / h [s] of the momentum-biased body (wheel momentum
        h = J |Wwheel| along the pitch axis, transverse axes x, y); inf without wheel momentum.
        The fastest natural motion of the attitude: a sample period must resolve it.

        Returns
        -------
        float
            Nutation period [s]; inf when the wheel momentum is zero.
        """
        h = abs(self.wheel_inertia * self.wheel_speed)
        return float(2.0 * np.pi * np.sqrt(self.inertia[0] * self.inertia[1]) / h) if h > 0 else float("inf")

    def field(self, model: str | None = None) -> FourierField:
        """The orbital-axes field model b_orb(t) (paper eq. 26 by default; ``model`` overrides ``field_model``).

        Parameters
        ----------
        model : str or None
            Field model name (:data:`~magtune_core.design.field.FIELD_MODELS`); None: ``field_model``.

        Returns
        -------
        FourierField
            The field at this orbit's rate (``constant_field`` for the constant model).
        """
        return paper_field(self.orbit_rate, model or self.field_model, self.constant_field)


def check_sample_period(ts: float, p: SpacecraftParams, where="ts") -> None:
    """ConfigError unless ``0 < ts < nutation period / 2`` (Nyquist: the sampled controller must
    resolve the nutation; beyond it the loop cannot damp it and RK4 at 2 sub-steps goes unstable,
    e.g. ts = 100 s for the paper's spacecraft, whose nutation period is 76.6 s).

    Parameters
    ----------
    ts : float
        Sample period [s] of the controller.
    p : SpacecraftParams
        Spacecraft whose nutation period bounds ``ts``.
    where : str
        Context named in the error message.

    Raises
    ------
    ConfigError
        If ``ts`` is not a positive finite number, is outside the bounds of the onboard ``SAMPLE_PERIOD``
        parameter, or is at least half the nutation period.
    """
    if not (isinstance(ts, (int, float)) and np.isfinite(ts) and ts > 0):
        raise ConfigError(where, None, f"expected a positive finite sample period in s, got {ts!r}")
    lo, hi = SAMPLE_PERIOD.bounds
    if not lo <= ts <= hi:
        raise ConfigError(where, None, f"expected a sample period in [{lo:g}, {hi:g}] s, got {ts:g}")
    limit = p.nutation_period / 2.0
    if ts >= limit:
        raise ConfigError(where, None, f"sample period {ts:g} s does not resolve the nutation period "
                                       f"{p.nutation_period:.1f} s; use ts < {limit:.1f} s")


def load_spacecraft(path, warn: bool = True) -> SpacecraftParams:
    """Read ``config/spacecraft.yaml`` (every node section merged) into SpacecraftParams.

    Parameters
    ----------
    path : str or Path
        ROS 2 parameter file.
    warn : bool
        Print the stale-TLE warning (:func:`warn_tle`); False where a command loads the file again
        (a worker's job) after its front end has.

    Returns
    -------
    SpacecraftParams
        The validated parameters (strict: unknown keys are errors); a relative ``tle_file`` is found
        beside ``path``.
    """
    p = SpacecraftParams.from_mapping(read_ros_params(path), path, strict=True, base_dir=Path(path).parent)
    if warn:
        warn_tle(p, path)
    return p
