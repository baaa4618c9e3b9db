"""Harris-Priester atmospheric density and the aerodynamic drag force/torque on a box.

Density: modified Harris-Priester model as given by Montenbruck & Gill (2000), section 3.5
(Harris-Priester coefficient table; mean solar activity, 100-1000 km): exponential interpolation of the antapex and
apex densities between tabulated heights and the diurnal bulge

    rho = rho_min + (rho_max - rho_min) cos^n(psi/2),

psi the angle between the satellite position and the bulge apex, which lags the Sun by 30 deg
in right ascension (at the Sun's declination); n = 2 for low and n = 6 for near-polar orbits
(default here: 6, for the 87 deg orbit). Height is WGS-84 geodetic.

Drag (flat-plate, free-molecular, M&G sec. 3.5 applied per face): each face with outward normal n and
area A, facing the relative wind (cos theta = n.v_hat > 0), takes
F = -1/2 rho Cd A cos(theta) |v_r|^2 v_hat, applied at its centroid; v_r = v - w_E x r is the
velocity relative to the co-rotating atmosphere. Face shadowing is irrelevant for a convex box.
"""
from __future__ import annotations

import numpy as np

from ..base.rotations import cross
from .earth import OMEGA_EARTH, geodetic_height

#: heights [km] and min/max densities [g/km^3] of M&G sec. 3.5 (Harris-Priester, mean solar activity)
HP_HEIGHT_KM = np.array([
    100.0, 120.0, 130.0, 140.0, 150.0, 160.0, 170.0, 180.0, 190.0, 200.0,
    210.0, 220.0, 230.0, 240.0, 250.0, 260.0, 270.0, 280.0, 290.0, 300.0,
    320.0, 340.0, 360.0, 380.0, 400.0, 420.0, 440.0, 460.0, 480.0, 500.0,
    520.0, 540.0, 560.0, 580.0, 600.0, 620.0, 640.0, 660.0, 680.0, 700.0,
    720.0, 740.0, 760.0, 780.0, 800.0, 840.0, 880.0, 920.0, 960.0, 1000.0])
HP_RHO_MIN = np.array([
    4.974e+05, 2.490e+04, 8.377e+03, 3.899e+03, 2.122e+03, 1.263e+03,
    8.008e+02, 5.283e+02, 3.617e+02, 2.557e+02, 1.839e+02, 1.341e+02,
    9.949e+01, 7.488e+01, 5.709e+01, 4.403e+01, 3.430e+01, 2.697e+01,
    2.139e+01, 1.708e+01, 1.099e+01, 7.214e+00, 4.824e+00, 3.274e+00,
    2.249e+00, 1.558e+00, 1.091e+00, 7.701e-01, 5.474e-01, 3.916e-01,
    2.819e-01, 2.042e-01, 1.488e-01, 1.092e-01, 8.070e-02, 6.012e-02,
    4.519e-02, 3.430e-02, 2.632e-02, 2.043e-02, 1.607e-02, 1.281e-02,
    1.036e-02, 8.496e-03, 7.069e-03, 4.680e-03, 3.200e-03, 2.210e-03,
    1.560e-03, 1.150e-03])
HP_RHO_MAX = np.array([
    4.974e+05, 2.490e+04, 8.710e+03, 4.059e+03, 2.215e+03, 1.344e+03,
    8.758e+02, 6.010e+02, 4.297e+02, 3.162e+02, 2.396e+02, 1.853e+02,
    1.455e+02, 1.157e+02, 9.308e+01, 7.555e+01, 6.182e+01, 5.095e+01,
    4.226e+01, 3.526e+01, 2.511e+01, 1.819e+01, 1.337e+01, 9.955e+00,
    7.492e+00, 5.684e+00, 4.355e+00, 3.362e+00, 2.612e+00, 2.042e+00,
    1.605e+00, 1.267e+00, 1.005e+00, 7.997e-01, 6.390e-01, 5.123e-01,
    4.121e-01, 3.325e-01, 2.691e-01, 2.185e-01, 1.779e-01, 1.452e-01,
    1.190e-01, 9.776e-02, 8.059e-02, 5.741e-02, 4.210e-02, 3.130e-02,
    2.360e-02, 1.810e-02])
RA_LAG = np.deg2rad(30.0)  #: lag of the bulge apex behind the Sun in right ascension (0.523599 rad)


def harris_priester_bounds(height_m):
    """(rho_min, rho_max) [kg/m^3] at geodetic heights [m]; 0 outside 100-1000 km."""
    h = np.asarray(height_m, dtype=float) / 1e3
    i = np.clip(np.searchsorted(HP_HEIGHT_KM, h, side="right") - 1, 0, HP_HEIGHT_KM.size - 2)
    h0, h1 = HP_HEIGHT_KM[i], HP_HEIGHT_KM[i + 1]
    out = []
    for tab in (HP_RHO_MIN, HP_RHO_MAX):
        scale = (h0 - h1) / np.log(tab[i + 1] / tab[i])  # scale height [km]
        out.append(np.where((h > 100.0) & (h < 1000.0), tab[i] * np.exp((h0 - h) / scale) * 1e-12, 0.0))
    return out[0], out[1]


def harris_priester(r_eci, r_sun_eci, n: float = 6.0) -> np.ndarray:
    """Density [kg/m^3] at ECI positions [m] given the Sun position in the same frame (M&G 3.5.2)."""
    r = np.asarray(r_eci, dtype=float)
    s = np.asarray(r_sun_eci, dtype=float)
    ra = np.arctan2(s[..., 1], s[..., 0]) + RA_LAG
    dec = np.arctan2(s[..., 2], np.hypot(s[..., 0], s[..., 1]))
    apex = np.stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)], axis=-1)
    cos_psi = np.sum(r * apex, axis=-1) / np.linalg.norm(r, axis=-1)
    c_half2 = 0.5 * (1.0 + cos_psi)  # cos^2(psi/2)
    rho_min, rho_max = harris_priester_bounds(geodetic_height(r))
    return rho_min + (rho_max - rho_min) * c_half2 ** (n / 2.0)


def relative_wind_eci(r_eci, v_eci) -> np.ndarray:
    """Velocity relative to the co-rotating atmosphere, v - w_E x r [m/s] (ECI axes)."""
    r = np.asarray(r_eci, dtype=float)
    w = np.array([0.0, 0.0, OMEGA_EARTH])
    return np.asarray(v_eci, dtype=float) - cross(w, r)


def drag_force_torque(rho, v_rel_body, geometry):
    """Aerodynamic (force [N], torque [N m]) in body axes about the CoM.

    ``rho`` (...,) [kg/m^3], ``v_rel_body`` (..., 3) the satellite velocity relative to the air in
    body axes, ``geometry`` a :class:`magtune_core.env.geometry.BoxGeometry`.
    """
    normals, areas, centroids = geometry.faces()
    v = np.asarray(v_rel_body, dtype=float)
    speed = np.linalg.norm(v, axis=-1)
    v_hat = v / np.maximum(speed, 1e-300)[..., None]
    cos_t = np.clip(v_hat @ normals.T, 0.0, None)  # (..., 6)
    mag = -0.5 * np.asarray(rho, dtype=float)[..., None] * geometry.cd * areas * cos_t * (speed**2)[..., None]
    F_faces = mag[..., None] * v_hat[..., None, :]  # (..., 6, 3)
    torque = np.sum(cross(centroids, F_faces), axis=-2)
    return np.sum(F_faces, axis=-2), torque
