"""Orbit propagation with zonal geopotential (J2..J4) and the orbital (LVLH) reference frame.

Force model: point mass + zonal harmonics J2 (default), optionally J3, J4 (JGM-3 values, see
:mod:`magtune_core.env.earth`). No drag/SRP/third-body accelerations on the orbit: over the
5-orbit simulations of the paper they move the satellite by metres, which changes nothing in
the attitude disturbances. ECI is the quasi-inertial frame of :mod:`magtune_core.env.earth`.

Orbital frame (SPEC.md, paper section 3), rows of :func:`eci_to_orbital`::

    X = -r/|r|            (yaw axis, towards the Earth's centre, "nadir")
    Z = -(r x v)/|r x v|  (pitch axis, opposite to the orbit angular momentum)
    Y = Z x X             (roll axis; Y = v/|v| exactly for a circular orbit, Y.v > 0 always)

It is right-handed (X x Y = Z). Its inertial angular velocity, in orbital axes, is
``w_oi = [-|r| a_h/|h|, 0, -|h|/|r|^2]`` (a_h: acceleration along the angular momentum), i.e.
``[0, 0, -W0]`` for a Keplerian circular orbit, which is the nominal body rate of SPEC.md.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime
from functools import lru_cache

import numpy as np
from scipy.integrate import solve_ivp

from ..base.rotations import cross
from .earth import GM_EARTH, J2, J3, J4, R_EARTH, SECONDS_PER_DAY, julian_date

DEFAULT_EPOCH = datetime(2026, 3, 20, 0, 0, 0)  #: default epoch (UTC), near the March equinox


@dataclass(frozen=True)
class OrbitConfig:
    """Initial orbit (circular, paper section 5, or a given state) and the propagation settings.

    altitude [m] above the JGM-3 equatorial radius; angles in degrees; ``arg_lat_deg`` is the
    argument of latitude (angle from the ascending node) at the epoch; ``epoch`` a UTC datetime
    or a Julian date; ``zonal_degree`` in {0 (point mass), 2, 3, 4}. With the defaults (RAAN 0 at
    the 2026 March equinox) the Sun lies in the orbit plane (beta ~ 0): noon-midnight orbit, the
    worst case for eclipses (38 % of the orbit in shadow at 450 km).

    ``state0`` (6 floats: ECI position [m] and velocity [m/s] at the epoch, e.g. SGP4's state of a
    TLE, :mod:`magtune_core.env.tle`) replaces the circular orbit of the elements as the start of
    the propagation; the elements then describe it (altitude: of the mean motion, so that
    :attr:`keplerian_period` is the TLE's 2 pi / n; osculating inclination, RAAN, argument of latitude).
    """

    altitude: float = 450e3
    inclination_deg: float = 87.0
    raan_deg: float = 0.0
    arg_lat_deg: float = 0.0
    epoch: datetime | float = field(default=DEFAULT_EPOCH)
    zonal_degree: int = 2
    rtol: float = 1e-11
    atol: float = 1e-5  #: absolute tolerance on position [m] (velocity: atol * 1e-3 [m/s])
    state0: tuple | None = None  #: (x, y, z, vx, vy, vz) at the epoch [m, m/s]; None: the circular orbit

    @property
    def jd0(self) -> float:
        return julian_date(self.epoch)

    @property
    def semi_major_axis(self) -> float:
        return R_EARTH + self.altitude

    @property
    def keplerian_period(self) -> float:
        return 2.0 * np.pi * np.sqrt(self.semi_major_axis**3 / GM_EARTH)


def initial_state(cfg: OrbitConfig) -> tuple[np.ndarray, np.ndarray]:
    """ECI position [m] and velocity [m/s] at the epoch: ``cfg.state0`` if given, else the circular orbit (osculating)."""
    if cfg.state0 is not None:
        y = np.array(cfg.state0, dtype=float)
        return y[:3], y[3:]
    a = cfg.semi_major_axis
    i, raan, u = np.deg2rad([cfg.inclination_deg, cfg.raan_deg, cfg.arg_lat_deg])
    cO, sO, ci, si, cu, su = np.cos(raan), np.sin(raan), np.cos(i), np.sin(i), np.cos(u), np.sin(u)
    r = a * np.array([cO * cu - sO * su * ci, sO * cu + cO * su * ci, su * si])
    v = np.sqrt(GM_EARTH / a) * np.array([-cO * su - sO * cu * ci, -sO * su + cO * cu * ci, cu * si])
    return r, v


def rotate_state(state, d_raan_deg: float, d_arg_lat_deg: float) -> tuple:
    """``state`` (6 floats, ECI r [m] and v [m/s]) turned by ``d_arg_lat_deg`` about its own orbit normal
    (the satellite further along the same plane) and then by ``d_raan_deg`` about the ECI Z axis (the
    node moved): the same orbit shape at another argument of latitude and RAAN. Returns 6 floats."""
    y = np.asarray(state, dtype=float)
    r, v = y[:3], y[3:]
    k = cross(r, v)
    k = k / np.linalg.norm(k)
    a = np.deg2rad(d_arg_lat_deg)
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    R = np.eye(3) + np.sin(a) * K + (1.0 - np.cos(a)) * K @ K  # Rodrigues
    c, s = np.cos(np.deg2rad(d_raan_deg)), np.sin(np.deg2rad(d_raan_deg))
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ R
    return tuple(float(x) for x in np.concatenate([R @ r, R @ v]))


def inclination(r, v) -> np.ndarray:
    """Inclination [rad] of the osculating orbit plane: the angle between r x v and the ECI Z axis."""
    h = cross(np.asarray(r, dtype=float), np.asarray(v, dtype=float))
    return np.arccos(np.clip(h[..., 2] / np.linalg.norm(h, axis=-1), -1.0, 1.0))


def gravity_acceleration(r, zonal_degree: int = 2) -> np.ndarray:
    """Point-mass + zonal (J2, J3, J4) acceleration [m/s^2] at ECI positions ``r`` (..., 3) [m].

    Closed forms of the gradient of U = GM/r [1 - sum_n J_n (R/r)^n P_n(z/r)] (standard zonal-harmonic
    expressions, e.g. in Vallado, Fundamentals of Astrodynamics; checked in the tests against a
    numerical gradient of U). The Earth-fixed vs inertial distinction vanishes for zonal terms.
    """
    r = np.asarray(r, dtype=float)
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    r2 = x * x + y * y + z * z
    rn = np.sqrt(r2)
    a = -GM_EARTH * r / (rn**3)[..., None]
    if zonal_degree >= 2:
        s2 = z * z / r2
        k = -1.5 * J2 * GM_EARTH * R_EARTH**2 / rn**5
        a = a + np.stack([k * x * (1 - 5 * s2), k * y * (1 - 5 * s2), k * z * (3 - 5 * s2)], axis=-1)
    if zonal_degree >= 3:
        k = -2.5 * J3 * GM_EARTH * R_EARTH**3 / rn**7
        cxy = 3 * z - 7 * z**3 / r2
        a = a + np.stack([k * x * cxy, k * y * cxy, k * (6 * z * z - 7 * z**4 / r2 - 0.6 * r2)], axis=-1)
    if zonal_degree >= 4:
        k = 1.875 * J4 * GM_EARTH * R_EARTH**4 / rn**7
        s2 = z * z / r2
        cxy = 1 - 14 * s2 + 21 * s2 * s2
        a = a + np.stack([k * x * cxy, k * y * cxy, k * z * (5 - 70.0 / 3.0 * s2 + 21 * s2 * s2)], axis=-1)
    if zonal_degree not in (0, 2, 3, 4):
        raise ValueError(f"zonal_degree must be 0, 2, 3 or 4, got {zonal_degree}")
    return a


def _rhs(zonal_degree):
    def f(_t, y):
        return np.concatenate([y[3:], gravity_acceleration(y[:3], zonal_degree)])
    return f


def rk4_step(r, v, dt: float, zonal_degree: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """One classical RK4 step of the orbit (for simulators that integrate the orbit themselves).

    With dt = 1 s the position error after 5 orbits is ~1e-6 m (the error constant of RK4 at
    dt*n = 1e-3 rad per step); use :class:`Orbit` for dense, tolerance-controlled output.
    """
    y = np.concatenate([r, v])
    f = _rhs(zonal_degree)
    k1 = f(0, y)
    k2 = f(0, y + 0.5 * dt * k1)
    k3 = f(0, y + 0.5 * dt * k2)
    k4 = f(0, y + dt * k3)
    y = y + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return y[:3], y[3:]


def propagate(cfg: OrbitConfig, t, rtol: float | None = None, atol: float | None = None):
    """ECI (r, v) at times ``t`` [s after epoch] (1-D, increasing), scipy DOP853 (Dormand-Prince 8(5,3)).

    Returns arrays of shape (len(t), 3). Tolerances default to the config's
    (rtol 1e-11, atol 1e-5 m; the 5-orbit error is quantified in tests/env/test_orbit.py).
    """
    t = np.atleast_1d(np.asarray(t, dtype=float))
    r0, v0 = initial_state(cfg)
    rtol = cfg.rtol if rtol is None else rtol
    atol = cfg.atol if atol is None else atol
    sol = solve_ivp(_rhs(cfg.zonal_degree), (0.0, float(t[-1]) if t[-1] > 0 else 1.0), np.concatenate([r0, v0]),
                    method="DOP853", t_eval=t, rtol=rtol, atol=np.r_[[atol] * 3, [atol * 1e-3] * 3])
    if not sol.success:
        raise RuntimeError(f"orbit propagation failed: {sol.message}")
    return sol.y[:3].T, sol.y[3:].T


class Orbit:
    """Dense ephemeris of one orbit configuration: ``orbit.state(t)`` -> (r, v) in ECI.

    Integrates with DOP853 once over [0, duration] and interpolates with its 7th-order dense
    output (interpolation error << integration tolerance); extends itself if asked beyond.
    """

    def __init__(self, cfg: OrbitConfig | None = None, duration: float = 6 * 5700.0):
        self.cfg = cfg or OrbitConfig()
        self.jd0 = self.cfg.jd0
        r0, v0 = initial_state(self.cfg)
        self._segments = []
        self._t_end = 0.0
        self._y_end = np.concatenate([r0, v0])
        self._extend(duration)

    def _extend(self, t_max: float):
        cfg = self.cfg
        span = max(t_max - self._t_end, 5700.0)
        sol = solve_ivp(_rhs(cfg.zonal_degree), (self._t_end, self._t_end + span), self._y_end,
                        method="DOP853", dense_output=True, rtol=cfg.rtol,
                        atol=np.r_[[cfg.atol] * 3, [cfg.atol * 1e-3] * 3])
        if not sol.success:
            raise RuntimeError(f"orbit propagation failed: {sol.message}")
        self._segments.append((self._t_end, self._t_end + span, sol.sol))
        self._t_end += span
        self._y_end = sol.y[:, -1]

    def jd(self, t) -> np.ndarray:
        """Julian date (UTC) at ``t`` seconds after the epoch."""
        return self.jd0 + np.asarray(t, dtype=float) / SECONDS_PER_DAY

    def state(self, t) -> tuple[np.ndarray, np.ndarray]:
        """ECI position [m] and velocity [m/s] at time(s) t >= 0 [s]; shapes t.shape + (3,)."""
        t = np.asarray(t, dtype=float)
        if np.any(t < 0):
            raise ValueError("Orbit.state: t must be >= 0 (seconds after the epoch)")
        while np.max(t, initial=0.0) > self._t_end:
            self._extend(float(np.max(t)))
        tf = t.reshape(-1)
        y = np.empty((6, tf.size))
        for t0, t1, sol in self._segments:
            sel = (tf >= t0) & (tf <= t1)
            if np.any(sel):
                y[:, sel] = sol(tf[sel]).reshape(6, -1)
        return y[:3].T.reshape(t.shape + (3,)), y[3:].T.reshape(t.shape + (3,))


    def frame(self, t) -> tuple[np.ndarray, np.ndarray]:
        """(R_eci_to_orbital (..., 3, 3), orbital-frame inertial rate in orbital axes (..., 3)) at t [s]."""
        r, v = self.state(t)
        return eci_to_orbital(r, v), orbital_rate(r, v, zonal_degree=self.cfg.zonal_degree)


def eci_to_orbital(r, v) -> np.ndarray:
    """Rotation matrices ECI -> orbital axes, shape (..., 3, 3): x_orb = R @ x_eci (rows X, Y, Z)."""
    r = np.asarray(r, dtype=float)
    v = np.asarray(v, dtype=float)
    X = -r / np.linalg.norm(r, axis=-1, keepdims=True)
    h = cross(r, v)
    Z = -h / np.linalg.norm(h, axis=-1, keepdims=True)
    Y = cross(Z, X)
    return np.stack([X, Y, Z], axis=-2)


def orbital_rate(r, v, accel=None, zonal_degree: int = 2) -> np.ndarray:
    """Inertial angular velocity of the orbital frame, in orbital axes [rad/s], shape (..., 3).

    From d/dt of the frame vectors: w = (|h|/|r|^2) h_hat + (|r| a.h_hat/|h|) r_hat; with
    r_hat = -X and h_hat = -Z this is [-|r| a_h/|h|, 0, -|h|/|r|^2]. ``accel`` defaults to the
    gravity model of :func:`gravity_acceleration` (only its out-of-plane part matters).
    """
    r = np.asarray(r, dtype=float)
    v = np.asarray(v, dtype=float)
    a = gravity_acceleration(r, zonal_degree) if accel is None else np.asarray(accel, dtype=float)
    h = cross(r, v)
    hn = np.linalg.norm(h, axis=-1)
    rn = np.linalg.norm(r, axis=-1)
    a_h = np.sum(a * h, axis=-1) / hn
    return np.stack([-rn * a_h / hn, np.zeros_like(hn), -hn / rn**2], axis=-1)


def argument_of_latitude(r, v) -> np.ndarray:
    """Argument of latitude u in [0, 2 pi) [rad]: angle from the ascending node to r in the orbit plane."""
    r = np.asarray(r, dtype=float)
    h = cross(r, np.asarray(v, dtype=float))
    h_hat = h / np.linalg.norm(h, axis=-1, keepdims=True)
    node = np.stack([-h[..., 1], h[..., 0], np.zeros_like(h[..., 0])], axis=-1)  # z x h
    n_hat = node / np.linalg.norm(node, axis=-1, keepdims=True)
    return np.mod(np.arctan2(np.sum(cross(n_hat, r) * h_hat, axis=-1), np.sum(n_hat * r, axis=-1)), 2 * np.pi)


def raan(r, v) -> np.ndarray:
    """Right ascension of the ascending node [rad] of the osculating orbit."""
    h = cross(np.asarray(r, dtype=float), np.asarray(v, dtype=float))
    return np.arctan2(h[..., 0], -h[..., 1])


def nodal_regression_rate(cfg: OrbitConfig) -> float:
    """Secular J2 RAAN rate [rad/s] of a circular orbit: -3/2 n J2 (R/a)^2 cos i (first-order secular theory, Brouwer 1959 / Kozai 1959, e = 0)."""
    a = cfg.semi_major_axis
    n = np.sqrt(GM_EARTH / a**3)
    return -1.5 * n * J2 * (R_EARTH / a) ** 2 * np.cos(np.deg2rad(cfg.inclination_deg))


def keplerian_period(altitude: float) -> float:
    """2 pi sqrt(a^3 / GM) [s] of a circular orbit at ``altitude`` [m] above the JGM-3 equatorial radius."""
    return float(2.0 * np.pi * np.sqrt((R_EARTH + float(altitude)) ** 3 / GM_EARTH))


@lru_cache(maxsize=32)
def mean_frame_period(cfg: OrbitConfig, orbits: int = 5) -> float:
    """2 pi / (mean of -w_oi,z over ``orbits`` Keplerian periods, 10 s samples) [s] of the propagated orbit.

    The mean inertial rate of the orbital frame of the J2 (zonal) orbit that starts osculating-circular
    at the epoch: the nominal period of the full environment (:func:`magtune_core.sim.fullenv.nominal_orbit_period`)
    and ``period_model: j2_mean`` of the spacecraft parameters. It differs from the Keplerian period by
    the J2 secular rates and the osculating-to-mean offset of the semi-major axis (-0.064 % at 450 km,
    87 deg). Cached: the propagation takes ~0.1 s.
    """
    orbit = Orbit(cfg, 6 * 5700.0)  # the Environment's ephemeris: same numbers as the simulation's
    t = np.arange(0.0, orbits * cfg.keplerian_period, 10.0)
    r, v = orbit.state(t)
    wz = orbital_rate(r, v, zonal_degree=cfg.zonal_degree)[:, 2]
    return float(2.0 * np.pi / np.mean(-wz))
