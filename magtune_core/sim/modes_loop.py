"""Offline closed loop of the flight modes: B-dot -> (acquisition) -> pointing on the nonlinear model.

One run, numpy, perfect sensors (the measurements the mode logic sees are the gyro rate, the
filtered |db/dt| of the measured field and the attitude estimate's pointing error, here equal to
the truth): :class:`magtune_core.design.modes.ModeLogic` picks the law each controller period,
:class:`~magtune_core.design.bdot.BdotController` in DETUMBLE, eq. 17
(:class:`~magtune_core.design.law.ProjectionController`) in ACQUISITION and POINTING (the measured
region of attraction covers every attitude, docs/modes.md), zero dipole in SAFE. The RK4 sub-steps
come from the initial rate (:func:`magtune_core.sim.initial.substeps_for_rate`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..design.bdot import BdotController, FieldDerivativeFilter, FilterState, bdot_gain, geomagnetic_inclination
from ..design.law import DEFAULT_DIPOLE_LIMIT, ProjectionController, linear_state
from ..design.modes import DETUMBLE, SAFE, Measurements, ModeLogic, ModeParams, ModeState, Transition
from ..design.params import SpacecraftParams
from .dynamics import AttitudeDynamics
from .initial import substeps_for_rate
from .metrics import pointing_error_deg
from .simulate import initial_state


@dataclass
class ModeRun:
    """Histories at t_k = k Ts: true ``q``, ``w``, dipole ``m``, ``mode`` (str per step), true pointing
    error ``pointing_deg``; ``transitions`` in order; ``substeps`` used."""

    t: np.ndarray
    q: np.ndarray
    w: np.ndarray
    m: np.ndarray
    mode: np.ndarray
    pointing_deg: np.ndarray
    transitions: list
    substeps: int


def simulate_modes(K, p: SpacecraftParams | None = None, *, q0=(1.0, 0.0, 0.0, 0.0), dw0=(0.0, 0.0, 0.0),
                   ts: float = 1.0, orbits: float = 6.0, mode_params: ModeParams | None = None,
                   bdot_k: float = 0.0, bdot_cutoff: float = 0.2, dipole_limit=DEFAULT_DIPOLE_LIMIT,
                   residual_dipole=(1.0, 1.0, 1.0), initial_mode: str = DETUMBLE,
                   stale=None) -> ModeRun:
    """Fly the mode logic from ``(q0, dw0)`` (:func:`magtune_core.sim.initial.initial_conditions`)
    for ``orbits``, paper environment (eq. 26 field, gravity gradient, residual dipole, section 5).

    ``bdot_k`` 0 = the Avanzini-Giulietti rule (:func:`~magtune_core.design.bdot.bdot_gain`);
    ``stale`` an optional function t -> bool (a sensor-outage script; the loop then holds SAFE's
    zero dipole and the logic recovers by itself).

    Returns
    -------
    ModeRun
        Histories, the transitions (time, from, to, reason) and the sub-steps.
    """
    p = p or SpacecraftParams()
    logic = ModeLogic(mode_params or ModeParams())
    dyn = AttitudeDynamics.from_params(p, residual_dipole=residual_dipole)
    k = bdot_k or bdot_gain(p.orbit_rate, geomagnetic_inclination(math.radians(p.inclination_deg)), p.inertia)
    bdot_law = BdotController(k, dipole_limit)
    point = ProjectionController(K, dipole_limit)
    filt = FieldDerivativeFilter(ts, bdot_cutoff)
    y = initial_state(p, dw0, q0)
    S = substeps_for_rate(y[4:], ts)
    n = int(round(orbits * p.orbit_period / ts))
    Y, M, modes = np.zeros((n + 1, 7)), np.zeros((n + 1, 3)), []
    state, fstate, transitions = ModeState(initial_mode, 0.0, "start"), FilterState(), []
    for i in range(n + 1):
        t = i * ts
        Y[i] = y
        b = dyn.body_field(t, y[:4])
        fstate, bdot = filt.step(fstate, b)
        x = linear_state(y[:4], y[4:], dyn.orbit_rate)
        err = 2.0 * math.asin(min(float(np.linalg.norm(x[:3])), 1.0))
        is_stale = bool(stale(t)) if stale is not None else False
        meas = Measurements(rate=float(np.linalg.norm(y[4:])), bdot=float(np.linalg.norm(bdot)),
                            pointing_error=err, stale=is_stale)
        state, tr = logic.step(state, meas, t)
        if tr is not None:
            transitions.append(tr)
        if state.mode == SAFE:
            m = np.zeros(3)
        elif state.mode == DETUMBLE:
            m = bdot_law.dipole(b, bdot)
        else:
            m = point(x, b).m
        M[i] = m
        modes.append(state.mode)
        if i < n:
            y = dyn.step(t, y, ts, m, S)
    qv = np.linalg.norm(Y[:, 1:4], axis=1)
    return ModeRun(np.arange(n + 1) * ts, Y[:, :4], Y[:, 4:], M, np.array(modes), pointing_error_deg(qv),
                   transitions, S)


def transition_table(transitions: list[Transition]) -> list[tuple]:
    """(t [s], from, to, reason) of each transition: what a test or a report prints."""
    return [(tr.t, tr.source, tr.target, tr.reason) for tr in transitions]
