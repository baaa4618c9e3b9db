"""Full simulation environment of paper section 5 coupled with the attitude dynamics.

``environment = "paper"`` (default everywhere) is the model of SPEC.md: circular orbit at the
constant rate W0, eq. (26) field, gravity gradient 3 W0^2 c x (I c), residual dipole.
``environment = "full"`` (this module, :class:`FullDynamics`) replaces it by

* the J2 orbit of :mod:`magtune_core.env.orbit` (DOP853 ephemeris from the orbital elements, Montenbruck & Gill
  2000 ch. 3), and the attitude is taken **relative to the actual orbital frame** of that orbit
  (X = -r/|r|, Z = -(r x v)/|r x v|): the kinematics are
  ``q' = 0.5 q (x) [0; w - R(q)^T w_oi(t)]`` with ``w_oi(t)`` the frame's inertial rate in
  orbital axes from :func:`orbit.orbital_rate` (``[-|r| a_h/|h|, 0, -|h|/|r|^2]``), instead of the
  constant ``[0, 0, -W0]``;
* IGRF-14 up to degree 10 (:mod:`magtune_core.env.igrf`, epoch + elapsed time) rotated to orbital, then body axes
  (or, selectable, one of the paper's periodic models of :mod:`magtune_core.design.field`);
* gravity gradient ``3 GM/|r|^3 c x (I c)`` with the actual radius; residual dipole;
  Harris-Priester drag and solar radiation pressure with eclipse (:mod:`magtune_core.env.atmosphere`,
  :mod:`magtune_core.env.srp`, :mod:`magtune_core.env.sun`, box of :mod:`magtune_core.env.geometry`), each switchable.

Controller state. The controller is the paper's: its linear state stays
``x = [dq; dw] = [q_vec; w - [0, 0, -W0]]`` (:func:`magtune_core.onboard.law.linear_state`), with dq now measured
against the actual orbital frame and W0 the *nominal* rate. In the full environment W0 is set
to the mean orbital-frame rate of the actual orbit (:func:`nominal_orbit_period`: mean of
``-w_oi,z`` over the first orbits; 2 pi/5611.2 s for the default orbit, vs the paper's 5614.8 s),
so that ``w_oi(t) - [0, 0, -W0]`` is a zero-mean periodic term (|.| <= 1.4e-6 rad/s: J2
radius oscillation and out-of-plane J2 acceleration) that the controller sees as an unmodelled
disturbance, exactly as a flight controller that uses the linear design model would. The
nominal period also defines the orbits of the run and the RMS window of figures_of_merit.

Performance. Everything that does not depend on the attitude (orbit state, frame and rate,
IGRF, density, relative wind, Sun direction, shadow) is evaluated vectorized on the grid of
RK4 stage times ``j * Ts/(2 substeps)`` in chunks (:class:`_TimeGrid`), then looked up as
plain floats; the attitude-dependent part is scalar float code (drag and SRP on the convex box
reduce to ``cp_offset x F``, see :mod:`magtune_core.env.geometry`). The SIL simulator node and the offline
``simulate`` build this same object, so their trajectories agree bit for bit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from datetime import datetime
from functools import lru_cache

import numpy as np

from ..base.rotations import dcm_floats, rotation_matrix
from ..design.params import SpacecraftParams
from ..env.atmosphere import harris_priester, relative_wind_eci
from ..env.earth import GM_EARTH
from ..env.environment import Environment, EnvironmentConfig
from ..env.geometry import BoxGeometry
from ..env.orbit import eci_to_orbital, mean_frame_period, orbital_rate
from ..env.sun import AU, SOLAR_PRESSURE_1AU, shadow_cylindrical
from .dynamics import AttitudeDynamics

ENVIRONMENTS = ("paper", "full")
#: Largest RK4 step [s] used when the sample period is long (see :func:`substeps_for`).
MAX_RK4_STEP = 0.5


def substeps_for(ts: float, default: int = 2) -> int:
    """RK4 sub-steps per sample period: ``default`` (2) at Ts <= 1 s, else ceil(Ts / 0.5 s).

    The attitude dynamics have nutation periods of ~50-110 s; a 0.5 s RK4 step keeps the
    integration error far below the sample-and-hold effect being studied, at any Ts.
    """
    return max(int(default), int(math.ceil(ts / MAX_RK4_STEP - 1e-9)))


@dataclass(frozen=True)
class FullEnvironmentOptions:
    """Switches of the full environment (SI units; angles in degrees)."""

    gravity_gradient: bool = True
    drag: bool = True
    srp: bool = True
    field: str = "igrf"  #: "igrf" or a periodic model of magtune_core.design.field (e.g. "eq26")
    igrf_degree: int = 10
    #: orbit overrides for studies; None (default) = the spacecraft parameters' orbit (SpacecraftParams)
    epoch: datetime | None = None
    raan_deg: float | None = None
    arg_lat_deg: float | None = None
    zonal_degree: int = 2

    def environment_config(self, p: SpacecraftParams) -> EnvironmentConfig:
        """The :class:`EnvironmentConfig` of these switches for spacecraft ``p`` (orbit, box geometry,
        inertia); the residual dipole stays off here, as the dynamics add it themselves."""
        orbit = p.orbit_config(raan_deg=self.raan_deg, arg_lat_deg=self.arg_lat_deg, epoch=self.epoch,
                               zonal_degree=self.zonal_degree)
        # residual dipole is the dynamics' built-in term; the others are computed here
        return EnvironmentConfig(gravity_gradient=self.gravity_gradient, residual_dipole=False, drag=self.drag,
                                 srp=self.srp, inertia=tuple(float(v) for v in np.asarray(p.inertia).reshape(-1)),
                                 geometry=BoxGeometry(dims=tuple(float(x) for x in p.box_dims),
                                                      cp_offset=tuple(float(x) for x in p.cp_offset)),
                                 igrf_degree=self.igrf_degree, orbit=orbit)


@lru_cache(maxsize=8)
def _environment(cfg: EnvironmentConfig) -> Environment:
    return Environment(cfg)


def nominal_orbit_period(p: SpacecraftParams, opts: FullEnvironmentOptions | None = None, orbits: int = 5) -> float:
    """2 pi / (mean of -w_oi,z over ``orbits`` Keplerian periods, 10 s samples) [s].

    Returns
    -------
    float
        The nominal orbit period T [s] whose rate W0 = 2 pi / T enters the linear state (paper eq. 14).

    The nominal rate W0 of the controller's linear state in the full environment (module doc);
    :func:`magtune_core.env.orbit.mean_frame_period` of the spacecraft's orbit.
    """
    return mean_frame_period((opts or FullEnvironmentOptions()).environment_config(p).orbit, orbits)


def environment_table(env: Environment, t: np.ndarray, field_fn=None) -> np.ndarray:
    """Attitude-independent environment at the times ``t`` [s], one row of 15 per time.

    Columns, all in orbital axes: w_oi (3) [rad/s], b_orb (3) [T], k_gg = 3 GM/|r|^3 [1/s^2],
    rho [kg/m^3], v_rel (3) [m/s], unit satellite->Sun (3), SRP pressure P (AU/d)^2 nu [N/m^2]
    (zeros for switched-off models). ``field_fn`` (t -> b_orb) replaces IGRF when given. The one
    implementation behind :class:`_TimeGrid` (single runs) and :mod:`magtune_core.sim.batch`.

    Returns
    -------
    numpy.ndarray
        (len(t), 15) float array.
    """
    t = np.asarray(t, dtype=float)
    cfg = env.config
    r, v = env.orbit.state(t)
    R_oi = eci_to_orbital(r, v)
    w_oi = orbital_rate(r, v, zonal_degree=cfg.orbit.zonal_degree)
    if field_fn is None:
        b = np.einsum("nij,nj->ni", R_oi, env.magnetic_field_eci(t, r))
    else:
        b = np.stack([np.asarray(field_fn(float(x)), dtype=float).reshape(3) for x in t])
    rn = np.linalg.norm(r, axis=-1)
    kgg = 3.0 * GM_EARTH / rn**3
    cols = [w_oi, b, kgg[:, None]]
    if cfg.drag or cfg.srp:
        sun = env.sun_eci(t)
    if cfg.drag:
        rho = harris_priester(r, sun, cfg.hp_exponent)
        wind = np.einsum("nij,nj->ni", R_oi, relative_wind_eci(r, v))
        cols += [rho[:, None], wind]  # density, v_rel in orbital axes
    else:
        cols += [np.zeros((t.size, 1)), np.zeros((t.size, 3))]
    if cfg.srp:
        d = sun - r
        dist = np.linalg.norm(d, axis=-1)
        s = np.einsum("nij,nj->ni", R_oi, d / dist[:, None])
        P = SOLAR_PRESSURE_1AU * (AU / dist) ** 2 * shadow_cylindrical(r, sun)
        cols += [s, P[:, None]]
    else:
        cols += [np.zeros((t.size, 3)), np.zeros((t.size, 1))]
    return np.hstack(cols)


class _TimeGrid:
    """Attitude-independent environment on the time grid j * dt, computed in vectorized chunks.

    ``row(t)`` returns a tuple of 15 floats, all in orbital axes: w_oi (3) [rad/s], b_orb (3) [T],
    k_gg = 3 GM/|r|^3 [1/s^2], rho [kg/m^3], v_rel (3) [m/s], unit satellite->Sun (3), SRP
    pressure P (AU/d)^2 nu [N/m^2] (zeros for switched-off models). Off-grid times are computed
    one at a time with the same vectorized code.
    """

    CHUNK = 2048

    def __init__(self, env: Environment, dt: float, field_fn=None):
        self.env, self.dt, self.field_fn = env, float(dt), field_fn
        self.chunks: dict = {}
        self.single: dict = {}

    def _compute(self, t: np.ndarray) -> list:
        return [tuple(row) for row in environment_table(self.env, t, self.field_fn).tolist()]

    def row(self, t: float) -> tuple:
        j = round(t / self.dt)
        if abs(j * self.dt - t) <= 1e-9 * max(1.0, abs(t)) and j >= 0:
            c, i = divmod(j, self.CHUNK)
            rows = self.chunks.get(c)
            if rows is None:
                if len(self.chunks) >= 2:
                    self.chunks.pop(min(self.chunks))
                rows = self.chunks[c] = self._compute(np.arange(c * self.CHUNK, (c + 1) * self.CHUNK) * self.dt)
            return rows[i]
        hit = self.single.get(t)
        if hit is None:
            if len(self.single) > 8:
                self.single.clear()
            hit = self.single[t] = self._compute(np.array([float(t)]))[0]
        return hit


class FullDynamics(AttitudeDynamics):
    """AttitudeDynamics on the actual J2 orbit with IGRF, drag and SRP (module docstring).

    ``orbit_rate`` is the nominal W0 of the linear state only; the kinematics use w_oi(t).
    Build it with :func:`make_dynamics`.
    """

    def __init__(self, p: SpacecraftParams, opts: FullEnvironmentOptions, grid_step: float,
                 residual_dipole=(1.0, 1.0, 1.0), disturbances=(), orbit_rate: float | None = None):
        self.options = opts
        self.env = _environment(opts.environment_config(p))
        field_fn = None if opts.field == "igrf" else p.field(opts.field)
        self.grid = _TimeGrid(self.env, grid_step, field_fn)
        geo: BoxGeometry = self.env.config.geometry
        normals, areas, _ = geo.faces()
        self._areas = tuple(float(a) for a in areas[:3])
        self._cp = tuple(float(x) for x in geo.cp_offset)
        self._cd = float(geo.cd)
        self._es, self._ed = float(geo.spec_reflect), float(geo.diff_reflect)
        self._gg = bool(opts.gravity_gradient)
        super().__init__(p.inertia, p.wheel_momentum, orbit_rate or p.orbit_rate, self._field_orbital,
                         list(disturbances), gravity_gradient=False,
                         residual_dipole=(0.0, 0.0, 0.0) if residual_dipole is None else residual_dipole)

    def _field_orbital(self, t):
        return np.array(self.grid.row(float(t))[3:6])

    # --- environment torques on plain floats ------------------------------------------------
    def _env_torque(self, row, r00, r01, r02, r10, r11, r12, r20, r21, r22):
        """Gravity gradient (actual |r|) + drag + SRP [N m], body axes, for R(q) given by rows r.."""
        tx = ty = tz = 0.0
        I = self._I
        if self._gg:
            k = row[6]
            c0, c1, c2 = r00, r01, r02  # nadir e_X of the orbital frame in body axes
            i0 = I[0][0] * c0 + I[0][1] * c1 + I[0][2] * c2
            i1 = I[1][0] * c0 + I[1][1] * c1 + I[1][2] * c2
            i2 = I[2][0] * c0 + I[2][1] * c1 + I[2][2] * c2
            tx, ty, tz = k * (c1 * i2 - c2 * i1), k * (c2 * i0 - c0 * i2), k * (c0 * i1 - c1 * i0)
        Ax, Ay, Az = self._areas
        fx = fy = fz = 0.0
        rho = row[7]
        if rho:  # drag: F = -1/2 Cd rho (sum_i A_i |v_i|) v over the lit faces of the box (atmosphere.py)
            ux, uy, uz = row[8:11]
            vx = r00 * ux + r10 * uy + r20 * uz
            vy = r01 * ux + r11 * uy + r21 * uz
            vz = r02 * ux + r12 * uy + r22 * uz
            k = -0.5 * self._cd * rho * (Ax * abs(vx) + Ay * abs(vy) + Az * abs(vz))
            fx, fy, fz = k * vx, k * vy, k * vz
        P = row[14]
        if P:  # SRP: F = -P sum_i A_i c_i [(1 - es) s + 2 (es c_i + ed/3) sgn(s_i) e_i], c_i = |s_i|
            sx0, sy0, sz0 = row[11:14]
            sx = r00 * sx0 + r10 * sy0 + r20 * sz0
            sy = r01 * sx0 + r11 * sy0 + r21 * sz0
            sz = r02 * sx0 + r12 * sy0 + r22 * sz0
            es, ed = self._es, self._ed
            cx, cy, cz = abs(sx), abs(sy), abs(sz)
            a = (1.0 - es) * (Ax * cx + Ay * cy + Az * cz)
            fx -= P * (a * sx + 2.0 * Ax * cx * (es * cx + ed / 3.0) * math.copysign(1.0, sx))
            fy -= P * (a * sy + 2.0 * Ay * cy * (es * cy + ed / 3.0) * math.copysign(1.0, sy))
            fz -= P * (a * sz + 2.0 * Az * cz * (es * cz + ed / 3.0) * math.copysign(1.0, sz))
        if fx or fy or fz:  # convex box, uniform coefficients: torque = cp_offset x F (geometry.py)
            px, py, pz = self._cp
            tx, ty, tz = tx + (py * fz - pz * fy), ty + (pz * fx - px * fz), tz + (px * fy - py * fx)
        return tx, ty, tz

    def _rhs(self, t: float, y, m=None, torque=None) -> tuple:
        q0, q1, q2, q3, wx, wy, wz = y
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = dcm_floats(q0, q1, q2, q3)
        row = self.grid.row(t)
        fo0, fo1, fo2 = row[3:6]
        b0 = r00 * fo0 + r10 * fo1 + r20 * fo2
        b1 = r01 * fo0 + r11 * fo1 + r21 * fo2
        b2 = r02 * fo0 + r12 * fo1 + r22 * fo2
        tx, ty, tz = self._env_torque(row, r00, r01, r02, r10, r11, r12, r20, r21, r22)
        if m is not None:
            m0, m1, m2 = m
            tx, ty, tz = tx + (m1 * b2 - m2 * b1), ty + (m2 * b0 - m0 * b2), tz + (m0 * b1 - m1 * b0)
        mr0, mr1, mr2 = self.residual_dipole
        if mr0 or mr1 or mr2:
            tx, ty, tz = tx + (mr1 * b2 - mr2 * b1), ty + (mr2 * b0 - mr0 * b2), tz + (mr0 * b1 - mr1 * b0)
        if self.disturbances:
            qa, wa, b = np.array([q0, q1, q2, q3]), np.array([wx, wy, wz]), np.array([b0, b1, b2])
            for f in self.disturbances:
                d0, d1, d2 = f(t, qa, wa, b)
                tx, ty, tz = tx + d0, ty + d1, tz + d2
        if torque is not None:
            tx, ty, tz = tx + torque[0], ty + torque[1], tz + torque[2]
        # w_rel = w - R(q)^T w_oi(t): rate of the body relative to the actual orbital frame
        o0, o1, o2 = row[0:3]
        vx = wx - (r00 * o0 + r10 * o1 + r20 * o2)
        vy = wy - (r01 * o0 + r11 * o1 + r21 * o2)
        vz = wz - (r02 * o0 + r12 * o1 + r22 * o2)
        return self._derivative(q0, q1, q2, q3, wx, wy, wz, vx, vy, vz, tx, ty, tz)

    # --- pieces (published torques, tests) ----------------------------------------------------
    def environment_torque(self, t: float, q) -> np.ndarray:
        """Gravity gradient + drag + SRP [N m] in body axes at (t, q) (no residual dipole)."""
        R = _rows(q)
        return np.array(self._env_torque(self.grid.row(float(t)), *R))

    def gravity_gradient_torque(self, q, t: float = 0.0) -> np.ndarray:
        """T_gg = 3 GM/|r|^3 c x (I c) on the actual orbit at time t [N m] (zero if switched off)."""
        row = self.grid.row(float(t))
        c = np.array(_rows(q)[:3])
        return row[6] * np.cross(c, self.inertia @ c) if self._gg else np.zeros(3)

    def disturbance_torque(self, t: float, q, w, b) -> np.ndarray:
        """Gravity gradient (actual r) + drag + SRP + residual dipole + plug-ins [N m]."""
        T = self.environment_torque(t, q) + np.cross(self.residual_dipole, b)
        for f in self.disturbances:
            T = T + np.asarray(f(t, q, w, b), dtype=float)
        return T

    def orbital_frame_rate(self, t: float) -> np.ndarray:
        """w_oi(t), inertial rate of the actual orbital frame in orbital axes [rad/s]."""
        return np.array(self.grid.row(float(t))[0:3])


def _rows(q) -> tuple:
    """R(q) row-major as a tuple (the argument layout of ``_env_torque``)."""
    return tuple(rotation_matrix(q).ravel().tolist())


def full_params(p: SpacecraftParams, opts: FullEnvironmentOptions | None = None) -> SpacecraftParams:
    """``p`` with orbit_period = the nominal period of the actual orbit (controller's W0)."""
    return replace(p, orbit_period=nominal_orbit_period(p, opts))


def make_dynamics(environment: str, p: SpacecraftParams, *, ts: float, substeps: int,
                  residual_dipole=(1.0, 1.0, 1.0), field=None, disturbances=(),
                  options: FullEnvironmentOptions | None = None) -> AttitudeDynamics:
    """The plant of ``simulate`` and of the simulator node for ``environment`` in ENVIRONMENTS.

    "paper": ``AttitudeDynamics.from_params`` (unchanged, bit-exact with earlier runs).
    "full": :class:`FullDynamics`; ``p.orbit_period`` is taken as the nominal period (pass
    :func:`full_params` (p) to use the actual orbit's mean rate, as ``simulate`` and the SIL do).
    """
    if environment == "paper":
        return AttitudeDynamics.from_params(p, field=field, residual_dipole=residual_dipole,
                                            disturbances=disturbances)
    if environment != "full":
        raise ValueError(f"environment must be one of {ENVIRONMENTS}, got {environment!r}")
    if field is not None:
        raise ValueError("environment 'full' computes its own field (FullEnvironmentOptions.field)")
    return FullDynamics(p, options or FullEnvironmentOptions(), ts / (2 * int(substeps)),
                        residual_dipole=residual_dipole, disturbances=disturbances)
