"""Offline closed loop of the flight modes: B-dot -> (acquisition) -> pointing on the nonlinear model.

One run, numpy, perfect sensors (the measurements the mode logic sees are the gyro rate, the
filtered |db/dt| of the measured field and the attitude estimate's pointing error, here equal to
the truth): :class:`magtune_core.onboard.modes.ModeLogic` picks the law each controller period,
:class:`~magtune_core.onboard.bdot.BdotController` in DETUMBLE, eq. 17
(:class:`~magtune_core.onboard.law.ProjectionController`) in ACQUISITION and POINTING (the measured
region of attraction covers every attitude, docs/modes.md), zero dipole in SAFE. The RK4 sub-steps
are re-chosen every period from the rate (:class:`magtune_core.sim.substeps.Substeps`).

Injected faults (:mod:`magtune_core.design.faults`) act as in the SIL: the sensor faults on the
measured field and gyro rate (:func:`~magtune_core.design.faults.measure`; the law and the mode
logic read the measurements), the torquer faults on the applied dipole
(:func:`~magtune_core.design.faults.actuate`). A magnetometer dropout is what the nodes see: the
mode logic and the filters take no sample while no field arrives, the stream is stale once its last
sample lags by more than ``stale_timeout`` (the mode manager's stamp check), and the controller holds
its dipole for 2 Ts, then zeroes it (its stale_data rule).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..base.errors import ConfigError
from ..design import faults as fl
from ..design.params import SpacecraftParams
from ..onboard.bdot import BdotController, FieldDerivativeFilter, FilterState, bdot_gain, geomagnetic_inclination
from ..onboard.law import DEFAULT_DIPOLE_LIMIT, ProjectionController, linear_state
from ..onboard.modes import DETUMBLE, SAFE, Measurements, ModeLogic, ModeParams, ModeState, Transition
from ..onboard.params import TS_DEFAULT
from ..onboard.torquers import NONE as NO_TORQUERS
from ..onboard.torquers import Torquers
from .dynamics import AttitudeDynamics
from .metrics import pointing_error_deg
from .simulate import initial_state
from .substeps import Substeps


@dataclass
class ModeRun:
    """Histories at t_k = k Ts: true ``q``, ``w``, dipole ``m``, ``mode`` (str per step), true pointing
    error ``pointing_deg``; ``transitions`` in order; ``substeps`` the most used (the first periods')."""

    t: np.ndarray
    q: np.ndarray
    w: np.ndarray
    m: np.ndarray
    mode: np.ndarray
    pointing_deg: np.ndarray
    transitions: list
    substeps: int


def simulate_modes(K, p: SpacecraftParams | None = None, *, q0=(1.0, 0.0, 0.0, 0.0), dw0=(0.0, 0.0, 0.0),
                   ts: float = TS_DEFAULT, orbits: float = 6.0, mode_params: ModeParams | None = None,
                   bdot_k: float = 0.0, bdot_cutoff: float = 0.2, dipole_limit=DEFAULT_DIPOLE_LIMIT,
                   residual_dipole=(1.0, 1.0, 1.0), initial_mode: str = DETUMBLE,
                   stale=None, faults=(), stale_timeout: float = 3.0, torquers: Torquers = NO_TORQUERS) -> ModeRun:
    """Fly the mode logic from ``(q0, dw0)`` (:func:`magtune_core.sim.initial.initial_conditions`)
    for ``orbits``, paper environment (eq. 26 field, gravity gradient, residual dipole, section 5).

    ``bdot_k`` 0 = the Avanzini-Giulietti rule (:func:`~magtune_core.onboard.bdot.bdot_gain`);
    ``stale`` an optional function t -> bool (a sensor-outage script; the loop then holds SAFE's
    zero dipole and the logic recovers by itself); ``faults`` injected faults (a sequence of
    :class:`~magtune_core.design.faults.Fault` or spec strings; ``sensors_killed`` is SIL only);
    ``stale_timeout`` [s] the mode manager's staleness limit of a silent magnetometer; ``torquers``
    (:class:`magtune_core.onboard.torquers.Torquers`) their field at the magnetometer (the applied dipole of
    the last period's drive), the duty cycle and its compensation, as the SIL's nodes.

    Returns
    -------
    ModeRun
        Histories, the transitions (time, from, to, reason) and the sub-steps.
    """
    p = p or SpacecraftParams()
    faults = fl.from_list(list(faults))
    if fl.kill_time(faults) is not None:
        raise ConfigError("faults", "kind", "sensors_killed is a SIL fault (a killed process); the offline loop "
                                            "has no processes")
    logic = ModeLogic(mode_params or ModeParams())
    dyn = AttitudeDynamics.from_params(p, residual_dipole=residual_dipole)
    k = bdot_k or bdot_gain(p.orbit_rate, geomagnetic_inclination(math.radians(p.inclination_deg)), p.inertia)
    lim = torquers.law_limit(dipole_limit, ts)
    bdot_law = BdotController(k, lim)
    point = ProjectionController(K, lim)
    filt = FieldDerivativeFilter(ts, bdot_cutoff)
    y = initial_state(p, dw0, q0)
    rule = Substeps.for_rate(ts, y[4:], torquers=torquers)  # the duty cycle's switch-off on the grid
    weights = rule.weights(torquers)
    n = int(round(orbits * p.orbit_period / ts))
    Y, M, modes = np.zeros((n + 1, 7)), np.zeros((n + 1, 3)), []
    stack = _Stack(logic, bdot_law, point, filt, torquers, ts, dyn.orbit_rate, stale, stale_timeout,
                   ModeState(initial_mode, 0.0, "start"))
    fault_state, applied = fl.FaultState(), np.zeros(3)
    for i in range(n + 1):
        t = i * ts
        Y[i] = y
        b_mag = dyn.body_field(t, y[:4])  # the field at the magnetometer: + the torquers' after the last drive
        if torquers.coupled:
            b_mag = b_mag + torquers.field(applied)
        b, w, fault_state = fl.measure(faults, t, ts, b_mag, y[4:], fault_state) if faults else (b_mag, y[4:], None)
        m = applied = stack.step(t, b, w, y[:4])
        if faults:
            applied, fault_state = fl.actuate(faults, t, m, fault_state)
        M[i] = applied
        modes.append(stack.state.mode)
        if i < n:
            S = rule.at(y)
            y = dyn.step(t, y, ts, applied, S, weights[S])
    qv = np.linalg.norm(Y[:, 1:4], axis=1)
    return ModeRun(np.arange(n + 1) * ts, Y[:, :4], Y[:, 4:], M, np.array(modes), pointing_error_deg(qv),
                   stack.transitions, rule.most)


class _Stack:
    """The flight software of the offline loop, one period at a time: the derivative filter and the mode
    logic on each field sample (the manager's stale rule without one), then the law of the mode, as the
    mode manager and the controller nodes do (perfect attitude: the truth's)."""

    def __init__(self, logic, bdot_law, point, filt, torquers, ts, orbit_rate, stale, stale_timeout, state):
        self.logic, self.bdot_law, self.point, self.filt, self.torquers = logic, bdot_law, point, filt, torquers
        self.ts, self.orbit_rate, self.stale, self.stale_timeout, self.state = ts, orbit_rate, stale, stale_timeout, state
        self.fstate, self.transitions = FilterState(), []
        self.b_prev = self.t_field = None
        self.m = np.zeros(3)

    def step(self, t: float, b, w, q) -> np.ndarray:
        """The commanded dipole of sample t from the measured field ``b`` (None: no sample) and rate ``w``."""
        tr = None
        if b is not None:  # a field sample: the filter, the logic and the law step on it
            self.t_field = t
            self.fstate, bdot = self.filt.step(self.fstate, b)
            step = math.nan if self.b_prev is None else float(np.linalg.norm(b - self.b_prev))
            self.b_prev = b
            x = linear_state(q, w, self.orbit_rate)
            err = 2.0 * math.asin(min(float(np.linalg.norm(x[:3])), 1.0))
            is_stale = bool(self.stale(t)) if self.stale is not None else False
            meas = Measurements(rate=float(np.linalg.norm(w)), bdot=float(np.linalg.norm(bdot)),
                                pointing_error=err, stale=is_stale, field_step=step)
            self.state, tr = self.logic.step(self.state, meas, t)
        elif self.t_field is not None and t - self.t_field > self.stale_timeout:  # the manager's stamp check
            self.state, tr = self.logic.step(self.state, Measurements(rate=math.nan, stale=True), t)
        if tr is not None:
            self.transitions.append(tr)
        mode, ts = self.state.mode, self.ts
        if b is None:  # no field: the controller holds its dipole for 2 Ts, then zeroes it
            if self.t_field is None or t - self.t_field > 2.0 * ts:
                self.m = np.zeros(3)
        elif mode == SAFE:
            self.m = np.zeros(3)
        elif mode == DETUMBLE:
            self.m = self.torquers.drive(self.bdot_law.dipole(b, bdot), ts)
        else:
            self.m = self.torquers.drive(self.point(x, b).m, ts)
        return self.m


def transition_table(transitions: list[Transition]) -> list[tuple]:
    """(t [s], from, to, reason) of each transition: what a test or a report prints."""
    return [(tr.t, tr.source, tr.target, tr.reason) for tr in transitions]
