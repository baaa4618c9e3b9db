"""Low-precision solar position and cylindrical Earth shadow (Montenbruck & Gill 2000, 3.3.2, 3.4.2).

Accuracy of the solar position: ~0.1-1 arcmin in direction, ~1e-4 relative in distance
(M&G: "about 0.1-1%"), far better than the attitude-disturbance models that use it.
"""
from __future__ import annotations

import numpy as np

from .earth import JD_J2000, R_EARTH

AU = 149597870700.0  #: astronomical unit [m]
OBLIQUITY_J2000 = np.deg2rad(23.43929111)  #: obliquity of the ecliptic at J2000 [rad]
SOLAR_PRESSURE_1AU = 4.56e-6  #: solar radiation pressure at 1 AU, P = Phi/c = 1367/c [N/m^2] (M&G sec. 3.4)


def sun_position(jd, of_date: bool = True) -> np.ndarray:
    """Geocentric Sun position [m] in ECI (equator/equinox of date if ``of_date``, else EME2000).

    M&G sec. 3.3.2: M = 357.5256 + 35999.049 T [deg],
    lambda = 282.9400 + M + 6892" sin M + 72" sin 2M, r = (149.619 - 2.499 cos M - 0.021 cos 2M) 1e6 km,
    rotated from the ecliptic by -epsilon about X. ``of_date`` adds the general precession in
    longitude 1.3972 deg T (M&G sec. 3.3.2), matching the ECI-of-date of :mod:`earth`
    (the obliquity change, 47" per century, is neglected).
    """
    T = (np.asarray(jd, dtype=float) - JD_J2000) / 36525.0
    M = np.deg2rad(357.5256 + 35999.049 * T)
    lam = np.deg2rad(282.9400) + M + np.deg2rad((6892.0 * np.sin(M) + 72.0 * np.sin(2 * M)) / 3600.0)
    if of_date:
        lam = lam + np.deg2rad(1.3972) * T
    r = (149.619 - 2.499 * np.cos(M) - 0.021 * np.cos(2 * M)) * 1e9
    ce, se = np.cos(OBLIQUITY_J2000), np.sin(OBLIQUITY_J2000)
    return np.stack([r * np.cos(lam), r * np.sin(lam) * ce, r * np.sin(lam) * se], axis=-1)


def shadow_cylindrical(r_sat, r_sun) -> np.ndarray:
    """Illumination factor nu in {0, 1} of the cylindrical Earth-shadow model (M&G sec. 3.4.2).

    nu = 0 when the satellite is behind the Earth (r.s_hat < 0) and within R_EARTH of the
    Earth-Sun line; otherwise 1. Penumbra is ignored (a ~8 s transition at 450 km).
    """
    r = np.asarray(r_sat, dtype=float)
    s = np.asarray(r_sun, dtype=float)
    s_hat = s / np.linalg.norm(s, axis=-1, keepdims=True)
    proj = np.sum(r * s_hat, axis=-1)
    perp = np.linalg.norm(r - proj[..., None] * s_hat, axis=-1)
    return np.where((proj < 0) & (perp < R_EARTH), 0.0, 1.0)
