"""Which sensor failed? A magnetometer bias jump or a gyro bias step, told from the MEKF's own statistics.

The estimator (:class:`magtune_core.onboard.estimator.MekfStream`) reports per sample the normalized
innovation squared (NIS) of its magnetometer and sun updates and whether each passed its chi-square gate;
its state holds the gyro-bias estimate b and its covariance block P_bb. :class:`SensorWatch` runs three
statistics on them, each with a threshold derived from one false-alarm probability per sample
(:attr:`SensorWatchParams.probability`) and the statistic's distribution for a consistent filter:

* **M**, the magnetometer's NIS (chi-square(3)) capped at its gate and averaged exponentially over
  ``tau_mag`` (:class:`~magtune_core.onboard.validity.ValidityMonitor`'s statistic); limit
  :func:`average_limit` (two-moment chi-square fit of the average);
* **S**, the same for the sun sensor's NIS (chi-square(2)), held where there is no sun update (eclipse);
* **G**, the drift of the gyro-bias estimate. Its increments d_k = b_k - b_(k-1) are the filter's
  martingale increments K_b nu_k: independent, zero mean, covariance C_k = P_bb(k-1) + sigma_u^2 ts I
  - P_bb(k) (the bias block propagates as P_bb + sigma_u^2 ts I; the updates remove exactly the part
  they move). Their exponentially weighted sum z_k = a z_(k-1) + d_k has covariance
  V_k = a^2 V_(k-1) + C_k and g_k = z^T V^-1 z is chi-square(3); limit its quantile. In steady state
  V = sigma_u^2 ts / (1 - a^2): the bias random walk over ~``tau_bias``/2 s.

Isolation (a verdict names one unit, once; :class:`Verdict`):

* G above its limit -> ``gyro``: the estimated bias moved more than its random walk allows (a gyro
  step is absorbed by the bias state, which is what G sees);
* S above its limit -> ``gyro``: the sun disagrees with the attitude propagated on the gyro (a
  magnetometer jump large enough to be gated leaves the attitude, and so the sun, alone);
* M above its limit starts a confirmation of ``confirm_time``; if G or S fires in it, ``gyro``; if M
  falls back below its limit, nothing; at its end, with at least ``min_sun`` accepted sun updates in it
  (the sun saw the attitude right), ``magnetometer``. Without them (eclipse) the growth of the gated
  innovation decides: the magnetometer's raw NIS averaged over the last ``growth_late`` s above
  ``growth_limit`` times its average over the first ``growth_early`` s is ``gyro`` (a gyro step that
  gates the magnetometer before the bias estimate moves drifts the attitude, and the gated NIS grows
  with the square of the drift); a level one is ``magnetometer`` with ``ambiguous`` set (a bias jump is
  a constant vector in body axes; but a magnetometer that drifts would grow too, and nothing without
  the sun tells the two: docs/modes.md, "Sensor fault detection from the innovations").

The watch is armed only after the estimate has been valid for ``arm_time`` in a row since the last
coarse fix (a converging or tumbling filter moves its bias and misses its innovations by design); a
restart (``started``) disarms it. Once armed it stays armed while the estimate is not valid (the
fault itself makes it so) until the filter restarts. After a verdict the statistics go on (a fault that
lasts holds them above their limits: no second verdict); once the estimate has been valid with all three
below their limits for ``arm_time`` in a row (after re-arming, if the filter restarted) it reports
:data:`BACK` for the unit.

The per-sample arithmetic is :func:`watch_step`, on a float64 state array and a float64 parameter array
only, compiled (numba, cached; ~1 us a sample against ~30 us in Python: ``watch_step.py_func`` is the
Python reference the tests compare with): the estimator node, the batched campaigns
(:mod:`magtune_core.sim.batch_kernels`) and the offline bench run the same code. Pure: no clock, no I/O.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .validity import nis_limit

MAGNETOMETER, GYRO = "magnetometer", "gyro"
FAILED, BACK = "failed", "back"

#: Codes returned by :func:`watch_step`.
NONE, MAG_FAULT, GYRO_FAULT, MAG_AMBIGUOUS, BACK_CODE = 0, 1, 2, 3, 4
#: Causes (state slot ``CAUSE``): the statistic that decided.
CAUSE_NONE, CAUSE_BIAS, CAUSE_SUN, CAUSE_MAG, CAUSE_GROWTH = 0, 1, 2, 3, 4

# state layout (float64 array of NS)
ARMED, VALID_RUN, M_AVG, S_AVG, Z, V, B_PREV, P_PREV = 0, 1, 2, 3, 4, 7, 13, 16
PENDING, PENDING_SUN, LATCHED, CAUSE, G_LAST, QUIET, EARLY, LATE, FIRED = 22, 23, 24, 25, 26, 27, 28, 29, 30
NS = 31
# parameter layout (float64 array of NP)
(P_Q, P_CAP_MAG, P_CAP_SUN, P_A_MAG, P_A_SUN, P_A_BIAS, P_LIM_MAG, P_LIM_SUN, P_LIM_BIAS, P_ARM, P_CONFIRM,
 P_MIN_SUN, P_FLOOR, P_EARLY_N, P_LATE_N, P_GROWTH_LIM) = range(16)
NP = 16
#: Index pairs of the 6 unique elements of a symmetric 3 x 3 matrix (00, 01, 02, 11, 12, 22).
_SYM = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def average_limit(tau: float, ts: float, dof: int, probability: float) -> float:
    """Upper quantile of the exponentially averaged NIS of a consistent filter, ``dof`` degrees of freedom
    (:func:`magtune_core.onboard.validity.nis_limit`: the two-moment chi-square fit of the average).

    Parameters
    ----------
    tau : float
        Averaging time constant [s].
    ts : float
        Sample period [s] (one NIS per sample).
    dof : int
        Degrees of freedom of one NIS (3: magnetometer, 2: sun sensor).
    probability : float
        Probability that a consistent filter's average exceeds the limit at a given sample.

    Returns
    -------
    float
        The limit on the average.
    """
    return nis_limit(tau, ts, probability, dof)


@dataclass(frozen=True)
class SensorWatchParams:
    """The watch's parameters (SI units); see the module docstring and docs/modes.md for the derivation.

    ``ts`` the sample period [s]; ``gyro_rrw`` the filter's sigma_u [rad/s^1.5] (its bias random walk);
    ``gate_mag``, ``gate_sun`` the filter's chi-square gates (the caps of the averages:
    ``MekfStream.gate_mag``, ``gate_sun``); ``tau_mag``, ``tau_sun``, ``tau_bias`` the time constants of
    M, S and G [s]; ``probability`` the false-alarm probability per sample of each statistic;
    ``arm_time`` [s] valid in a row before the watch arms; ``confirm_time`` [s] M must hold with G and S
    quiet before the magnetometer is named; ``min_sun`` accepted sun updates in that time for a verdict
    without ambiguity; ``growth_early``, ``growth_late`` [s] and ``growth_limit``: without them, the
    magnetometer's raw NIS averaged over the last ``growth_late`` of the confirmation, over its average
    over the first ``growth_early``, above ``growth_limit`` names the gyro (an attitude drift grows the
    gated innovation, a bias jump holds it level).
    """

    ts: float = 1.0
    gyro_rrw: float = 1e-6
    gate_mag: float = 21.107
    gate_sun: float = 18.421
    tau_mag: float = 60.0
    tau_sun: float = 60.0
    tau_bias: float = 120.0
    probability: float = 1e-10
    arm_time: float = 600.0
    confirm_time: float = 120.0
    min_sun: int = 30
    growth_early: float = 10.0
    growth_late: float = 30.0
    growth_limit: float = 3.0

    @classmethod
    def of_stream(cls, stream, **overrides) -> "SensorWatchParams":
        """The parameters matched to a running filter (its ts, sigma_u and gates).

        Parameters
        ----------
        stream : MekfStream
            The estimator (``ts``, ``params.rrw``, ``gate_mag``, ``gate_sun`` are read).
        **overrides
            Any other field of this class.

        Returns
        -------
        SensorWatchParams
            The parameters.
        """
        return cls(float(stream.ts), float(stream.params.rrw), float(stream.gate_mag), float(stream.gate_sun),
                   **overrides)

    def limits(self) -> tuple[float, float, float]:
        """The limits of M, S and G at :attr:`probability` per sample.

        Returns
        -------
        tuple of float
            (M limit: :func:`average_limit` of 3 dof, S limit: 2 dof, G limit: chi-square(3) quantile).
        """
        from scipy.stats import chi2

        return (average_limit(self.tau_mag, self.ts, 3, self.probability),
                average_limit(self.tau_sun, self.ts, 2, self.probability),
                float(chi2.isf(self.probability, 3)))

    def array(self) -> np.ndarray:
        """The float64 parameter array of :func:`watch_step`.

        Returns
        -------
        ndarray (NP,)
            Parameters in the ``P_*`` layout (times in samples, limits derived).
        """
        lim_m, lim_s, lim_g = self.limits()
        q = self.gyro_rrw**2 * self.ts
        p = np.zeros(NP)
        p[P_Q], p[P_CAP_MAG], p[P_CAP_SUN] = q, self.gate_mag, self.gate_sun
        p[P_A_MAG], p[P_A_SUN], p[P_A_BIAS] = (math.exp(-self.ts / t) for t in (self.tau_mag, self.tau_sun,
                                                                                   self.tau_bias))
        p[P_LIM_MAG], p[P_LIM_SUN], p[P_LIM_BIAS] = lim_m, lim_s, lim_g
        p[P_ARM] = math.ceil(self.arm_time / self.ts - 1e-9)
        p[P_CONFIRM] = math.ceil(self.confirm_time / self.ts - 1e-9)
        p[P_MIN_SUN] = self.min_sun
        p[P_FLOOR] = max(q, 1e-30) * 1e-4  # keeps V invertible where the bias has not moved (z = 0 there)
        p[P_EARLY_N] = max(1, min(round(self.growth_early / self.ts), p[P_CONFIRM] // 2))
        p[P_LATE_N] = max(1, min(round(self.growth_late / self.ts), p[P_CONFIRM] // 2))
        p[P_GROWTH_LIM] = self.growth_limit
        return p


def new_state() -> np.ndarray:
    """A watch's state before any sample (not armed, nothing latched).

    Returns
    -------
    ndarray (NS,)
        The state in the slot layout of this module.
    """
    s = np.zeros(NS)
    s[PENDING] = -1.0
    return s


@njit(cache=True, error_model="numpy")
def _arm(s, p, b, Pbb) -> None:
    """Start the statistics: averages at their means, bias sum 0, the reference b and P_bb."""
    s[ARMED], s[M_AVG], s[S_AVG], s[PENDING], s[PENDING_SUN], s[QUIET] = 1.0, 3.0, 2.0, -1.0, 0.0, 0.0
    for i in range(3):
        s[Z + i] = 0.0
        s[B_PREV + i] = b[i]
    for n in range(6):
        s[V + n] = 0.0
        s[P_PREV + n] = Pbb[_SYM[n][0], _SYM[n][1]]


@njit(cache=True, error_model="numpy")
def _bias_statistic(s, p, b, Pbb) -> float:
    """Advance z and V by this sample's bias increment and return g = z^T (V + floor I)^-1 z."""
    a = p[P_A_BIAS]
    for i in range(3):
        s[Z + i] = a * s[Z + i] + (b[i] - s[B_PREV + i])
        s[B_PREV + i] = b[i]
    for n in range(6):
        i, j = _SYM[n]
        c = s[P_PREV + n] - Pbb[i, j] + (p[P_Q] if i == j else 0.0)
        s[V + n] = a * a * s[V + n] + c
        s[P_PREV + n] = Pbb[i, j]
    f = p[P_FLOOR]
    v00, v01, v02, v11, v12, v22 = s[V] + f, s[V + 1], s[V + 2], s[V + 3] + f, s[V + 4], s[V + 5] + f
    c00, c01, c02 = v11 * v22 - v12 * v12, v02 * v12 - v01 * v22, v01 * v12 - v02 * v11
    c11, c12, c22 = v00 * v22 - v02 * v02, v01 * v02 - v00 * v12, v00 * v11 - v01 * v01
    det = v00 * c00 + v01 * c01 + v02 * c02
    z0, z1, z2 = s[Z], s[Z + 1], s[Z + 2]
    quad = (z0 * (c00 * z0 + c01 * z1 + c02 * z2) + z1 * (c01 * z0 + c11 * z1 + c12 * z2)
            + z2 * (c02 * z0 + c12 * z1 + c22 * z2))
    return quad / det if det > 0.0 else math.inf


@njit(cache=True, error_model="numpy")
def _decide(s, p, fired_m, fired_s, fired_g, sun_ok, nis_mag) -> int:
    """The isolation rules of the module docstring on this sample's firings; the verdict code."""
    if fired_g or fired_s:
        s[CAUSE] = CAUSE_BIAS if fired_g else CAUSE_SUN
        s[FIRED] = s[G_LAST] if fired_g else s[S_AVG]
        return GYRO_FAULT
    if not fired_m:
        s[PENDING] = -1.0  # M back below its limit: no magnetometer verdict pending
        return NONE
    if s[PENDING] < 0.0:
        s[PENDING], s[PENDING_SUN], s[EARLY], s[LATE] = 0.0, 0.0, 0.0, 0.0
    s[PENDING] += 1.0
    if sun_ok:
        s[PENDING_SUN] += 1.0
    if not math.isnan(nis_mag):
        if s[PENDING] <= p[P_EARLY_N]:
            s[EARLY] += nis_mag / p[P_EARLY_N]
        if s[PENDING] > p[P_CONFIRM] - p[P_LATE_N]:
            s[LATE] += nis_mag / p[P_LATE_N]
    if s[PENDING] < p[P_CONFIRM]:
        return NONE
    s[CAUSE], s[FIRED] = CAUSE_MAG, s[M_AVG]
    if s[PENDING_SUN] >= p[P_MIN_SUN]:  # the sun saw the attitude right all along
        return MAG_FAULT
    if s[LATE] > p[P_GROWTH_LIM] * s[EARLY]:  # no sun: a growing gated innovation is an attitude drift
        s[CAUSE], s[FIRED] = CAUSE_GROWTH, s[LATE] / s[EARLY]
        return GYRO_FAULT
    return MAG_AMBIGUOUS


@njit(cache=True, error_model="numpy")
def watch_step(s, p, nis_mag, nis_sun, sun_ok, b, Pbb, valid, started) -> int:
    """One processed sample of the watch (in place on ``s``); numba-compilable as it is.

    Parameters
    ----------
    s : ndarray (NS,)
        The watch's state (:func:`new_state`), updated in place.
    p : ndarray (NP,)
        The parameters (:meth:`SensorWatchParams.array`).
    nis_mag : float
        The magnetometer update's NIS (nan: no update at this sample).
    nis_sun : float
        The sun update's NIS (nan: none, e.g. eclipse).
    sun_ok : bool
        The sun update passed its gate (False when there was none).
    b : ndarray (3,)
        The gyro-bias estimate after this sample's updates [rad/s] (read only when armed or arming).
    Pbb : ndarray (3, 3)
        Its covariance block P[3:6, 3:6] [rad^2/s^2].
    valid : bool
        The estimate is valid at this sample (:class:`~magtune_core.onboard.validity.ValidityMonitor`).
    started : bool
        The filter made its coarse fix at this sample (a start or a restart: the watch disarms).

    Returns
    -------
    int
        :data:`NONE`, :data:`MAG_FAULT`, :data:`GYRO_FAULT`, :data:`MAG_AMBIGUOUS` (at the sample of the
        verdict) or :data:`BACK_CODE` (at the sample a verdict's unit has been quiet for ``arm_time``).
    """
    if started:
        s[ARMED], s[VALID_RUN], s[PENDING] = 0.0, 0.0, -1.0
    if s[ARMED] == 0.0:
        s[VALID_RUN] = s[VALID_RUN] + 1.0 if valid else 0.0
        if s[VALID_RUN] < p[P_ARM]:
            return NONE
        _arm(s, p, b, Pbb)
        return NONE
    if not math.isnan(nis_mag):
        s[M_AVG] = p[P_A_MAG] * s[M_AVG] + (1.0 - p[P_A_MAG]) * min(nis_mag, p[P_CAP_MAG])
    if not math.isnan(nis_sun):
        s[S_AVG] = p[P_A_SUN] * s[S_AVG] + (1.0 - p[P_A_SUN]) * min(nis_sun, p[P_CAP_SUN])
    g = _bias_statistic(s, p, b, Pbb)
    s[G_LAST] = g
    fired_m, fired_s, fired_g = s[M_AVG] > p[P_LIM_MAG], s[S_AVG] > p[P_LIM_SUN], g > p[P_LIM_BIAS]
    if s[LATCHED] != 0.0:  # after a verdict: back once valid and quiet for arm_time in a row
        s[QUIET] = s[QUIET] + 1.0 if valid and not (fired_m or fired_s or fired_g) else 0.0
        if s[QUIET] < p[P_ARM]:
            return NONE
        s[LATCHED], s[QUIET] = 0.0, 0.0
        return BACK_CODE
    code = _decide(s, p, fired_m, fired_s, fired_g, sun_ok and not math.isnan(nis_sun), nis_mag)
    if code != NONE:  # the statistics go on: while the fault lasts they stay above their limits
        s[LATCHED] = MAG_FAULT if code == MAG_AMBIGUOUS else code
        s[PENDING], s[QUIET] = -1.0, 0.0
    return code


@dataclass(frozen=True)
class Verdict:
    """What the watch decided at one sample: ``unit`` (:data:`MAGNETOMETER` or :data:`GYRO`), ``status``
    (:data:`FAILED` or :data:`BACK`), ``ambiguous`` (a magnetometer verdict without the sun to rule out a
    gyro step) and a one-line ``message`` for /diagnostics."""

    unit: str
    status: str
    message: str
    ambiguous: bool = False


class SensorWatch:
    """The watch of the module docstring: :meth:`step` once per processed sample of the estimator."""

    def __init__(self, params: SensorWatchParams = SensorWatchParams()):
        self.params = params
        self.p = params.array()
        self.s = new_state()

    @property
    def armed(self) -> bool:
        """Whether the statistics run.

        Returns
        -------
        bool
            True once the estimate has been valid for ``arm_time`` in a row since the last fix.
        """
        return self.s[ARMED] != 0.0

    @property
    def statistics(self) -> tuple[float, float, float]:
        """The current statistics.

        Returns
        -------
        tuple of float
            M, S and G (their limits: :meth:`SensorWatchParams.limits`; the values when last armed).
        """
        return float(self.s[M_AVG]), float(self.s[S_AVG]), float(self.s[G_LAST])

    def step(self, nis_mag: float, nis_sun: float, sun_accepted, bias, P_bias, valid: bool,
             started: bool = False) -> Verdict | None:
        """Take one processed sample of the estimator; the verdict when there is one.

        Parameters
        ----------
        nis_mag : float
            ``StepOutput.nis_mag`` (nan: no magnetometer update).
        nis_sun : float
            ``StepOutput.nis_sun`` (nan: no sun update).
        sun_accepted : bool or None
            ``StepOutput.sun_accepted`` (None: no sun update).
        bias : array_like (3,) or None
            The gyro-bias estimate [rad/s] (``state.b``; None before the fix: the watch disarms).
        P_bias : array_like (3, 3) or None
            Its covariance ``state.P[3:6, 3:6]`` [rad^2/s^2] (None before the fix).
        valid : bool
            The estimate is valid (the validity monitor's verdict; False before the fix).
        started : bool
            ``StepOutput.started``: the filter made a (re)start's coarse fix at this sample.

        Returns
        -------
        Verdict or None
            A :data:`FAILED` verdict naming the unit at the sample of detection, :data:`BACK` when the unit has
            been quiet for ``arm_time`` after one, else None.
        """
        if bias is None or P_bias is None:  # no estimate (the filter restarts): disarmed as by a fix
            b, P = np.zeros(3), np.zeros((3, 3))
            valid, started = False, True
        else:
            b, P = np.asarray(bias, dtype=float), np.asarray(P_bias, dtype=float)
        latched = int(self.s[LATCHED])
        code = watch_step(self.s, self.p, float(nis_mag), float(nis_sun), bool(sun_accepted), b, P, bool(valid),
                          bool(started))
        return None if code == NONE else self._verdict(code, latched)

    def _verdict(self, code: int, latched: int) -> Verdict:
        """The :class:`Verdict` of a code (messages name the unit and the statistic that decided)."""
        lim_m, lim_s, lim_g = (float(self.p[i]) for i in (P_LIM_MAG, P_LIM_SUN, P_LIM_BIAS))
        x = float(self.s[FIRED])
        if code == BACK_CODE:
            unit = GYRO if latched == GYRO_FAULT else MAGNETOMETER
            return Verdict(unit, BACK, f"{unit}: estimate valid and innovations consistent again for "
                                       f"{self.params.arm_time:g} s")
        if code == GYRO_FAULT:
            cause = self.s[CAUSE]
            why = (f"gyro-bias estimate drifting (G {x:.1f} > {lim_g:.1f})" if cause == CAUSE_BIAS
                   else f"sun innovations inconsistent (S {x:.2f} > {lim_s:.2f})" if cause == CAUSE_SUN
                   else f"gated magnetometer innovations growing x{x:.0f} in {self.params.confirm_time:g} s "
                        f"(an attitude drift)")
            return Verdict(GYRO, FAILED, f"gyro: {why}")
        ambiguous = code == MAG_AMBIGUOUS
        msg = (f"magnetometer: innovations inconsistent (M {x:.2f} > {lim_m:.2f}) and level for "
               f"{self.params.confirm_time:g} s, gyro bias steady")
        msg += (" (no sun in that time: decided from the level of the gated innovations alone)" if ambiguous
                else ", sun consistent")
        return Verdict(MAGNETOMETER, FAILED, msg, ambiguous)
