"""Documented spacecraft surface geometry for the drag and solar-pressure torque models.

A rectangular box, faces normal to the body axes (body = orbital axes nominally: X nadir/yaw,
Y along-track/roll, Z orbit anti-normal/pitch). Default dimensions 0.6 x 1.0 x 0.8 m
(X x Y x Z): the ordering of the uniform-box moments of inertia, I_xx > I_zz > I_yy, then matches
the paper's I = diag(35, 17, 25) kg m^2; frontal (ram) area 0.48 m^2.

``cp_offset`` is the position of the geometric centre (the centre of pressure of the
uniformly coated box) relative to the centre of mass, in body axes: default 5 cm along
(1, 1, 1)/sqrt(3), so drag and SRP produce torques about every axis. For a convex box with the
same coefficients on every face the face-centroid moments about the geometric centre cancel
exactly, so the torque is cp_offset x F_total (checked in tests).

Surface coefficients: drag coefficient Cd = 2.2 (free-molecular flat plate, the usual
value; Montenbruck & Gill 2000, 3.5.2). Optical: specular reflectivity 0.2, diffuse 0.1,
absorptivity 0.7 (mix of solar cells and MLI), flat-plate SRP model of Wertz (1978) /
M&G sec. 3.4 generalized with a diffuse term.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class BoxGeometry:
    dims: tuple = (0.6, 1.0, 0.8)  #: edge lengths along body X, Y, Z [m]
    cp_offset: tuple = field(default_factory=lambda: tuple(np.full(3, 0.05 / np.sqrt(3.0))))  #: [m]
    cd: float = 2.2
    spec_reflect: float = 0.2
    diff_reflect: float = 0.1

    def faces(self):
        """(normals (6,3), areas (6,), centroids relative to the CoM (6,3)) of the six faces."""
        return self._faces

    @cached_property
    def _faces(self):
        d = np.asarray(self.dims, dtype=float)
        normals = np.vstack([np.eye(3), -np.eye(3)])
        area3 = np.array([d[1] * d[2], d[0] * d[2], d[0] * d[1]])
        areas = np.concatenate([area3, area3])
        centroids = normals * np.concatenate([d, d])[:, None] / 2.0 + np.asarray(self.cp_offset)
        return normals, areas, centroids
