"""Earth constants, time scales and the Earth-fixed frame used by the simulation environment.

Conventions (documented simplifications, adequate for attitude-disturbance modelling):

* **ECI** is the mean equator and equinox *of the epoch* (a quasi-inertial frame). Precession
  and nutation during a simulation (< 0.01 deg over a month) are neglected, and so is the
  difference between the frame of the epoch and EME2000 when positions are compared with
  external ephemerides (0.36 deg for 2026).
* **ECEF** is obtained from ECI by a single rotation about Z by the Greenwich mean sidereal
  angle (IAU 1982 GMST expression, linear part; Montenbruck & Gill 2000, ch. 5). Polar motion is neglected and
  UT1 = UTC (|UT1-UTC| < 0.9 s, i.e. < 0.004 deg of Earth rotation).
* Time arguments: ``jd`` is a Julian date in UTC (also used as TT for the Sun, an error of 69 s,
  negligible for the low-precision solar position).

Constants: JGM-3 gravity model (Tapley et al. 1996, as tabulated in Montenbruck & Gill 2000,
Table 3.3; the paper's simulation uses JGM-3), WGS-84 ellipsoid.
"""
from __future__ import annotations

from datetime import datetime, timezone

import numpy as np

GM_EARTH = 3.986004415e14  #: JGM-3 gravitational parameter [m^3/s^2]
R_EARTH = 6378.1363e3  #: JGM-3 reference radius [m]
#: JGM-3 fully normalized zonal coefficients (Tapley et al. 1996, as tabulated in Montenbruck & Gill 2000, ch. 3)
C20_NORM, C30_NORM, C40_NORM = -4.841653717e-4, 0.9571612071e-6, 0.5399658667e-6
#: un-normalized zonal harmonics J_n = -sqrt(2n+1) * C_n0(normalized)
J2 = -np.sqrt(5.0) * C20_NORM  # 1.0826e-3
J3 = -np.sqrt(7.0) * C30_NORM  # -2.5324e-6
J4 = -3.0 * C40_NORM  # -1.6199e-6
OMEGA_EARTH = 7.2921158553e-5  #: Earth rotation rate [rad/s] (IERS)
F_WGS84 = 1.0 / 298.257223563  #: WGS-84 flattening
R_WGS84 = 6378.137e3  #: WGS-84 equatorial radius [m]

JD_J2000 = 2451545.0
SECONDS_PER_DAY = 86400.0


def julian_date(epoch) -> float:
    """Julian date of a ``datetime`` (naive = UTC) or pass-through of a float JD."""
    if isinstance(epoch, datetime):
        if epoch.tzinfo is not None:
            epoch = epoch.astimezone(timezone.utc).replace(tzinfo=None)
        delta = epoch - datetime(2000, 1, 1, 12, 0, 0)
        return JD_J2000 + delta.days + (delta.seconds + delta.microseconds * 1e-6) / SECONDS_PER_DAY
    return float(epoch)


def decimal_year(jd) -> np.ndarray:
    """Decimal year of a Julian date (Julian years of 365.25 d from J2000.0), as IGRF uses."""
    return 2000.0 + (np.asarray(jd, dtype=float) - JD_J2000) / 365.25


def gmst(jd) -> np.ndarray:
    """Greenwich mean sidereal angle [rad] at UT1 Julian date(s) ``jd``.

    IAU 1982 expression (Aoki et al. 1982; Montenbruck & Gill 2000, ch. 5) without the T^2, T^3 terms (< 0.1 arcsec per century
    squared): GMST = 280.4606 deg + 360.9856473 deg * (JD - 2451545.0).
    """
    d = np.asarray(jd, dtype=float) - JD_J2000
    return np.mod(np.deg2rad(280.46061837 + 360.98564736629 * d), 2.0 * np.pi)


def rot_z(angle) -> np.ndarray:
    """Frame rotation R_z(angle) (passive convention: coordinates in the rotated frame)."""
    a = np.asarray(angle, dtype=float)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 0, 0], R[..., 0, 1] = c, s
    R[..., 1, 0], R[..., 1, 1] = -s, c
    R[..., 2, 2] = 1.0
    return R


def eci_to_ecef(jd) -> np.ndarray:
    """Rotation matrix ECI -> ECEF, R_z(GMST) (no precession/nutation/polar motion)."""
    return rot_z(gmst(jd))


def geodetic_height(r_ecef) -> np.ndarray:
    """WGS-84 geodetic height [m] of ECEF (or ECI: height is rotation invariant about Z) positions.

    Bowring's closed form with one Newton refinement; accurate to < 1 mm in low Earth orbit.
    """
    r = np.asarray(r_ecef, dtype=float)
    a, f = R_WGS84, F_WGS84
    b = a * (1.0 - f)
    e2 = f * (2.0 - f)
    ep2 = e2 / (1.0 - e2)
    p = np.hypot(r[..., 0], r[..., 1])
    z = r[..., 2]
    theta = np.arctan2(z * a, p * b)
    lat = np.arctan2(z + ep2 * b * np.sin(theta) ** 3, p - e2 * a * np.cos(theta) ** 3)
    for _ in range(2):  # fixed-point refinement of the latitude
        N = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
        h = np.where(np.abs(np.cos(lat)) > 1e-8, p / np.maximum(np.cos(lat), 1e-300) - N,
                     np.abs(z) - b)
        lat = np.arctan2(z, p * (1.0 - e2 * N / (N + h)))
    N = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    return np.where(np.abs(np.cos(lat)) > 1e-8, p / np.maximum(np.cos(lat), 1e-300) - N,
                    np.abs(z) - b)
