"""The on-board attitude estimator, one sample at a time: reference models, coarse fix, MEKF step.

Shared by the offline run (:func:`magtune_core.sim.estimation.run_mekf`) and the
``attitude_estimator`` node, so both execute the same arithmetic on the same measurements
(the node's output equals the offline estimate: tests/ros/test_estimator_sil.py). Flight code:
nothing here knows the truth.

* :class:`OnboardModels`: reference field and Sun direction at sim time t from the position fix,
  in the filter's reference frame: ECI in the full environment (IGRF of a configurable degree at
  the measured position, the Sun of date of :func:`magtune_core.env.sun.sun_position` minus the
  measured position); in the paper environment the orbital axes at t = 0 and the environment's
  own field (eq. 26), so the filter is not biased by a model the truth does not use.
* :class:`MekfStream`: the coarse fix (Davenport from magnetometer and Sun at the first sample,
  else from the magnetometer now and the first one carried by the gyro once the reference field
  turned by ``init_angle``) then per sample: propagation with the previous gyro sample,
  magnetometer update, sun update when one is given, each gated (docs/estimation.md). With
  ``compiled=True`` (the node's) the propagation and the updates run the same equations compiled
  (:mod:`magtune_core.onboard.mekf_kernel`, ~2 us a call against ~50-100 us of numpy on 3- and
  6-vectors): equal to the Python filter within 1e-10 rad (tests/onboard/test_mekf_kernel.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..base.rotations import matrix_to_quat, quat_mul, rotation_matrix
from ..env.earth import R_EARTH
from ..env.igrf import IGRF
from ..env.orbit import eci_to_orbital
from ..env.sun import sun_position
from .attitude_fix import davenport
from .mekf import MAG_BIAS_STD, MekfParams, MekfState, initial_state, propagate, rotvec_quat, update
from .params import TS_DEFAULT

SECONDS_PER_DAY = 86400.0


@dataclass(frozen=True)
class FilterModel:
    """The filter's model of its sensors: what the MEKF assumes, not the simulated sensors.

    ``ts`` the sample period [s]; ``mag_var`` the magnetometer's variance per axis [T^2] (white noise
    plus quantization); ``gyro_arw`` sigma_v [rad/s^0.5] and ``gyro_rrw`` sigma_u [rad/s^1.5] of the
    Farrenkopf gyro (Crassidis & Junkins 2012, sec. 7.2.1); ``sun_noise_std`` the sun sensor's angle
    error per axis [rad]. The node builds it from its parameters (:meth:`from_values`); an offline
    run matched to its simulated sensors from their suite (:meth:`of_suite`).
    """

    ts: float = TS_DEFAULT
    mag_var: float = (100e-9) ** 2
    gyro_arw: float = 1e-4
    gyro_rrw: float = 1e-6
    sun_noise_std: float = math.radians(0.5)

    @classmethod
    def from_values(cls, v: dict) -> "FilterModel":
        """From the parsed :data:`magtune_core.onboard.params.ESTIMATOR_FIELDS`.

        Parameters
        ----------
        v : dict
            Parsed values: ``ts``, ``mag_noise_std``, ``gyro_arw``, ``gyro_rrw``, ``sun_noise_std``.

        Returns
        -------
        FilterModel
            The model (``mag_var`` = mag_noise_std^2).
        """
        return cls(float(v["ts"]), float(v["mag_noise_std"]) ** 2, float(v["gyro_arw"]), float(v["gyro_rrw"]),
                   float(v["sun_noise_std"]))

    @classmethod
    def of_suite(cls, suite) -> "FilterModel":
        """The filter matched to a sensor suite (any object with ``ts``, ``magnetometer.covariance``,
        ``gyro.arw``/``rrw`` and ``sun.noise_std``: :class:`magtune_core.design.sensors.SensorSuite`).

        Parameters
        ----------
        suite : SensorSuite
            The simulated sensors (``mag_var`` taken from ``magnetometer.covariance[0, 0]``).

        Returns
        -------
        FilterModel
            The filter's model of those sensors.
        """
        return cls(float(suite.ts), float(suite.magnetometer.covariance[0, 0]), float(suite.gyro.arw),
                   float(suite.gyro.rrw), float(suite.sun.noise_std))

    def gyro_white_std(self) -> float:
        """Std [rad/s] of the white part of one gyro sample: sqrt(sigma_v^2/ts + sigma_u^2 ts/12).

        Returns
        -------
        float
            The std [rad/s].
        """
        return math.sqrt(self.gyro_arw**2 / self.ts + self.gyro_rrw**2 * self.ts / 12.0)


def _rz(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class OnboardModels:
    """Reference vectors of the filter at sim time ``t`` [s from the run's origin].

    ``environment`` "full": reference ECI, ``jd0`` the Julian date of t = 0, IGRF of
    ``igrf_degree``; "paper": reference = orbital axes at t = 0 (they turn at [0, 0, -W0]),
    ``paper_field`` the environment's b_orb(t) [T] and ``orbit_rate`` W0 [rad/s].
    """

    environment: str = "full"
    jd0: float = 0.0
    igrf_degree: int = 10
    paper_field: object = None
    orbit_rate: float = 0.0

    def __post_init__(self):
        self._igrf = IGRF(self.jd0, self.igrf_degree) if self.environment == "full" else None
        self._sun_at = (math.nan, None)  # (t, Sun of date): one evaluation per sample

    def field(self, t: float, r_meas=None) -> np.ndarray:
        """Reference field [T] in reference axes (IGRF at the measured ECI position r_meas [m], or eq. 26).

        Parameters
        ----------
        t : float
            Sim time [s].
        r_meas : array_like (3,), optional
            Measured ECI position [m] (full environment; not read in the paper one).

        Returns
        -------
        ndarray (3,)
            The reference field [T]: ECI (full) or the orbital axes at t = 0 (paper).
        """
        if self._igrf is not None:
            return np.asarray(self._igrf.eci(np.asarray(r_meas, dtype=float), self.jd0 + t / SECONDS_PER_DAY), dtype=float)
        return _rz(-self.orbit_rate * t) @ np.asarray(self.paper_field(t), dtype=float).reshape(3)

    def sun(self, t: float, r_meas) -> np.ndarray:
        """Unit satellite-Sun vector in ECI from the Sun of date and the measured position [m].

        Parameters
        ----------
        t : float
            Sim time [s].
        r_meas : array_like (3,)
            Measured ECI position [m].

        Returns
        -------
        ndarray (3,)
            Unit vector from the satellite to the Sun, ECI.
        """
        d = self.sun_eci(t) - np.asarray(r_meas, dtype=float)
        return d / np.linalg.norm(d)

    def sun_eci(self, t: float) -> np.ndarray:
        """Geocentric Sun position [m] of date (for the on-board eclipse prediction).

        Parameters
        ----------
        t : float
            Sim time [s] (the last one's position is cached).

        Returns
        -------
        ndarray (3,)
            Sun position [m], ECI.
        """
        if self._sun_at[0] != t:
            self._sun_at = (t, sun_position(self.jd0 + t / SECONDS_PER_DAY))
        return self._sun_at[1]

    def lit(self, t: float, r_meas) -> bool:
        """The on-board eclipse prediction at the measured position [m]: the cylindrical shadow of
        :func:`magtune_core.env.sun.shadow_cylindrical` (lit unless behind the Earth and within R_EARTH
        of the Earth-Sun line), on scalars.

        Parameters
        ----------
        t : float
            Sim time [s].
        r_meas : array_like (3,)
            Measured ECI position [m].

        Returns
        -------
        bool
            True when the satellite is predicted in sunlight.
        """
        sx, sy, sz = (float(x) for x in self.sun_eci(t))
        rx, ry, rz = (float(x) for x in r_meas)
        n = math.sqrt(sx * sx + sy * sy + sz * sz)
        sx, sy, sz = sx / n, sy / n, sz / n
        proj = rx * sx + ry * sy + rz * sz
        px, py, pz = rx - proj * sx, ry - proj * sy, rz - proj * sz
        return not (proj < 0 and math.sqrt(px * px + py * py + pz * pz) < R_EARTH)

    def to_orbital(self, q_ref, t: float, r_meas=None, v_meas=None) -> np.ndarray:
        """Body w.r.t. the orbital axes from body w.r.t. the reference frame: R_bo = R_oi R_bi with
        the orbital axes of the position fix (full), or R_z(W0 t) R_bi (paper). The error angle is
        in body axes either way, so the attitude covariance carries over (the fix's error adds
        |dr| / |r| ~ 1e-6 rad at 10 m, neglected).

        Parameters
        ----------
        q_ref : array_like (4,)
            Body w.r.t. the reference frame, scalar first.
        t : float
            Sim time [s] (paper environment).
        r_meas : array_like (3,), optional
            Measured ECI position [m] (full environment).
        v_meas : array_like (3,), optional
            Measured ECI velocity [m/s] (full environment).

        Returns
        -------
        ndarray (4,)
            Body w.r.t. the orbital axes, scalar first, q0 >= 0.
        """
        R_bi = rotation_matrix(np.asarray(q_ref, dtype=float))
        R_oi = eci_to_orbital(np.asarray(r_meas, dtype=float), np.asarray(v_meas, dtype=float)) \
            if self.environment == "full" else _rz(self.orbit_rate * t)
        q = matrix_to_quat(R_oi @ R_bi)
        return q if q[0] >= 0 else -q


@dataclass(frozen=True)
class StepOutput:
    """What one :meth:`MekfStream.step` did: the state (None before the coarse fix), the NIS of
    each update (NaN: none) and whether it passed the gate."""

    state: MekfState | None
    nis_mag: float = math.nan
    nis_sun: float = math.nan
    mag_accepted: bool | None = None
    sun_accepted: bool | None = None
    started: bool = False  #: the coarse fix was made at this sample


class MekfStream:
    """The MEKF of :mod:`magtune_core.onboard.mekf` fed one sample at a time (see the module docstring).

    ``model`` is the filter's sensor model (:class:`FilterModel`; a simulated sensor suite is taken as
    :meth:`FilterModel.of_suite`); ``bias_std`` [rad/s] the gyro-bias prior; ``mag_bias_std`` [T] the magnetometer-bias prior
    (9 states, always; 0: the bias block stays zero and the estimate is the 6-state filter's) and
    ``mag_bias_rw`` [T/s^0.5] its random walk; ``init_angle`` [rad] how far the reference field must
    turn before the magnetometer-only fix. The coarse fix weighs the magnetometer with
    sqrt(R_mag[0, 0] + mag_bias_std^2) (the bias prior taken as part of its error).
    """

    def __init__(self, model, *, bias_std: float = 5e-4, gate_probability: float = 0.9999,
                 init_angle: float = math.radians(10.0), mag_bias_std: float = MAG_BIAS_STD, mag_bias_rw: float = 0.0,
                 compiled: bool = False):
        model = model if isinstance(model, FilterModel) else FilterModel.of_suite(model)
        self.model, self.ts = model, model.ts
        self.params = MekfParams(model.gyro_arw, model.gyro_rrw, gate_probability, mag_rw=mag_bias_rw)
        self.R_mag = model.mag_var * np.eye(3)
        self.R_sun = model.sun_noise_std**2 * np.eye(3)
        self.gate_mag, self.gate_sun = self.params.gate(3), self.params.gate(2)
        self.sig_mag = math.sqrt(self.R_mag[0, 0]) if mag_bias_std == 0 else math.sqrt(self.R_mag[0, 0] + mag_bias_std**2)
        self.bias_std, self.init_angle, self.mag_bias_std = bias_std, init_angle, mag_bias_std
        self.state: MekfState | None = None
        self.k = -1  # samples seen
        self._first = None  # (mag_0, b_ref_0) of the magnetometer-only fix
        self._carry = np.array([1.0, 0.0, 0.0, 0.0])
        self._kernel = None
        if compiled:
            from . import mekf_kernel

            self._kernel = mekf_kernel
            self._sv2, self._su2 = float(self.params.arw) ** 2, float(self.params.rrw) ** 2
            self._sm2 = float(mag_bias_rw) ** 2
            self._R_mag, self._R_sun = np.ascontiguousarray(self.R_mag, dtype=float), np.ascontiguousarray(self.R_sun)
            self._warm_up()

    def reset(self) -> None:
        """Drop the estimate: the next sample starts again as the first (coarse fix; the validity monitor's
        ``reinit_due``)."""
        self.state, self.k, self._first = None, -1, None
        self._carry = np.array([1.0, 0.0, 0.0, 0.0])

    def reopen(self, unit: str, std: float, attitude_std: float = 0.0) -> None:
        """Re-estimate a bias: its covariance block widened to std^2 I, its cross-covariances zeroed (the sensor
        watch's recovery, :mod:`magtune_core.onboard.sensor_watch`). The updates that the jump gated pass again
        (the innovation's covariance now holds the bias' uncertainty) and move the bias, not the attitude.

        Parameters
        ----------
        unit : str
            ``"gyro"`` (the gyro-bias block, states 3-5) or ``"magnetometer"`` (the magnetometer-bias block,
            states 6-8).
        std : float
            The new 1-sigma per axis [rad/s or T] (0: nothing changes).
        attitude_std : float
            With ``"gyro"``: the attitude block widened too, to this 1-sigma [rad] (the step drifted the attitude
            before it was named; 0: the attitude block unchanged).
        """
        if self.state is None or std <= 0.0:
            return
        P = self.state.P.copy()
        blocks = [(3, std)] if unit == "gyro" else [(6, std)]
        if unit == "gyro" and attitude_std > 0.0:
            blocks.append((0, attitude_std))
        for i, sd in blocks:
            P[i:i + 3, :] = 0.0
            P[:, i:i + 3] = 0.0
            P[i:i + 3, i:i + 3] = sd * sd * np.eye(3)
        self.state = MekfState(self.state.q, self.state.b, P, self.state.m)

    def _warm_up(self) -> None:
        """One call of each compiled function on a throw-away state (loads numba's cache, or compiles
        once, here rather than at the first sample of a lockstep run)."""
        k = self._kernel
        q, b, m, P = np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), np.zeros(3), np.eye(9)
        k.propagate(q, b, P, np.zeros(3), self.ts, self._sv2, self._su2, self._sm2, k.GL_X, k.GL_W)
        k.update(q, b, m, P, np.array([1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]), self._R_sun, math.inf, True)

    def step(self, w_prev, mag, b_ref, sun=None, s_ref=None) -> StepOutput:
        """Sample k: ``w_prev`` the gyro sample of k-1 [rad/s] (None at k = 0), ``mag`` [T] and its
        reference ``b_ref``, ``sun``/``s_ref`` the unit Sun vector and its reference (None: no
        valid sun measurement).

        Parameters
        ----------
        w_prev : array_like (3,) or None
            Gyro sample of sample k-1 [rad/s], body axes (None at k = 0).
        mag : array_like (3,) or None
            Magnetometer sample [T], body axes (None: a dropout, no magnetometer update; the filter
            propagates on the gyro and takes the sun update alone).
        b_ref : array_like (3,) or None
            Reference field [T], reference axes (:meth:`OnboardModels.field`; not read without ``mag``).
        sun : array_like (3,), optional
            Unit Sun vector, body axes (None: no valid sun measurement).
        s_ref : array_like (3,), optional
            Its reference, unit, reference axes (:meth:`OnboardModels.sun`).

        Returns
        -------
        StepOutput
            The state (None before the coarse fix), NIS and gate decision of each update.
        """
        self.k += 1
        started = False
        if self.state is None:
            if mag is None:  # the gyro carries the first field of the magnetometer-only fix (no field yet: not counted)
                self._carry_first(w_prev)
                return StepOutput(None)
            start = self._fix(w_prev, np.asarray(mag, dtype=float), np.asarray(b_ref, dtype=float), sun, s_ref)
            if start is None:
                return StepOutput(None)
            self.state, started = start, True
        elif self._kernel is not None:
            return self._step_compiled(w_prev, mag, b_ref, sun, s_ref)
        else:
            self.state = propagate(self.state, w_prev, self.ts, self.params)
        nis_m, ok_m = math.nan, None
        if mag is not None:
            self.state, _, nis_m, ok_m = update(self.state, mag, b_ref, self.R_mag, self.gate_mag, biased=True)
        nis_s, ok_s = math.nan, None
        if sun is not None:
            self.state, _, nis_s, ok_s = update(self.state, sun, s_ref, self.R_sun, self.gate_sun)
        return StepOutput(self.state, nis_m, nis_s, ok_m, ok_s, started)

    def _carry_first(self, w_prev) -> None:
        """A sample without a field before the fix: the gyro turns the first field on (before any field: the
        sample does not count)."""
        if self._first is None:
            self.k -= 1
        else:
            self._carry = quat_mul(self._carry, rotvec_quat(np.asarray(w_prev, dtype=float) * self.ts))

    def _step_compiled(self, w_prev, mag, b_ref, sun, s_ref) -> StepOutput:
        """:meth:`step` after the fix with :mod:`mekf_kernel`'s propagate and update (in place, on copies)."""
        k, st = self._kernel, self.state
        q, b, m, P = st.q.copy(), st.b.copy(), st.m.copy(), st.P.copy()
        k.propagate(q, b, P, np.asarray(w_prev, dtype=float), self.ts, self._sv2, self._su2, self._sm2, k.GL_X, k.GL_W)
        nis_m, ok_m = math.nan, None
        if mag is not None:
            nis_m, ok_m = k.update(q, b, m, P, np.asarray(mag, dtype=float), np.asarray(b_ref, dtype=float), self._R_mag,
                                   self.gate_mag, True)
            ok_m = bool(ok_m)
        nis_s, ok_s = math.nan, None
        if sun is not None:
            nis_s, ok_s = k.update(q, b, m, P, np.asarray(sun, dtype=float), np.asarray(s_ref, dtype=float),
                                   self._R_sun, self.gate_sun, False)
            ok_s = bool(ok_s)
        self.state = MekfState(q, b, P, m)
        return StepOutput(self.state, nis_m, nis_s, ok_m, ok_s, False)

    def _fix(self, w_prev, mag, b_ref, sun, s_ref) -> MekfState | None:
        """The coarse fix of this sample, or None while waiting for the field to turn."""
        if self.k == 0:
            if sun is not None:
                q, P = davenport([mag, sun], [b_ref, s_ref], [self.sig_mag / np.linalg.norm(mag),
                                                             self.model.sun_noise_std])
                return initial_state(q, P, self.bias_std, mag_bias_std=self.mag_bias_std)
            self._first = (mag, b_ref)
            return None
        self._carry = quat_mul(self._carry, rotvec_quat(np.asarray(w_prev, dtype=float) * self.ts))
        mag0, b0_ref = self._first
        cosang = b_ref @ b0_ref / (np.linalg.norm(b_ref) * np.linalg.norm(b0_ref))
        if cosang > math.cos(self.init_angle):
            return None
        T = self.k * self.ts
        b_old = rotation_matrix(self._carry).T @ mag0
        s_old = math.sqrt((self.sig_mag / np.linalg.norm(mag0)) ** 2 + (self.bias_std * T) ** 2
                          + self.model.gyro_arw**2 * T)
        q, P = davenport([mag, b_old], [b_ref, b0_ref], [self.sig_mag / np.linalg.norm(mag), s_old])
        return initial_state(q, P, self.bias_std, mag_bias_std=self.mag_bias_std)
