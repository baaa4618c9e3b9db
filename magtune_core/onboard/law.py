"""The flight control law: paper eq. 17 with per-axis saturation, and its input state (eq. 14).

This module is what the ROS 2 controller node runs and what the offline simulation calls,
so flight code never imports simulation code and both compute bit-identical dipoles.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..base.rotations import skew_field
from .params import DEFAULT_DIPOLE_LIMIT, DEFAULT_MIN_FIELD  # noqa: F401 (the law's defaults)


def saturate(m, m_max) -> np.ndarray:
    """Per-axis dipole saturation |m_i| <= m_max_i [A m^2] (``m_max`` scalar or 3-vector; inf = none).

    Parameters
    ----------
    m : array_like (3,)
        Dipole to saturate [A m^2].
    m_max : float or array_like (3,)
        Per-axis limit [A m^2] (inf: no limit on that axis).

    Returns
    -------
    ndarray (3,)
        ``m`` clipped per axis to [-m_max, m_max] [A m^2].
    """
    return np.clip(np.asarray(m, dtype=float), -np.asarray(m_max, dtype=float), np.asarray(m_max, dtype=float))


def linear_state(q, w, orbit_rate: float) -> np.ndarray:
    """x = [dq; dw] of paper eq. (14): q_vec (hemisphere q0 >= 0) and w - [0, 0, -W0].

    ``q`` scalar-first attitude of the body w.r.t. orbital axes, ``w`` inertial body rate in body
    axes [rad/s]; see :mod:`magtune_core.sim.dynamics` for why dw is the inertial-rate deviation.

    Parameters
    ----------
    q : array_like (4,)
        Attitude of the body w.r.t. the orbital axes, scalar first.
    w : array_like (3,)
        Inertial body rate in body axes [rad/s].
    orbit_rate : float
        Orbit rate W0 [rad/s].

    Returns
    -------
    ndarray (6,)
        x = [dq; dw]: q's vector part (sign of q0 >= 0) and w + [0, 0, W0] [rad/s].
    """
    q = np.asarray(q, dtype=float)
    s = -1.0 if q[0] < 0.0 else 1.0
    return np.array([s * q[1], s * q[2], s * q[3], w[0], w[1], w[2] + orbit_rate])


@dataclass
class ControlOutput:
    """One controller evaluation: saturated dipole and what happened."""

    m: np.ndarray
    saturated: bool = False
    weak_field: bool = False


@dataclass
class ProjectionController:
    """m = sat(S(b)^T K x / |b|^2) (paper eq. 17), with a weak-field guard.

    Written with explicit float arithmetic (no einsum) so that the offline simulation and
    the ROS controller node compute bit-identical dipoles from the same inputs.
    """

    K: np.ndarray
    dipole_limit: float | np.ndarray = DEFAULT_DIPOLE_LIMIT
    min_field: float = DEFAULT_MIN_FIELD

    def __post_init__(self):
        self.K = np.asarray(self.K, dtype=float).reshape(3, 6)
        self.dipole_limit = np.broadcast_to(np.asarray(self.dipole_limit, dtype=float), (3,)).copy()

    def __call__(self, x, b) -> ControlOutput:
        b = np.asarray(b, dtype=float)
        b2 = float(b @ b)
        if not b2 >= self.min_field**2:  # also catches NaN
            return ControlOutput(np.zeros(3), weak_field=True)
        u = self.K @ np.asarray(x, dtype=float)  # ideal torque T_id = K x (eq. 19)
        m = skew_field(b).T @ u / b2
        ms = saturate(m, self.dipole_limit)
        return ControlOutput(ms, saturated=bool(np.any(ms != m)))
