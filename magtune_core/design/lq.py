"""The LQ starting gain of paper 4.2 on the time-averaged model (Stickler & Alfriend).

The one LQ design of the project: the tuner's start (paper 4.2) and SPEC.md's reference design.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import solve_continuous_are

from ..onboard.params import TS_DEFAULT
from .gains import Gains
from .model import Z_ATT, AttitudeLTP


def lq_gain(model: AttitudeLTP, sigma: float) -> np.ndarray:
    """K = -R^-1 Bbar^T P, LQ on the averaged model, Q = Z^T Z, R = sigma^2 I (weights of z).

    Parameters
    ----------
    model : AttitudeLTP
        LTP attitude model; its time-averaged input matrix is used.
    sigma : float
        Weight of the torque in z (paper eq. 20): R = sigma^2 I.

    Returns
    -------
    ndarray (3, 6)
        The LQ gain K of the time-averaged model (paper 4.2's starting point).
    """
    Bbar = model.B_mean()
    Q = Z_ATT.T @ Z_ATT
    R = sigma**2 * np.eye(3)
    P = solve_continuous_are(model.A, Bbar, Q, R)
    return -np.linalg.solve(R, Bbar.T @ P)


def lq_gains(model: AttitudeLTP, sigma: float, ts: float = TS_DEFAULT) -> Gains:
    """:func:`lq_gain` wrapped as :class:`~magtune_core.design.gains.Gains` with its provenance.

    Parameters
    ----------
    model : AttitudeLTP
        LTP attitude model.
    sigma : float
        Weight of the torque in z (paper eq. 20).
    ts : float
        Sample period [s] stored with the gains.

    Returns
    -------
    Gains
        The LQ gain, sigma, ts and provenance {"design": "lq_averaged", "design_field": field name}.
    """
    return Gains(lq_gain(model, sigma), sigma, ts, {"design": "lq_averaged", "design_field": model.field.name})
