"""Switchable environment for the full nonlinear simulation (paper section 5): field and disturbances.

One object, :class:`Environment`, built from a frozen :class:`EnvironmentConfig`, gives the
simulator everything that depends on where the satellite is and when:

* ``env.sample(t)`` -> :class:`EnvironmentSample` (r, v, ECI->orbital rotation, orbital-frame
  rate, IGRF field in ECI and orbital axes): everything that does not depend on the attitude;
* ``env.orbit.state(t)`` -> (r_eci, v_eci): J2 (JGM-3) orbit, dense DOP853 ephemeris;
* ``env.magnetic_field_eci(t, r_eci)`` -> b [T]: IGRF-14, degree 10 by default;
* ``env.torques(t, r_eci, v_eci, R_bi, b_eci=None)`` -> dict of named body-axis torques [N m]:
  ``gravity_gradient``, ``residual_dipole``, ``drag``, ``srp`` (zeros when switched off) and
  ``total``. ``R_bi`` rotates body vectors to ECI (x_eci = R_bi @ x_body); helper
  :func:`body_to_eci` builds it from the SPEC quaternion q (body w.r.t. orbital axes, scalar first).

Every function is array-in/array-out: leading axes of t, r, v, R broadcast (one step, or a whole
trajectory for post-processing). Models: gravity gradient T = 3 GM/|r|^3 c x (I c), c the unit
nadir vector in body axes (Wertz 1978, ch. 17; with the actual |r|, not W0);
residual dipole T = m_res x b (1 A m^2 per body axis, the paper's unmeasured disturbance);
drag and SRP from :mod:`atmosphere`, :mod:`srp` on the box of :mod:`geometry`; Sun from :mod:`sun`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from ..base.rotations import cross, rotation_matrix
from .atmosphere import drag_force_torque, harris_priester, relative_wind_eci
from .earth import GM_EARTH
from .geometry import BoxGeometry
from .igrf import IGRF
from .orbit import Orbit, OrbitConfig, eci_to_orbital, orbital_rate
from .srp import srp_force_torque
from .sun import shadow_cylindrical, sun_position

TORQUE_NAMES = ("gravity_gradient", "residual_dipole", "drag", "srp")


@dataclass(frozen=True)
class EnvironmentSample:
    """Everything attitude-independent at time t (arrays with leading axes of t)."""

    t: np.ndarray
    r_eci: np.ndarray  #: position [m]
    v_eci: np.ndarray  #: velocity [m/s]
    R_eci_to_orbital: np.ndarray  #: (..., 3, 3), x_orb = R @ x_eci
    orbital_rate: np.ndarray  #: inertial rate of the orbital frame in orbital axes [rad/s] (~[0, 0, -W0])
    b_eci: np.ndarray  #: IGRF field [T]
    b_orbital: np.ndarray  #: IGRF field in orbital axes [T]


@dataclass(frozen=True)
class EnvironmentConfig:
    """Switches and physical parameters of the simulation environment (SI units)."""

    gravity_gradient: bool = True
    residual_dipole: bool = True
    drag: bool = True
    srp: bool = True
    residual_moment: tuple = (1.0, 1.0, 1.0)  #: residual dipole in body axes [A m^2]
    inertia: tuple = (35.0, 17.0, 25.0)  #: principal moments (body axes) [kg m^2], or a 3x3 nested tuple
    geometry: BoxGeometry = field(default_factory=BoxGeometry)
    igrf_degree: int = 10
    hp_exponent: float = 6.0  #: Harris-Priester cos^n exponent (6: near-polar orbit)
    orbit: OrbitConfig = field(default_factory=OrbitConfig)

    @property
    def inertia_matrix(self) -> np.ndarray:
        I = np.asarray(self.inertia, dtype=float)
        return np.diag(I) if I.shape == (3,) else I


def body_to_eci(q_body_orbital, r_eci, v_eci) -> np.ndarray:
    """R_bi = R_io R_ob: body -> ECI from the body-w.r.t.-orbital quaternion and the orbit state."""
    R_oi = eci_to_orbital(r_eci, v_eci)  # ECI -> orbital
    return np.swapaxes(R_oi, -1, -2) @ rotation_matrix(q_body_orbital)


def _to_body(R_bi, vec_eci):
    return np.einsum("...ji,...j->...i", R_bi, vec_eci)


def gravity_gradient_torque(r_eci, R_bi, inertia) -> np.ndarray:
    """T = 3 GM/|r|^3 c x (I c), c = R_bi^T (-r/|r|) the nadir unit vector in body axes [N m]."""
    r = np.asarray(r_eci, dtype=float)
    rn = np.linalg.norm(r, axis=-1)
    c = _to_body(R_bi, -r / rn[..., None])
    Ic = np.einsum("ij,...j->...i", np.asarray(inertia, dtype=float), c)
    return (3.0 * GM_EARTH / rn**3)[..., None] * cross(c, Ic)


def residual_dipole_torque(m_res, b_body) -> np.ndarray:
    """T = m_res x b [N m]; m_res [A m^2], b [T] in body axes."""
    return cross(np.asarray(m_res, dtype=float), np.asarray(b_body, dtype=float))


class Environment:
    """Orbit, IGRF field, Sun and disturbance torques for one :class:`EnvironmentConfig`."""

    def __init__(self, config: EnvironmentConfig | None = None, orbit_duration: float = 6 * 5700.0):
        self.config = config or EnvironmentConfig()
        self.orbit = Orbit(self.config.orbit, orbit_duration)
        self.jd0 = self.orbit.jd0
        self.igrf = IGRF(self.jd0, self.config.igrf_degree)
        self._inertia = self.config.inertia_matrix
        self._cache: dict = {}  # scalar t -> (r, v, R_oi, sun): RK4 stages ask for the same t twice

    def _at(self, t: float):
        """Attitude-independent quantities at scalar t, memoized for the last few times:
        (r, v, R_eci_to_orbital, b_orbital, rho, v_rel_eci, sat->Sun vector, Sun distance, shadow)."""
        hit = self._cache.get(t)
        if hit is None:
            cfg = self.config
            r, v = self.orbit.state(t)
            R_oi = eci_to_orbital(r, v)
            sun = self.sun_eci(t)
            d = sun - r
            hit = (r, v, R_oi, R_oi @ self.magnetic_field_eci(t, r),
                   harris_priester(r, sun, cfg.hp_exponent) if cfg.drag else 0.0, relative_wind_eci(r, v),
                   d, float(np.linalg.norm(d)), shadow_cylindrical(r, sun))
            if len(self._cache) >= 8:
                self._cache.pop(next(iter(self._cache)))
            self._cache[t] = hit
        return hit

    def jd(self, t) -> np.ndarray:
        return self.orbit.jd(t)

    def magnetic_field_eci(self, t, r_eci) -> np.ndarray:
        """IGRF field [T] in ECI at time(s) t [s after epoch] and ECI position(s) [m]."""
        return self.igrf.eci(r_eci, self.jd(t))

    def sample(self, t) -> EnvironmentSample:
        """Orbit state, orbital frame and rate, and IGRF field at time(s) t [s after epoch]."""
        t = np.asarray(t, dtype=float)
        r, v = self.orbit.state(t)
        R_oi = eci_to_orbital(r, v)
        b = self.magnetic_field_eci(t, r)
        return EnvironmentSample(t, r, v, R_oi, orbital_rate(r, v, zonal_degree=self.config.orbit.zonal_degree), b,
                                 np.einsum("...ij,...j->...i", R_oi, b))

    def magnetic_field_body(self, t, r_eci, R_bi) -> np.ndarray:
        """IGRF field [T] in body axes (what an ideal magnetometer measures)."""
        return _to_body(R_bi, self.magnetic_field_eci(t, r_eci))

    def sun_eci(self, t) -> np.ndarray:
        """Geocentric Sun position [m], ECI of date."""
        return sun_position(self.jd(t))

    def density(self, t, r_eci) -> np.ndarray:
        return harris_priester(r_eci, self.sun_eci(t), self.config.hp_exponent)

    def torques(self, t, r_eci, v_eci, R_bi, b_eci=None) -> dict:
        """Named disturbance torques [N m] in body axes, plus ``total``; switched-off ones are zero.

        ``b_eci`` (optional) avoids a second IGRF evaluation when the caller already has the field.
        """
        cfg = self.config
        r = np.asarray(r_eci, dtype=float)
        v = np.asarray(v_eci, dtype=float)
        R_bi = np.asarray(R_bi, dtype=float)
        shape = np.broadcast_shapes(r.shape, R_bi.shape[:-1])
        zero = np.zeros(shape)
        out = {}
        out["gravity_gradient"] = gravity_gradient_torque(r, R_bi, self._inertia) if cfg.gravity_gradient else zero
        if cfg.residual_dipole:
            b = self.magnetic_field_eci(t, r) if b_eci is None else np.asarray(b_eci, dtype=float)
            out["residual_dipole"] = residual_dipole_torque(cfg.residual_moment, _to_body(R_bi, b))
        else:
            out["residual_dipole"] = zero
        sun = self.sun_eci(t) if (cfg.drag or cfg.srp) else None
        out["drag"] = self._drag(r, v, R_bi, sun) if cfg.drag else zero
        out["srp"] = self._srp(r, R_bi, sun) if cfg.srp else zero
        out["total"] = out["gravity_gradient"] + out["residual_dipole"] + out["drag"] + out["srp"]
        return out


    def _drag(self, r, v, R_bi, sun):
        rho = harris_priester(r, sun, self.config.hp_exponent)
        return drag_force_torque(rho, _to_body(R_bi, relative_wind_eci(r, v)), self.config.geometry)[1]

    def _srp(self, r, R_bi, sun):
        d = sun - r
        return srp_force_torque(_to_body(R_bi, d), np.linalg.norm(d, axis=-1), shadow_cylindrical(r, sun),
                                self.config.geometry)[1]

    def field_orbital(self, t) -> np.ndarray:
        """IGRF field [T] in orbital axes along the orbit at time(s) t: a ``field(t)`` callable for
        ``dynamics.AttitudeDynamics`` (which takes b in orbital axes)."""
        if np.ndim(t) == 0:
            return self._at(float(t))[3].copy()
        r, v = self.orbit.state(t)
        return np.einsum("...ij,...j->...i", eci_to_orbital(r, v), self.magnetic_field_eci(t, r))

    def disturbance_fn(self, include=("residual_dipole", "drag", "srp")):
        """Plug-in torque ``(t, q, w, b_body) -> T_body`` [N m] for ``dynamics.AttitudeDynamics``.

        ``q`` is the body-w.r.t.-orbital quaternion (scalar first); ``b_body`` the field the
        dynamics already computed (used for the residual dipole, so IGRF is not evaluated twice).
        Gravity gradient is excluded by default because that rigid-body model contains its own
        (circular-orbit, 3 W0^2) term; include "gravity_gradient" (and switch theirs off) to use
        the actual 3 GM/|r|^3. Names not in ``include`` or switched off in the config are skipped.
        """
        unknown = set(include) - set(TORQUE_NAMES)
        if unknown:
            raise ValueError(f"unknown torque name(s) {sorted(unknown)}; expected some of {TORQUE_NAMES}")
        cfg = self.config
        on = {k for k in include if getattr(cfg, k)}
        m_res = np.asarray(cfg.residual_moment, dtype=float)

        def torque(t, q, w, b_body):
            total = residual_dipole_torque(m_res, b_body) if "residual_dipole" in on else np.zeros(3)
            if on - {"residual_dipole"}:
                r, _, R_oi, _, rho, v_rel, d, dist, nu = self._at(float(t))
                R_bi = R_oi.T @ rotation_matrix(q)
                if "gravity_gradient" in on:
                    total = total + gravity_gradient_torque(r, R_bi, self._inertia)
                if "drag" in on:
                    total = total + drag_force_torque(rho, R_bi.T @ v_rel, cfg.geometry)[1]
                if "srp" in on:
                    total = total + srp_force_torque(R_bi.T @ d, dist, nu, cfg.geometry)[1]
            return total

        return torque


@lru_cache(maxsize=4)
def _cached_environment(config: EnvironmentConfig) -> Environment:
    return Environment(config)


def torques(t, r_eci, v_eci, R_bi, config: EnvironmentConfig | None = None, b_eci=None) -> dict:
    """Functional form of :meth:`Environment.torques` (the Environment is cached per config)."""
    return _cached_environment(config or EnvironmentConfig()).torques(t, r_eci, v_eci, R_bi, b_eci)
