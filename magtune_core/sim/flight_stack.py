"""The flight nodes' on-board calls, one sample at a time, without ROS: the replay of an input stream.

:class:`FlightStack` is what the ``attitude_estimator``, ``mode_manager`` and ``controller`` nodes
compute for one stamped sample (their callbacks with the ROS plumbing taken out), in their order:

1. estimator: the on-board reference models at the position fix, one
   :class:`~magtune_core.onboard.estimator.MekfStream` step (propagation with the previous gyro
   sample, magnetometer update, sun update when a sun sample came), the estimate's validity
   (:class:`~magtune_core.onboard.validity.ValidityMonitor`, with its re-initialisation) and the
   estimate in orbital axes with the rate ``gyro - bias``: what ``estimate/attitude`` carries;
2. mode manager: the filtered field derivative, |w|, |b_k - b_(k-1)| and the estimate's pointing error
   into :class:`~magtune_core.onboard.modes.ModeLogic`;
3. controller: the law of the mode (B-dot in DETUMBLE, eq. 17 in ACQUISITION and POINTING, zero
   without a valid attitude there and in SAFE), through the torquers' duty-cycle compensation.

The mode the logic gives at sample k drives the law of sample k (the offline loop's order,
:mod:`magtune_core.sim.modes_loop`; in the SIL a new mode reaches the controller by a topic). The
fault watches (sensor, torquer, sun sensor) are not stepped: their verdicts only report, or reopen a
bias after a fault, and a nominal run has none. Everything here is on-board code
(:mod:`magtune_core.onboard`); this module only sequences it, so ``magtune export`` can record what
the flight software computes from its inputs and a test can recompute it from the recorded inputs.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..design.params import SpacecraftParams
from ..onboard.bdot import BdotController, FieldDerivativeFilter, FilterState, bdot_gain, geomagnetic_inclination
from ..onboard.estimator import FilterModel, MekfStream, OnboardModels
from ..onboard.law import ProjectionController, linear_state
from ..onboard.modes import ACQUISITION, DETUMBLE, MODES, POINTING, Measurements, ModeLogic, ModeParams, ModeState
from ..onboard.params import TORQUER_FIELDS
from ..onboard.torquers import Torquers
from ..onboard.validity import ValidityMonitor


@dataclass(frozen=True)
class StackStep:
    """What the flight nodes computed for one sample (SI units, body axes unless said).

    ``field_ref`` [T] and ``sun_ref`` (unit; NaN without a sun sample) are the on-board models' reference
    vectors (the filter's reference frame); ``valid`` the estimate is valid (False before the fix);
    ``q`` body w.r.t. the orbital axes (scalar first, q_w >= 0; (1, 0, 0, 0) before the fix), ``rate``
    gyro minus the estimated bias [rad/s] (the gyro before the fix), ``gyro_bias`` [rad/s] (NaN before
    the fix); ``bdot`` the filtered field derivative [T/s]; ``mode`` the mode id (index in
    :data:`~magtune_core.onboard.modes.MODES`); ``dipole`` the commanded dipole [A m^2].
    """

    field_ref: np.ndarray
    sun_ref: np.ndarray
    valid: bool
    q: np.ndarray
    rate: np.ndarray
    gyro_bias: np.ndarray
    bdot: np.ndarray
    mode: int
    dipole: np.ndarray


def onboard_models(estimator: dict, p: SpacecraftParams) -> OnboardModels:
    """The estimator node's reference models of its parameters (``models_from`` of the node).

    Parameters
    ----------
    estimator : dict
        Parsed ``ESTIMATOR_FIELDS`` values (``environment``, ``igrf_degree``).
    p : SpacecraftParams
        The spacecraft (epoch, orbit rate, field model).

    Returns
    -------
    OnboardModels
        IGRF and the Sun of date ("full"), or the spacecraft's eq. 26 field ("paper").
    """
    if estimator["environment"] == "full":
        return OnboardModels("full", p.orbit_config().jd0, int(estimator["igrf_degree"]))
    return OnboardModels("paper", p.orbit_config().jd0, paper_field=p.field(), orbit_rate=p.orbit_rate)


def resolved_bdot_gain(controller: dict, p: SpacecraftParams) -> float:
    """The controller's B-dot gain: ``bdot_gain``, or the rule 2 W0 (1 + sin xi_m) J_min when it is 0.

    Parameters
    ----------
    controller : dict
        Parsed controller values (``bdot_gain``).
    p : SpacecraftParams
        The spacecraft (orbit rate, inclination, inertia).

    Returns
    -------
    float
        The gain k [N m s] the controller node flies.
    """
    return float(controller["bdot_gain"]) or float(bdot_gain(p.orbit_rate, geomagnetic_inclination(
        math.radians(p.inclination_deg)), p.inertia))


class FlightStack:
    """The three flight nodes configured from their parsed parameters, stepped one sample at a time.

    Parameters
    ----------
    controller : dict
        The controller's values: ``gain`` (18), ``ts``, ``dipole_limit``, ``min_field``, ``bdot_gain``,
        ``bdot_cutoff`` and the torquer fields.
    manager : dict
        The mode manager's: the mode fields, ``bdot_cutoff``, ``initial_mode``.
    estimator : dict
        The estimator's: ``ESTIMATOR_FIELDS``.
    p : SpacecraftParams
        The spacecraft (orbit rate W0 of the law's state, B-dot gain rule, on-board models).
    """

    def __init__(self, controller: dict, manager: dict, estimator: dict, p: SpacecraftParams):
        ts = float(controller["ts"])
        self.ts, self.w0 = ts, p.orbit_rate
        self.torquers = Torquers.from_values({f.name: controller[f.name] for f in TORQUER_FIELDS})
        lim = self.torquers.law_limit(controller["dipole_limit"], ts)
        self.law = ProjectionController(np.asarray(controller["gain"], dtype=float).reshape(3, 6), lim,
                                        controller["min_field"])
        self.bdot_law = BdotController(resolved_bdot_gain(controller, p), lim, min_field=controller["min_field"])
        self.law_filter = FieldDerivativeFilter(ts, controller["bdot_cutoff"])  # the controller's
        self.mode_filter = FieldDerivativeFilter(ts, manager["bdot_cutoff"])  # the mode manager's
        self.law_fstate, self.mode_fstate = FilterState(), FilterState()
        self.logic = ModeLogic(ModeParams.from_mapping(manager))
        self.state = ModeState(manager["initial_mode"], 0.0, "start")
        self.b_prev = None
        v = estimator
        self.models = onboard_models(v, p)
        self.stream = MekfStream(FilterModel.from_values(v), bias_std=v["initial_bias_std"],
                                 gate_probability=v["gate_probability"], init_angle=v["init_angle"],
                                 mag_bias_std=v["initial_mag_bias_std"], mag_bias_rw=v["mag_bias_rw"])
        self.validity = ValidityMonitor.from_values(v, ts, self.stream.gate_mag) if v["validity_gate"] else None
        self.full = v["environment"] == "full"
        self.w_prev = None

    def estimate(self, t: float, field, gyro, sun, position, velocity):
        """The estimator node's sample (``_process`` and ``publish``): (field_ref, sun_ref, valid, q, rate, bias).

        Parameters
        ----------
        t : float
            Sim time [s].
        field, gyro : ndarray (3,)
            Magnetometer [T] and gyro [rad/s] samples.
        sun : ndarray (3,) or None
            Unit Sun vector, body axes (None: no sun sample).
        position, velocity : ndarray (3,) or None
            Position fix [m] and velocity [m/s], ECI (full environment).

        Returns
        -------
        tuple
            Reference field, reference Sun (NaN without a sun sample), validity, q (orbital), rate, gyro bias.
        """
        r, v = (position, velocity) if self.full else (None, None)
        b_ref = self.models.field(t, r)
        s_ref = self.models.sun(t, r) if sun is not None else None
        out = self.stream.step(self.w_prev, field, b_ref, sun, s_ref)
        self.w_prev = np.array(gyro, dtype=float)
        s_ref_col = np.full(3, np.nan) if s_ref is None else s_ref
        if out.state is None:
            return b_ref, s_ref_col, False, np.array([1.0, 0.0, 0.0, 0.0]), self.w_prev.copy(), np.full(3, np.nan)
        valid = self.validity is None or self.validity.step(out.state.P, out.nis_mag)
        if self.validity is not None and self.validity.reinit_due:  # not valid for reinit_time: a new coarse fix
            self.stream.reset()
            self.validity.reset()
        q = self.models.to_orbital(out.state.q, t, r, v)
        bias = np.array(out.state.b, dtype=float)
        return b_ref, s_ref_col, bool(valid), q, self.w_prev - bias, bias

    def step(self, t: float, field, gyro, sun=None, position=None, velocity=None) -> StackStep:
        """One sample through the estimator, the mode manager and the controller.

        Parameters
        ----------
        t : float
            Sim time [s] (stamp minus the estimator's ``time_origin_ns``).
        field : array_like (3,)
            Magnetometer sample [T], body axes.
        gyro : array_like (3,)
            Gyro sample [rad/s], body axes.
        sun : array_like (3,), optional
            Unit Sun vector, body axes (None: no sun sample at this stamp).
        position, velocity : array_like (3,), optional
            Position fix [m] and velocity [m/s], ECI (read in the full environment only).

        Returns
        -------
        StackStep
            The sample's reference vectors, estimate, field derivative, mode and dipole.
        """
        b = np.asarray(field, dtype=float)
        b_ref, s_ref, valid, q, rate, bias = self.estimate(t, b, gyro, None if sun is None else np.asarray(sun, float),
                                                           position, velocity)
        # mode manager (sample): its own derivative filter, then one step of the logic
        self.mode_fstate, bdot_m = self.mode_filter.step(self.mode_fstate, b)
        qv = math.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) / max(math.sqrt(float(q @ q)), 1e-300)
        step = math.nan if self.b_prev is None else math.dist(b, self.b_prev)
        self.b_prev = b
        meas = Measurements(rate=math.sqrt(float(rate @ rate)), bdot=float(np.linalg.norm(bdot_m)),
                            pointing_error=2.0 * math.asin(min(qv, 1.0)) if valid else math.nan, field_step=step,
                            attitude_known=valid)
        self.state, _ = self.logic.step(self.state, meas, t)
        # controller (command): the law of the mode
        self.law_fstate, bdot = self.law_filter.step(self.law_fstate, b)
        mode = self.state.mode
        if mode in (ACQUISITION, POINTING) and not valid:
            m = np.zeros(3)  # no attitude: torquers off (the controller's no_attitude)
        elif mode in (ACQUISITION, POINTING):
            m = self.torquers.drive(self.law(linear_state(q, rate, self.w0), b).m, self.ts)
        elif mode == DETUMBLE:
            m = self.torquers.drive(self.bdot_law.dipole(b, bdot), self.ts)
        else:  # SAFE
            m = np.zeros(3)
        return StackStep(b_ref, s_ref, valid, q, rate, bias, bdot, MODES.index(mode), np.asarray(m, dtype=float))
