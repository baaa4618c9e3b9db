"""The kinematic truth of the estimator tests: the paper's field along the orbit seen from an inertial
frame, and an Earth-pointing body with a slow wobble (tests/onboard/test_mekf*.py, tests/sim/test_estimation.py)."""
import math

import numpy as np

from magtune_core.design.field import paper_field

W0 = 2 * math.pi / 5614.8  #: orbit rate [rad/s] of the paper's 5614.8-s orbit


def b_ref(t):
    """Eq. 26 along the orbit, in the orbital axes at t = 0 (an inertial frame): turns at ~2 W0."""
    b = np.asarray(paper_field(W0)(t)).reshape(len(t), 3)
    c, s = np.cos(-W0 * t), np.sin(-W0 * t)
    return np.stack([c * b[:, 0] - s * b[:, 1], s * b[:, 0] + c * b[:, 1], b[:, 2]], -1)


def wobble_rate(t):
    """Earth pointing with a slow wobble of 1e-3 rad/s (the paper's dw(0) size)."""
    return np.stack([1e-3 * np.sin(2 * np.pi * t / 700), 1e-3 * np.cos(2 * np.pi * t / 900), -W0 + 0 * t], -1)
