"""B-dot rate damping (detumbling): m = -k d(b/|b|)/dt / |b| or m = -k_raw db/dt, saturated per axis.

The law the controller node runs in DETUMBLE and the offline mode simulation calls
(:mod:`magtune_core.sim.modes_loop`), like :mod:`magtune_core.onboard.law` holds the pointing law.
Gain rule and normalized law: Avanzini & Giulietti, "Magnetic detumbling of a rigid spacecraft",
J. Guidance, Control, and Dynamics 35(4), 2012 (doi 10.2514/1.53074):
``k = 2 W0 (1 + sin xi_m) J_min`` with W0 the orbit rate, xi_m the inclination of the orbit plane
relative to the geomagnetic equator and J_min the smallest principal moment of inertia; with
``m = -(k/|b|) d(b_hat)/dt`` (b_hat = b/|b|) the torque is m x b = k (w x b_hat) x b_hat in a
slowly varying field: the rate across the field decays with time constant ~ J/k, and the rule
is their quasi-minimum-time gain (the field direction turns at up to ~(1 + sin xi_m) W0 in
inertial space; a faster damping only follows the field and leaves the rate along it).
The derivative of the measured field is estimated by :class:`FieldDerivativeFilter`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .law import saturate
from .params import DEFAULT_DIPOLE_LIMIT, DEFAULT_MIN_FIELD

#: Inclination of the geomagnetic dipole axis to the Earth's rotation axis [rad] (IGRF-14 2025:
#: dipole pole at 80.8 N): the orbit's inclination to the geomagnetic equator swings daily
#: between |i - TILT| and i + TILT (:func:`geomagnetic_inclination`).
DIPOLE_TILT = math.radians(9.2)


def geomagnetic_inclination(inclination: float, tilt: float = DIPOLE_TILT) -> float:
    """xi_m [rad]: the largest inclination of the orbit plane to the geomagnetic equator over a day.

    The dipole axis precesses about the spin axis daily, so the angle between the orbit normal and
    the dipole axis swings between |i - tilt| and i + tilt; folded into [0, pi/2] (an inclination
    and its supplement give the same sin). Largest sin xi_m = largest gain of the rule (the fast bound).

    Parameters
    ----------
    inclination : float
        Orbit inclination i to the Earth's equator [rad] (its absolute value is used).
    tilt : float
        Inclination of the geomagnetic dipole axis to the spin axis [rad] (default :data:`DIPOLE_TILT`).

    Returns
    -------
    float
        xi_m in [0, pi/2] [rad]: pi/2 when |i - tilt| <= pi/2 <= i + tilt.
    """
    i = abs(float(inclination))
    lo, hi = abs(i - tilt), i + tilt
    s = 1.0 if lo <= math.pi / 2.0 <= hi else max(math.sin(lo), math.sin(hi))
    return math.asin(min(s, 1.0))


def bdot_gain(orbit_rate: float, xi_m: float, inertia) -> float:
    """k = 2 W0 (1 + sin xi_m) J_min [N m s] (Avanzini & Giulietti 2012, the normalized law's gain).

    ``orbit_rate`` W0 [rad/s], ``xi_m`` [rad] (:func:`geomagnetic_inclination`), ``inertia`` the
    principal moments (3,) or the matrix (3, 3) [kg m^2] (J_min its smallest eigenvalue).

    Parameters
    ----------
    orbit_rate : float
        Orbit rate W0 [rad/s].
    xi_m : float
        Inclination of the orbit plane to the geomagnetic equator [rad].
    inertia : array_like (3,) or (3, 3)
        Principal moments or the inertia matrix [kg m^2].

    Returns
    -------
    float
        The gain k [N m s].
    """
    I = np.asarray(inertia, dtype=float)
    jmin = float(np.min(np.linalg.eigvalsh(I) if I.ndim == 2 else I))
    return 2.0 * float(orbit_rate) * (1.0 + math.sin(float(xi_m))) * jmin


@dataclass(frozen=True)
class FilterState:
    """The derivative filter's memory: previous field sample [T] and previous output [T/s] (None: no sample yet)."""

    b_prev: np.ndarray | None = None
    bdot: np.ndarray | None = None


@dataclass(frozen=True)
class FieldDerivativeFilter:
    """First-order derivative filter s / (tau s + 1), tau = 1 / cutoff, on the sampled field.

    Why filtered: differencing the magnetometer multiplies its white noise by sqrt(2) / Ts (1e-7 T
    noise at Ts = 1 s gives 1.4e-7 T/s, more than the |db/dt| ~ 2 W0 |b| ~ 1e-7 T/s of a
    detumbled body), and a low-pass at ``cutoff`` [rad/s] passes the field's variation at tumbling
    rates (~|w| rad/s) while cutting that noise's std by (1 - a) / sqrt(1 + a), a = exp(-cutoff Ts)
    (0.13 at the default 0.2 rad/s, Ts = 1 s).

    Exact discretization at Ts: the field between samples is taken as the straight line through
    them (first-order hold), whose derivative is the constant (b_k - b_{k-1}) / Ts over the
    interval; the low-pass 1 / (tau s + 1) driven by a constant is solved exactly,
    ``y_k = a y_{k-1} + (1 - a) (b_k - b_{k-1}) / Ts``. So a field ramp is differentiated
    without bias, and the output is the continuous filter's output at the sample instants for
    any piecewise-linear field (tests/onboard/test_bdot.py: the analytic step response).
    """

    ts: float
    cutoff: float

    def __post_init__(self):
        if not (self.ts > 0 and self.cutoff > 0):
            raise ValueError(f"FieldDerivativeFilter: ts and cutoff must be positive, got {self.ts}, {self.cutoff}")

    @property
    def pole(self) -> float:
        """a = exp(-cutoff Ts), the discrete pole.

        Returns
        -------
        float
            The pole a, in (0, 1).
        """
        return math.exp(-self.cutoff * self.ts)

    def step(self, state: FilterState, b) -> tuple[FilterState, np.ndarray]:
        """Feed one field sample ``b`` (3,) [T]; returns the new state and db/dt [T/s] (zero at the first sample).

        Parameters
        ----------
        state : FilterState
            The filter's memory after the previous sample (``FilterState()`` before the first).
        b : array_like (3,)
            Measured field sample [T], body axes.

        Returns
        -------
        state : FilterState
            The new memory: ``b`` and the new output.
        bdot : ndarray (3,)
            Filtered field derivative db/dt [T/s] (zeros at the first sample).
        """
        b = np.array(b, dtype=float).reshape(3)
        if state.b_prev is None:
            return FilterState(b, np.zeros(3)), np.zeros(3)
        a = self.pole
        y = a * state.bdot + (1.0 - a) * (b - state.b_prev) / self.ts
        return FilterState(b, y), y


@dataclass(frozen=True)
class BdotController:
    """Saturated B-dot: ``normalized`` m = -(k / |b|) d(b_hat)/dt (the gain rule's law), else m = -k db/dt.

    ``gain`` k [N m s] for the normalized law (:func:`bdot_gain`), [A m^2 s / T] for the raw one;
    ``dipole_limit`` per axis [A m^2]; below ``min_field`` [T] the dipole is zero (b_hat undefined).
    Per-axis clipping keeps the sign of every component, so the torque still does negative work
    on the body rate (the energy identity of tests/onboard/test_bdot.py holds saturated too).
    """

    gain: float
    dipole_limit: float | np.ndarray = DEFAULT_DIPOLE_LIMIT
    normalized: bool = True
    min_field: float = DEFAULT_MIN_FIELD

    def dipole(self, b, bdot) -> np.ndarray:
        """Saturated dipole [A m^2] from the measured field ``b`` [T] and its derivative ``bdot`` [T/s] (body axes).

        Parameters
        ----------
        b : array_like (3,)
            Measured field [T], body axes.
        bdot : array_like (3,)
            Its time derivative db/dt [T/s] (:class:`FieldDerivativeFilter`).

        Returns
        -------
        ndarray (3,)
            Dipole [A m^2] saturated per axis at ``dipole_limit``; zeros when |b| < ``min_field`` (or NaN).
        """
        b = np.asarray(b, dtype=float)
        bdot = np.asarray(bdot, dtype=float)
        nb = float(np.sqrt(b @ b))
        if not nb >= self.min_field:
            return np.zeros(3)
        if self.normalized:
            # d(b/|b|)/dt = (bdot - b_hat (b_hat . bdot)) / |b|
            bh = b / nb
            m = -self.gain * (bdot - bh * float(bh @ bdot)) / (nb * nb)
        else:
            m = -self.gain * bdot
        return saturate(m, self.dipole_limit)
