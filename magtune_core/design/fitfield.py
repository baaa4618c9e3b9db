"""Fit a periodic design-model field b(t) (orbital axes) to IGRF along the real orbit.

``magtune fit-field --altitude 450 --inclination 87 [--harmonics 2] --out config/field_model.yaml``
(the command lives in :mod:`magtune_core.cli.fit_field`).

Method: propagate the J2 orbit of :mod:`magtune_core.env.orbit` for ``days`` days (default 3: ~46 orbits, the
Earth turns under the orbit 3 times, so the fit averages over longitude), sample the IGRF-14
field (degree 10) in orbital axes every ``step`` seconds, and fit by linear least squares

    b(u) = mean + sum_{k=1..H} [cos_k cos(k u) + sin_k sin(k u)]

against the argument of latitude u (angle from the ascending node). With t counted from an
ascending-node crossing, u = W t, W the mean nodal rate measured from the samples, so the result
is a :class:`magtune_core.design.field.FourierField` with ``omega = W`` - the same form as the paper's
eq. (26) (whose t = 0 is thus read as the ascending node). The longitude-dependent part of the
field (tilted dipole, higher degrees) is what the periodic model cannot represent: it is the fit
residual, reported as RMS per axis.

Output file (ROS 2 parameter layout, loadable by :func:`load_field_model` and by any node)::

    /**:
      ros__parameters:
        field_fourier_omega: 0.00111...          # rad/s
        field_fourier_harmonics: 2
        field_fourier_mean: [bx, by, bz]         # T
        field_fourier_cos: [c1x, c1y, c1z, c2x, ...]   # T, row-major (harmonic k, axis)
        field_fourier_sin: [s1x, s1y, s1z, s2x, ...]   # T
        field_fit_rms: [rx, ry, rz]              # T, residual RMS per axis
        field_fit_*: provenance (altitude, inclination, IGRF degree, epoch, days, step)

ROS 2 parameters cannot hold nested lists, hence the flattened (H*3) coefficient arrays.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..base.atomic import atomic_write
from ..base.errors import ConfigError
from ..base.paramfile import read_ros_params
from ..base.schema import Field, parse
from ..env.igrf import IGRF
from ..env.orbit import DEFAULT_EPOCH, Orbit, OrbitConfig, argument_of_latitude, eci_to_orbital
from .field import FourierField
from .params import PERIOD_TOLERANCE


@dataclass(frozen=True)
class FitReport:
    """Quality of a periodic fit: residual RMS and max per orbital axis [T], over the samples."""

    rms: np.ndarray
    max_abs: np.ndarray
    field_rms: np.ndarray  #: RMS of the IGRF samples themselves per axis [T]
    n_samples: int
    days: float
    omega: float
    harmonics: int

    @property
    def rms_total(self) -> float:
        """RMS of the fit residual over the three axes [T].

        Returns
        -------
        float
            sqrt(sum of the per-axis residual RMS squared) [T].
        """
        return float(np.sqrt(np.sum(self.rms**2)))

    def markdown(self) -> str:
        """The fit report as a markdown table (per-axis IGRF RMS, residual RMS and maximum, uT).

        Returns
        -------
        str
            Header, separator and one row per axis X, Y, Z, values in uT.
        """
        ax = "XYZ"
        rows = ["| axis | IGRF RMS [uT] | fit residual RMS [uT] | max residual [uT] |", "|---|---|---|---|"]
        for i in range(3):
            rows.append(f"| {ax[i]} | {self.field_rms[i] * 1e6:.2f} | {self.rms[i] * 1e6:.2f} | {self.max_abs[i] * 1e6:.2f} |")
        return "\n".join(rows)


def sample_igrf_along_orbit(orbit_cfg: OrbitConfig, days: float = 3.0, step: float = 20.0, degree: int = 10):
    """(t [s], u [rad], b_orbital [T] (N, 3)) of IGRF along the propagated orbit.

    Parameters
    ----------
    orbit_cfg : OrbitConfig
        Orbit (and epoch) to propagate with J2.
    days : float
        Length of the sampled arc [days].
    step : float
        Sample spacing [s].
    degree : int
        IGRF truncation degree.

    Returns
    -------
    t : ndarray (N,)
        Sample times [s] from the epoch.
    u : ndarray (N,)
        Argument of latitude [rad] at each sample.
    b_orb : ndarray (N, 3)
        IGRF field [T] in orbital axes.
    """
    t = np.arange(0.0, days * 86400.0 + 0.5 * step, step)
    orbit = Orbit(orbit_cfg, duration=float(t[-1]) + step)
    r, v = orbit.state(t)
    igrf = IGRF(orbit.jd0, degree)
    b_eci = igrf.eci(r, orbit.jd(t))
    b_orb = np.einsum("nij,nj->ni", eci_to_orbital(r, v), b_eci)
    return t, argument_of_latitude(r, v), b_orb


def fit_fourier(u, b, harmonics: int):
    """Least-squares (mean (3,), cos (H, 3), sin (H, 3), residual (N, 3)) of b(u).

    Parameters
    ----------
    u : array_like (N,)
        Argument of latitude [rad] of each sample.
    b : ndarray (N, 3)
        Field samples [T].
    harmonics : int
        Number H of harmonics of u fitted.

    Returns
    -------
    mean : ndarray (3,)
        Constant term [T].
    cos, sin : ndarray (H, 3)
        Coefficients [T] of cos(k u) and sin(k u), row k-1 for harmonic k.
    residual : ndarray (N, 3)
        b minus the fit [T].
    """
    u = np.asarray(u, dtype=float)
    k = np.arange(1, harmonics + 1)
    A = np.hstack([np.ones((u.size, 1)), np.cos(np.outer(u, k)), np.sin(np.outer(u, k))])
    coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    return coef[0], coef[1:harmonics + 1], coef[harmonics + 1:], b - A @ coef


def fit_field(altitude: float = 450e3, inclination_deg: float = 87.0, harmonics: int = 2, days: float = 3.0,
              step: float = 20.0, degree: int = 10, epoch=DEFAULT_EPOCH, raan_deg: float = 0.0):
    """Fit IGRF along the orbit; returns (FourierField with omega = mean nodal rate, FitReport).

    Parameters
    ----------
    altitude : float
        Circular-orbit altitude [m].
    inclination_deg : float
        Inclination [deg].
    harmonics : int
        Number of harmonics fitted (>= 1).
    days : float
        Length of the sampled arc [days].
    step : float
        Sample spacing [s].
    degree : int
        IGRF truncation degree.
    epoch : datetime
        UTC epoch of the orbit and of IGRF.
    raan_deg : float
        Right ascension of the ascending node [deg].

    Returns
    -------
    field : FourierField
        The fitted field, omega the mean nodal rate [rad/s], named after altitude, inclination and H.
    report : FitReport
        Residual and field RMS per axis, residual maximum, samples, days, omega, harmonics.

    Raises
    ------
    ValueError
        If ``harmonics`` < 1.
    """
    cfg = OrbitConfig(altitude=altitude, inclination_deg=inclination_deg, raan_deg=raan_deg, epoch=epoch)
    return fit_field_orbit(cfg, harmonics, days, step, degree)


def fit_field_orbit(orbit: OrbitConfig, harmonics: int = 2, days: float = 3.0, step: float = 20.0, degree: int = 10):
    """Fit b(u) to IGRF sampled along ``orbit`` (any :class:`OrbitConfig`: circular, or a TLE's state,
    :meth:`magtune_core.design.params.SpacecraftParams.orbit_config`), as :func:`fit_field`.

    Parameters
    ----------
    orbit : OrbitConfig
        Orbit and epoch; propagated with J2 at rtol 1e-10, atol 1 mm (its own tolerances are replaced).
    harmonics : int
        Harmonics of the orbital rate.
    days : float
        Length of the sampled arc [days].
    step : float
        Sampling step [s].
    degree : int
        IGRF degree.

    Returns
    -------
    (FourierField, FitReport)
        The fitted field (rate: the measured mean nodal rate) and its residual report.

    Raises
    ------
    ValueError
        If ``harmonics`` < 1.
    """
    if harmonics < 1:
        raise ValueError("harmonics must be >= 1")
    cfg = replace(orbit, rtol=1e-10, atol=1e-3)
    t, u, b = sample_igrf_along_orbit(cfg, days, step, degree)
    omega = float(np.polyfit(t, np.unwrap(u), 1)[0])
    mean, cos, sin, res = fit_fourier(u, b, harmonics)
    report = FitReport(rms=np.sqrt(np.mean(res**2, axis=0)), max_abs=np.max(np.abs(res), axis=0),
                       field_rms=np.sqrt(np.mean(b**2, axis=0)), n_samples=t.size, days=days, omega=omega,
                       harmonics=harmonics)
    name = f"igrf_fit_{cfg.altitude / 1e3:g}km_{cfg.inclination_deg:g}deg_h{harmonics}"
    return FourierField(omega, mean=mean, cos=cos, sin=sin, name=name), report


def _fmt(values) -> str:
    return "[" + ", ".join(f"{float(x):.6e}" for x in np.ravel(values)) + "]"


def write_field_model(path, field: FourierField, report: FitReport, meta: dict) -> None:
    """Write the fitted field as a ROS 2 parameter file (layout in the module docstring).

    Parameters
    ----------
    path : str or Path
        Output file (parent directories are created; written atomically).
    field : FourierField
        Fitted field.
    report : FitReport
        Fit quality (its residual RMS is written).
    meta : dict
        Provenance written as ``field_fit_<key>`` parameters.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [
        "# Periodic geomagnetic field model in orbital axes (X nadir, Y along-track, Z = -orbit normal),",
        "# b(t) = mean + sum_k cos_k cos(k omega t) + sin_k sin(k omega t), t from an ascending-node crossing.",
        "# Least-squares fit of IGRF-14 along the J2 orbit: `magtune fit-field` (magtune_core/design/fitfield.py).",
        f"# Residual RMS per axis [uT]: {', '.join(f'{x * 1e6:.2f}' for x in report.rms)}",
        "/**:",
        "  ros__parameters:",
        f"    field_fourier_omega: {field.omega:.12e}   # mean nodal rate [rad/s] (period {field.period:.1f} s)",
        f"    field_fourier_harmonics: {field.cos.shape[0]}",
        f"    field_fourier_mean: {_fmt(field.mean)}   # [T]",
        f"    field_fourier_cos: {_fmt(field.cos)}   # [T], row-major (harmonic, axis)",
        f"    field_fourier_sin: {_fmt(field.sin)}   # [T], row-major (harmonic, axis)",
        f"    field_fit_rms: {_fmt(report.rms)}   # [T]",
    ]
    for key, val in meta.items():
        lines.append(f"    field_fit_{key}: {val!r}" if isinstance(val, str) else f"    field_fit_{key}: {val}")
    atomic_write(path, "\n".join(lines) + "\n")


#: The schema of a field-model file (``magtune fit-field`` output); ``field_fit_*`` is provenance.
FIELD_MODEL_FIELDS = (
    Field("field_fourier_omega", "float", "fundamental rate omega [rad/s]", positive=True),
    Field("field_fourier_harmonics", "int", "number of harmonics H", positive=True),
    Field("field_fourier_mean", "float[]", "mean field [T] in orbital axes", size=3),
)


def load_field_model(path, with_meta: bool = False):
    """Read a file written by :func:`write_field_model` back into a FourierField.

    Any number of harmonics; the coefficients must be finite, no axis may be identically zero
    (zero mean and zero amplitude: a fit that failed or a hand-edited file) and |b(t)| must stay
    > 1 nT over the period (the projection law divides by |b|^2). ConfigError otherwise, naming
    the field. ``with_meta``: also return the ``field_fit_*`` provenance as a dict (keys without prefix).

    Parameters
    ----------
    path : str or Path
        Field-model file.
    with_meta : bool
        Also return the provenance.

    Returns
    -------
    FourierField or (FourierField, dict)
        The field (named ``file:<name>``), and with ``with_meta`` the provenance dict.

    Raises
    ------
    ConfigError
        If a field is missing or invalid, or :func:`check_field` rejects the field.
    """
    p = read_ros_params(path)
    v = parse(p, FIELD_MODEL_FIELDS, path)
    H = v["field_fourier_harmonics"]  # the coefficient lists' size depends on it
    c = parse(p, [Field(name, "float[]", f"{3 * H} coefficients [T], row-major (harmonic, axis)", size=3 * H)
                  for name in ("field_fourier_cos", "field_fourier_sin")], path)
    field = FourierField(v["field_fourier_omega"], mean=v["field_fourier_mean"],
                         cos=c["field_fourier_cos"].reshape(H, 3), sin=c["field_fourier_sin"].reshape(H, 3),
                         name=f"file:{Path(path).name}")
    check_field(field, path)
    if with_meta:
        return field, {k[len("field_fit_"):]: val for k, val in p.items() if k.startswith("field_fit_")}
    return field


def check_field(field: FourierField, where) -> None:
    """ConfigError if an axis of ``field`` is identically zero or |b(t)| gets below 1 nT (see load_field_model).

    Parameters
    ----------
    field : FourierField
        Field to check (|b| on 4096 points of a period).
    where : str or Path
        File or context named in the error message.

    Raises
    ------
    ConfigError
        If an axis has zero mean and zero harmonics, or min |b(t)| is not above 1e-9 T.
    """
    for i, axis in enumerate("xyz"):
        if field.mean[i] == 0.0 and not np.any(field.cos[:, i]) and not np.any(field.sin[:, i]):
            raise ConfigError(where, "field_fourier_mean", f"the {axis} component is identically zero (zero mean and "
                                                           "zero amplitude): refit with magtune fit-field")
    t = np.arange(4096) * field.period / 4096
    bmin = float(np.min(np.linalg.norm(field(t), axis=-1)))
    if not bmin > 1e-9:
        raise ConfigError(where, "field_fourier_mean", f"|b(t)| falls to {bmin:.3g} T (< 1 nT): the projection law "
                                                       "divides by |b|^2; refit with magtune fit-field")


def field_for_spacecraft(path, params, where=None) -> FourierField:
    """The field file ``path`` as the design field of spacecraft ``params`` (a SpacecraftParams).

    The fit must be for this orbit: fundamental rate within ``PERIOD_TOLERANCE`` (0.5 %) of
    2 pi / orbit_period, and, when the file records them, altitude within 1 km and inclination
    within 0.5 deg of the spacecraft's. ConfigError naming the field otherwise.

    Parameters
    ----------
    path : str or Path
        Field-model file (``magtune fit-field`` output).
    params : SpacecraftParams
        Spacecraft whose orbit the fit must match.
    where : str or None
        Context named in error messages; None: ``path``.

    Returns
    -------
    FourierField
        The file's field.

    Raises
    ------
    ConfigError
        If the file is invalid, its rate is more than 0.5 % off 2 pi / orbit_period, or its recorded altitude
        (inclination) differs by more than 1 km (0.5 deg).
    """
    field, meta = load_field_model(path, with_meta=True)
    where = where or path
    w0 = 2.0 * np.pi / params.orbit_period
    if abs(field.omega - w0) > PERIOD_TOLERANCE * w0:
        raise ConfigError(where, "field_fourier_omega", f"field period {field.period:.1f} s does not match the orbit "
                                                        f"period {params.orbit_period:.1f} s of the spacecraft file: "
                                                        "fit the field for this orbit (magtune fit-field --altitude ...)")
    alt, inc = meta.get("altitude"), meta.get("inclination")
    if isinstance(alt, (int, float)) and abs(alt - params.altitude) > 1e3:
        raise ConfigError(where, "field_fit_altitude", f"fit for {alt / 1e3:g} km, the spacecraft flies at "
                                                       f"{params.altitude / 1e3:g} km: refit with magtune fit-field")
    if isinstance(inc, (int, float)) and abs(inc - params.inclination_deg) > 0.5:
        raise ConfigError(where, "field_fit_inclination", f"fit for {inc:g} deg, the spacecraft's inclination is "
                                                          f"{params.inclination_deg:g} deg: refit with magtune fit-field")
    return field
