"""Solar radiation pressure force and torque on the box of :mod:`magtune_core.env.geometry`.

Flat-plate model (Wertz 1978, sec. 17.2; Montenbruck & Gill 2000, sec. 3.4): a face of area A,
outward normal n, illuminated at cos(theta) = n.s > 0 (s: unit vector from satellite to Sun) gets

    F = -P A cos(theta) [ (1 - eps_s) s + 2 (eps_s cos(theta) + eps_d / 3) n ],

eps_s, eps_d the specular and diffuse reflectivities (absorptivity 1 - eps_s - eps_d), applied
at the face centroid. P = 4.56e-6 N/m^2 (AU/d)^2; the shadow factor nu (cylindrical, :mod:`sun`)
multiplies everything. Self-shadowing is absent on a convex box.
"""
from __future__ import annotations

import numpy as np

from ..base.rotations import cross
from .sun import AU, SOLAR_PRESSURE_1AU


def srp_force_torque(sun_dir_body, sun_distance, shadow, geometry):
    """SRP (force [N], torque [N m]) in body axes about the CoM.

    ``sun_dir_body`` (..., 3) unit (or not) vector satellite->Sun in body axes, ``sun_distance`` [m],
    ``shadow`` illumination factor in [0, 1].
    """
    s = np.asarray(sun_dir_body, dtype=float)
    s = s / np.linalg.norm(s, axis=-1, keepdims=True)
    normals, areas, centroids = geometry.faces()
    P = SOLAR_PRESSURE_1AU * (AU / np.asarray(sun_distance, dtype=float)) ** 2 * np.asarray(shadow, dtype=float)
    cos_t = np.clip(s @ normals.T, 0.0, None)  # (..., 6)
    es, ed = geometry.spec_reflect, geometry.diff_reflect
    w = -P[..., None] * areas * cos_t  # (..., 6)
    F_faces = w[..., None] * ((1.0 - es) * s[..., None, :]
                              + (2.0 * (es * cos_t + ed / 3.0))[..., None] * normals)
    torque = np.sum(cross(centroids, F_faces), axis=-2)
    return np.sum(F_faces, axis=-2), torque
