"""Initial states from the user's degrees.

What ``magtune sil --initial-attitude-deg/--initial-rate-deg`` and deployment campaigns build a
run from: an attitude as a rotation vector and a rate deviation, both in degrees at the interface
and SI inside (q0, dw0 of :func:`magtune_core.sim.simulate.initial_state`); the RK4 sub-steps such
a run needs are :mod:`magtune_core.sim.substeps`'s.
"""
from __future__ import annotations

import math

import numpy as np

from ..base.errors import ConfigError


def attitude_quaternion(rotation_deg, where="initial attitude") -> np.ndarray:
    """q0 (scalar first, body w.r.t. orbital axes) of a rotation vector [deg]: axis times angle.

    The axis has the same components in body and orbital axes (it is the rotation's fixed
    vector); angle |v| in [0, 180] deg (a larger one is the same attitude the other way round:
    rejected, ConfigError naming ``where``). Chosen over Euler angles because the paper's body
    axes are named x yaw, y roll, z pitch, where "3-2-1" would mislead.
    """
    v = np.radians(np.asarray(rotation_deg, dtype=float).reshape(3))
    ang = float(np.linalg.norm(v))
    if not math.isfinite(ang) or ang > math.pi * (1 + 1e-12):
        raise ConfigError(where, "attitude", f"expected a rotation vector of at most 180 deg, got {rotation_deg!r}")
    if ang == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.r_[math.cos(ang / 2.0), math.sin(ang / 2.0) * v / ang]


def initial_conditions(attitude_deg=(0.0, 0.0, 0.0), rate_deg=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """(q0, dw0) of a run: attitude rotation vector [deg] (:func:`attitude_quaternion`) and the
    inertial body-rate deviation dw(0) = w(0) - [0, 0, -W0] [deg/s, body axes], the simulator's
    ``initial_rate_error`` (paper eq. 14's dw; zero = the nominal orbit-following rate).

    Returns
    -------
    (ndarray (4,), ndarray (3,))
        q0 scalar-first and dw0 [rad/s].
    """
    rate = np.asarray(rate_deg, dtype=float).reshape(3)
    if not np.all(np.isfinite(rate)):
        raise ConfigError("initial rate", "rate", f"expected finite numbers, got {rate_deg!r}")
    return attitude_quaternion(attitude_deg), np.radians(rate)
