"""Batched closed-loop simulation: many dispersed runs advanced together as arrays.

The per-run loop (:func:`magtune_core.sim.simulate.simulate`) evaluates the plant on plain
floats, one run at a time; a Monte Carlo campaign of 1,000 five-orbit full-environment runs
would spend ~2.3 s per run in it. Here a batch of B runs shares every Python-level operation:

* the state is a (7, B) array; one classical RK4 step (same stages, same fixed step, same
  end-of-interval quaternion renormalization as :meth:`AttitudeDynamics.step`) advances all runs;
* the attitude-independent environment (orbit, orbital frame rate, IGRF, gravity-gradient
  gain, density, wind, Sun, shadow: :func:`magtune_core.sim.fullenv.environment_table`) is
  computed per run, vectorized over time, in chunks of controller periods, on the grid of RK4
  stage times ``j Ts / (2 substeps)`` -- exactly the grid the single-run simulator uses;
* the sample-and-hold projection controller (paper eq. 17 with per-axis saturation and the
  weak-field guard, :mod:`magtune_core.design.law`) and the sensor models are evaluated for all
  runs at once.

Per run, the arithmetic is the single-run arithmetic (same formulas, same order of the terms
up to a few reassociations), so with zero sensor noise every run equals ``simulate`` with the
same parameters to ~1e-12 (tests/sim/test_batch.py checks 1e-9, paper and full environment).
Runs are independent: a run's result does not depend on which other runs share its batch
(sensor noise comes from the run's own generator, drawn in fixed chunks of
:data:`NOISE_CHUNK` steps), which is what makes a Monte Carlo campaign reproducible whatever
the number of workers.

Sensors (the model of the ``attitude_sensors`` ROS node): magnetometer
``b_meas = b + bias + N(0, std^2)`` (optionally quantized), attitude
``q_meas = q (x) exp(dtheta/2)`` with ``dtheta ~ N(0, std^2 I)`` in body axes, gyro
``w_meas = w + bias + N(0, std^2)``. The controller's linear state (eq. 14) is built from
``q_meas, w_meas`` and its dipole from ``b_meas``; the plant feels the true field.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.integrate import solve_ivp

from ..design.law import DEFAULT_MIN_FIELD
from ..design.params import SpacecraftParams
from ..env.environment import Environment
from ..env.igrf import IGRF
from ..env.orbit import gravity_acceleration, initial_state, orbital_rate
from .fullenv import FullEnvironmentOptions, _environment, environment_table, nominal_orbit_period
from .metrics import pointing_error_deg

#: Sensor noise is drawn per run in blocks of this many controller steps (9 normals per step:
#: magnetometer, attitude, gyro), so the stream a run sees does not depend on its batch.
NOISE_CHUNK = 1024
#: Controller steps whose environment is computed at once (bounded memory: ~15 x 8 B x
#: (2 substeps x CHUNK + 1) per run).
ENV_CHUNK = 512
#: A run whose body rate exceeds this [rad/s] (or turns non-finite) is marked diverged.
DIVERGED_RATE = 1.0


@dataclass
class SensorNoise:
    """Per-run sensor model (arrays with leading axis B; SI units, see module docstring)."""

    mag_std: np.ndarray  #: (B,) magnetometer white-noise std [T]
    mag_bias: np.ndarray  #: (B, 3) magnetometer bias [T]
    gyro_std: np.ndarray  #: (B,) gyro white-noise std [rad/s]
    gyro_bias: np.ndarray  #: (B, 3) gyro bias [rad/s]
    attitude_std: np.ndarray  #: (B,) attitude-determination error std per axis [rad]
    seeds: Sequence  #: per-run seeds (anything ``numpy.random.default_rng`` takes)
    mag_quantum: float = 0.0  #: magnetometer quantization step [T] (0: none)

    @classmethod
    def none(cls, n: int) -> "SensorNoise":
        """Perfect sensors for ``n`` runs (the single-run ``simulate`` case)."""
        z, z3 = np.zeros(n), np.zeros((n, 3))
        return cls(z, z3, z, z3, z, [0] * n)

    @property
    def any(self) -> bool:
        return bool(np.any(self.mag_std) or np.any(self.mag_bias) or np.any(self.gyro_std) or np.any(self.gyro_bias)
                    or np.any(self.attitude_std) or self.mag_quantum)


@dataclass
class BatchRuns:
    """The B runs of one batch: per-run plant, controller, initial state and environment.

    ``inertia`` (B, 3) principal moments or (B, 3, 3); ``K`` (B, 3, 6) or (3, 6);
    ``dipole_limit`` (B,) or (B, 3) [A m^2]; ``q0`` (B, 4) attitude w.r.t. the orbital frame
    (scalar first); ``dw0`` (B, 3) [rad/s]; ``residual_dipole`` (B, 3) [A m^2];
    ``env_options`` one :class:`FullEnvironmentOptions` per run (environment "full") or None.
    ``p`` gives the rest (wheel, circular orbit and field model of "paper", altitude and
    inclination of "full").
    """

    K: np.ndarray
    inertia: np.ndarray
    residual_dipole: np.ndarray
    dipole_limit: np.ndarray
    q0: np.ndarray
    dw0: np.ndarray
    p: SpacecraftParams = field(default_factory=SpacecraftParams)
    environment: str = "paper"
    env_options: Sequence[FullEnvironmentOptions] | None = None
    sensors: SensorNoise | None = None
    min_field: float = DEFAULT_MIN_FIELD

    @property
    def size(self) -> int:
        return int(np.asarray(self.q0).shape[0])


@dataclass
class BatchResult:
    """Time histories at the controller instants t_k = k Ts for all runs of the batch.

    Arrays are (B, N+1, ...) as in :class:`magtune_core.sim.simulate.SimResult`: ``q``, ``w`` the
    true state, ``x`` the controller's linear state (built from the measurements), ``m`` the
    saturated dipole held over [t_k, t_k+1), ``b`` the true body field. ``orbit_period`` (B,)
    the nominal period of each run (controller's W0). When ``record`` is False (campaigns)
    only every ``record_every``-th instant is kept.
    """

    t: np.ndarray
    q: np.ndarray
    w: np.ndarray
    x: np.ndarray
    m: np.ndarray
    b: np.ndarray
    orbit_period: np.ndarray
    saturated_steps: np.ndarray
    weak_field_steps: np.ndarray
    diverged: np.ndarray
    steps: int = 0
    info: dict = field(default_factory=dict)
    #: with ``full_series``: true pointing error 2 asin(|q_vec|) [deg] (metrics.pointing_error_deg) and |m| [A m^2] at
    #: every controller instant, (B, N+1); ``record_index`` the instants kept in the histories
    pointing_deg: np.ndarray | None = None
    m_norm: np.ndarray | None = None
    record_index: np.ndarray | None = None


def _as3x3(I: np.ndarray, n: int) -> np.ndarray:
    I = np.asarray(I, dtype=float)
    if I.ndim == 1:
        I = np.broadcast_to(I, (n, 3))
    if I.ndim == 2 and I.shape == (n, 3):
        return np.einsum("bi,ij->bij", I, np.eye(3))
    if I.shape == (3, 3):
        return np.broadcast_to(I, (n, 3, 3)).copy()
    return I.reshape(n, 3, 3)


def _cross(a, b):
    """a x b for (3, B) arrays, either may be (3, 1): the cyclic rows as views of [x; x0; x1]."""
    a5, b5 = np.concatenate((a, a[:2])), np.concatenate((b, b[:2]))
    return a5[1:4] * b5[2:5] - a5[2:5] * b5[1:4]


class _Plant:
    """Right-hand side of the attitude dynamics for B runs at once: vectors are (3, B) arrays.

    Same equations as :meth:`FullDynamics._rhs` / :meth:`AttitudeDynamics._rhs` (rigid body with
    wheel, kinematics relative to the orbital frame, gravity gradient, drag and SRP on the box as
    ``cp_offset x F``, magnetic torque of the commanded and residual dipoles); the paper
    environment is the table ``w_oi = [0, 0, -W0]``, ``k_gg = 3 W0^2``, no drag, no SRP. Written
    with whole-vector operations (about 110 numpy calls per evaluation instead of ~300 scalar-row
    ones: the per-step cost of a batch is dominated by the number of calls, not by B).
    """

    def __init__(self, runs: BatchRuns, drag: bool, srp: bool, gg: bool, geometry=None):
        n = runs.size
        I = _as3x3(runs.inertia, n)
        self.I = np.ascontiguousarray(np.moveaxis(I, 0, -1))  # (3, 3, B)
        self.J = np.ascontiguousarray(np.moveaxis(np.linalg.inv(I), 0, -1))
        self.h = np.asarray(runs.p.wheel_momentum, dtype=float).reshape(3, 1)
        self.mres = np.ascontiguousarray(np.broadcast_to(np.asarray(runs.residual_dipole, float), (n, 3)).T)
        self.drag, self.srp, self.gg = drag, srp, gg
        if geometry is not None:
            normals, areas, _ = geometry.faces()
            self.A = np.asarray(areas[:3], dtype=float).reshape(3, 1)
            self.cp = np.asarray(geometry.cp_offset, dtype=float).reshape(3, 1)
            self.cd = float(geometry.cd)
            self.es, self.ed = float(geometry.spec_reflect), float(geometry.diff_reflect)

    def rhs(self, E, y, m):
        """dy/dt (7, B) for y (7, B), environment row E (15, B or 1), held dipole m (3, B)."""
        q, w = y[:4], y[4:]
        a = q / np.sqrt((q * q).sum(0))
        a0, av = a[0], a[1:]
        # R(q) (body -> orbital) = (a0^2 - |av|^2) I + 2 av av^T + 2 a0 [av]x, shape (3, 3, B)
        R = (2.0 * av)[:, None] * av[None, :]
        d = a0 * a0 - (av * av).sum(0)
        s = 2.0 * a0 * av
        R[0, 0] += d
        R[1, 1] += d
        R[2, 2] += d
        R[0, 1] -= s[2]
        R[1, 0] += s[2]
        R[0, 2] += s[1]
        R[2, 0] -= s[1]
        R[1, 2] -= s[0]
        R[2, 1] += s[0]
        # orbital-axes vectors of the table to body axes at once: w_oi, b, v_rel, sun -> R^T x
        F = E[_ROT].reshape(4, 3, -1)
        Fb = (R[None] * F[:, :, None, :]).sum(1)
        wo, b, vrel, sun = Fb[0], Fb[1], Fb[2], Fb[3]
        if self.gg:  # 3 GM/|r|^3 c x (I c), c = nadir in body axes (first row of R)
            c = R[0]
            T = E[6] * _cross(c, (self.I * c[None]).sum(1))
        else:
            T = np.zeros_like(w)
        if self.drag or self.srp:
            A = self.A
            Fo = 0.0
            if self.drag:  # F = -1/2 Cd rho (sum_i A_i |v_i|) v (fullenv.FullDynamics._env_torque)
                Fo = ((-0.5 * self.cd) * E[7] * (A * np.abs(vrel)).sum(0)) * vrel
            if self.srp:  # F = -P sum_i A_i c_i [(1 - es) s + 2 (es c_i + ed/3) sgn(s_i) e_i]
                cs = np.abs(sun)
                k = (1.0 - self.es) * (A * cs).sum(0)
                Fo = Fo - E[14] * (k * sun + (2.0 * A) * cs * (self.es * cs + self.ed / 3.0) * np.copysign(1.0, sun))
            T = T + _cross(self.cp, Fo)
        T = T + _cross(m + self.mres, b)
        v = w - wo  # body rate relative to the actual orbital frame
        e = T - _cross(w, (self.I * w[None]).sum(1) + self.h)
        out = np.empty_like(y)
        out[0] = -0.5 * (q[1:] * v).sum(0)
        out[1:4] = 0.5 * (q[0] * v + _cross(q[1:], v))
        out[4:] = (self.J * e[None]).sum(1)
        return out


#: Rows of the environment table rotated to body axes: w_oi, b_orb, v_rel, unit sun.
_ROT = [0, 1, 2, 3, 4, 5, 8, 9, 10, 11, 12, 13]


class _BatchOrbits:
    """The J2 orbits of several runs propagated as one DOP853 system (one solver for B orbits).

    Each run's single-run ephemeris (:class:`magtune_core.env.orbit.Orbit`) is a DOP853 solution
    with rtol 1e-11 / atol 1e-5 m; propagating B orbits one by one costs ~0.2 s each, more than
    the batched attitude loop per run. Here the (6 B,) system is integrated once with both
    tolerances divided by sqrt(B): the solver's RMS error norm over the 6 B components then
    bounds each run's own 6-component norm by the single-run criterion, so every run is at least
    as accurate as its single-run ephemeris (the two differ by ~1e-5 m, far below anything the
    attitude sees: the batch-vs-simulate test holds at 1e-9). Dense output is evaluated once per
    time chunk for all runs (cached) and sliced per run by :class:`_OrbitView`.
    """

    def __init__(self, cfgs, duration: float):
        B = len(cfgs)
        c0 = cfgs[0]
        self.B, self.zonal = B, c0.zonal_degree
        y0 = np.concatenate([np.concatenate(initial_state(c)) for c in cfgs])
        k = 1.0 / np.sqrt(B)
        atol = np.tile(np.r_[[c0.atol] * 3, [c0.atol * 1e-3] * 3], B) * k
        sol = solve_ivp(self._rhs, (0.0, float(duration)), y0, method="DOP853", dense_output=True, rtol=c0.rtol * k,
                        atol=atol)
        if not sol.success:
            raise RuntimeError(f"orbit propagation failed: {sol.message}")
        self.sol, self.t_end = sol.sol, float(duration)
        self._key, self._val = None, None

    def _rhs(self, _t, y):
        Y = y.reshape(self.B, 6)
        out = np.empty_like(Y)
        out[:, :3] = Y[:, 3:]
        out[:, 3:] = gravity_acceleration(Y[:, :3], self.zonal)
        return out.ravel()

    def states(self, t: np.ndarray) -> np.ndarray:
        """(B, 6, n) ECI position and velocity of every run at the 1-D times t (last call cached)."""
        key = (t.size, float(t[0]), float(t[-1]))
        if key != self._key:
            if float(t[-1]) > self.t_end:
                raise ValueError(f"batched ephemeris ends at {self.t_end:g} s, asked for {float(t[-1]):g} s")
            self._key, self._val = key, self.sol(t).reshape(self.B, 6, t.size)
        return self._val


class _OrbitView:
    """Run ``i`` of a :class:`_BatchOrbits`, with the interface of :class:`magtune_core.env.orbit.Orbit`
    that :func:`environment_table` uses (``cfg``, ``jd0``, ``jd``, ``state``)."""

    def __init__(self, orbits: _BatchOrbits, i: int, cfg):
        self.orbits, self.i, self.cfg, self.jd0 = orbits, i, cfg, cfg.jd0

    def jd(self, t) -> np.ndarray:
        return self.jd0 + np.asarray(t, dtype=float) / 86400.0

    def state(self, t):
        t = np.asarray(t, dtype=float)
        y = self.orbits.states(t.reshape(-1))[self.i]
        return y[:3].T.reshape(t.shape + (3,)), y[3:].T.reshape(t.shape + (3,))


class _ViewEnvironment(Environment):
    """An :class:`Environment` on a run's view of the batched ephemeris (no propagation of its own)."""

    def __init__(self, config, orbit: _OrbitView):  # noqa: D107 - Environment.__init__ without Orbit()
        self.config = config
        self.orbit = orbit
        self.jd0 = orbit.jd0
        self.igrf = IGRF(self.jd0, config.igrf_degree)
        self._inertia = config.inertia_matrix
        self._cache = {}


class _EnvTables:
    """Environment rows on the RK4 stage grid for all runs, computed in chunks of controller steps.

    Runs with equal :class:`FullEnvironmentOptions` share one table (a campaign that disperses
    neither epoch nor RAAN computes the environment once per batch).
    """

    def __init__(self, runs: BatchRuns, dt: float, per_step: int, duration: float = 0.0):
        self.dt, self.per_step = float(dt), int(per_step)
        self.runs = runs
        if runs.environment == "full":
            unique = list(dict.fromkeys(runs.env_options))
            self.index = np.array([unique.index(o) for o in runs.env_options])
            # the Environment's inertia only serves its own torque helpers (unused here): the
            # Environment of the base spacecraft is the environment of every run on that orbit
            self.envs, periods = [], []
            cfgs = [o.environment_config(runs.p) for o in unique]
            if len(unique) == 1:  # one orbit: the single-run Environment itself (bit-identical)
                self.envs = [_environment(cfgs[0])]
            else:
                duration = max(6 * 5700.0, duration + 10.0)
                orbits = _BatchOrbits([c.orbit for c in cfgs], duration)
                self.envs = [_ViewEnvironment(c, _OrbitView(orbits, i, c.orbit)) for i, c in enumerate(cfgs)]
            for env in self.envs:
                periods.append(_nominal_period(env))
            self.periods = np.array(periods)[self.index]
            self.field_fns = [None if o.field == "igrf" else runs.p.field(o.field) for o in unique]
        else:
            self.field = runs.p.field()
            self.W0 = runs.p.orbit_rate
            self.periods = np.full(runs.size, float(runs.p.orbit_period))

    def chunk(self, k0: int, k1: int) -> np.ndarray:
        """Rows for grid indices k0*per_step .. k1*per_step, shape (npts, 15, B) (B = 1 for "paper")."""
        j = np.arange(k0 * self.per_step, k1 * self.per_step + 1)
        t = j * self.dt
        if self.runs.environment == "full":
            out = np.empty((t.size, 15, len(self.envs)))
            for i, (env, ff) in enumerate(zip(self.envs, self.field_fns)):
                out[:, :, i] = environment_table(env, t, ff)
            return out if len(self.envs) == 1 else np.ascontiguousarray(out[:, :, self.index])
        out = np.zeros((t.size, 15, 1))
        out[:, 2, 0] = -self.W0
        out[:, 3:6, 0] = np.asarray(self.field(t), dtype=float).reshape(t.size, 3)
        out[:, 6, 0] = 3.0 * self.W0**2
        return out


def _nominal_period(env, orbits: int = 5) -> float:
    """:func:`magtune_core.env.orbit.mean_frame_period` evaluated on the run's own ephemeris without a
    second propagation (the single-run Orbit: the same number; a batched one: equal to ~1e-12)."""
    cfg = env.config.orbit
    t = np.arange(0.0, orbits * cfg.keplerian_period, 10.0)
    r, v = env.orbit.state(t)
    wz = orbital_rate(r, v, zonal_degree=cfg.zonal_degree)[:, 2]
    return float(2.0 * np.pi / np.mean(-wz))


def run_orbit_periods(runs: BatchRuns) -> np.ndarray:
    """Nominal orbit period of each run [s]: ``p.orbit_period`` ("paper") or the actual orbit's mean
    orbital-frame rate (:func:`magtune_core.sim.fullenv.nominal_orbit_period`, as ``simulate`` uses)."""
    if runs.environment == "full":
        periods = {o: nominal_orbit_period(runs.p, o) for o in dict.fromkeys(runs.env_options)}
        return np.array([periods[o] for o in runs.env_options])
    return np.full(runs.size, float(runs.p.orbit_period))


def _noise_blocks(sensors: SensorNoise, n: int):
    gens = [np.random.default_rng(s) for s in sensors.seeds]

    def block():
        return np.stack([g.standard_normal((NOISE_CHUNK, 9)) for g in gens])  # (B, CHUNK, 9)

    return block


def _quat_mul_cols(p, q):
    p0, p1, p2, p3 = p
    q0, q1, q2, q3 = q
    return (p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3, p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2,
            p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1, p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0)


def simulate_batch(runs: BatchRuns, *, ts: float = 1.0, steps: int, substeps: int = 2,
                   record_every: int = 1, orbit_periods=None, full_series: bool = False) -> BatchResult:
    """Closed loop of B runs of the nonlinear model with the sample-and-hold projection controller.

    Same loop as :func:`magtune_core.sim.simulate.simulate` (``steps`` controller periods of
    ``ts``, each integrated with ``substeps`` RK4 steps with the dipole held), all runs at once.
    ``record_every``: keep every k-th controller instant in the histories (campaigns keep a
    downsampled history; figures of merit needing every step are accumulated on the fly:
    saturated and weak-field counts, divergence). ``orbit_periods`` (B,) overrides the nominal
    periods (default :func:`run_orbit_periods`). ``full_series``: also keep the true pointing
    error and |m| at every instant (what the figures of merit of a campaign need).

    Returns
    -------
    BatchResult
        Histories (B, n_rec, .) at t = k Ts for k = 0, record_every, ..., and always the last step.
    """
    B, n, S = runs.size, int(steps), int(substeps)
    per = 2 * S  # grid points per controller period (grid step h/2)
    tables = _EnvTables(runs, ts / per, per, duration=n * ts)
    T = np.asarray(orbit_periods if orbit_periods is not None else tables.periods, dtype=float)
    W0 = 2.0 * np.pi / T
    env_fn = runs.env_options[0] if runs.environment == "full" else None
    plant = _Plant(runs, drag=bool(env_fn and env_fn.drag), srp=bool(env_fn and env_fn.srp),
                   gg=True if env_fn is None else bool(env_fn.gravity_gradient),
                   geometry=_geometry(runs) if env_fn else None)
    if runs.environment == "full" and any((o.drag, o.srp, o.gravity_gradient) != (env_fn.drag, env_fn.srp,
                                          env_fn.gravity_gradient) for o in runs.env_options):
        raise ValueError("simulate_batch: all runs of a batch must switch the same disturbances on")
    h = ts / S
    hh, h6 = 0.5 * h, h / 6.0
    K = np.broadcast_to(np.asarray(runs.K, dtype=float), (B, 3, 6))
    lim = np.broadcast_to(np.asarray(runs.dipole_limit, dtype=float).reshape(B, -1), (B, 3)).T.copy()  # (3, B)
    q0 = np.asarray(runs.q0, dtype=float)
    q0 = q0 / np.linalg.norm(q0, axis=1, keepdims=True)
    y = np.vstack([q0.T, (np.array([0.0, 0.0, -1.0])[:, None] * W0[None, :]) + np.asarray(runs.dw0, float).T])
    sensors = runs.sensors if runs.sensors is not None else SensorNoise.none(B)
    noisy = sensors.any
    if noisy:
        block = _noise_blocks(sensors, n)
        mag_bias, gyro_bias = np.asarray(sensors.mag_bias, float).T, np.asarray(sensors.gyro_bias, float).T
        mag_std, gyro_std = np.asarray(sensors.mag_std, float), np.asarray(sensors.gyro_std, float)
        att_std = np.asarray(sensors.attitude_std, float)
    rec = list(range(0, n + 1, max(1, int(record_every))))
    if rec[-1] != n:
        rec.append(n)
    rec_index = {k: i for i, k in enumerate(rec)}
    R = len(rec)
    Q, W, X, M, Bb = (np.empty((B, R, d)) for d in (4, 3, 6, 3, 3))
    sat = np.zeros(B, dtype=np.int64)
    weak = np.zeros(B, dtype=np.int64)
    diverged = np.zeros(B, dtype=bool)
    min_b2 = runs.min_field**2
    if full_series:
        ang_all = np.empty((B, n + 1))
        mn_all = np.empty((B, n + 1))
    table = None
    kc = -1
    noise = None
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        for k in range(n + 1):
            if table is None or k >= kc + ENV_CHUNK:
                kc = k
                table = tables.chunk(k, min(k + ENV_CHUNK, n + 1))
            if noisy and k % NOISE_CHUNK == 0:
                noise = block()
            base = (k - kc) * per
            E = table[base]
            # true body field at t_k (the controller instant), then the sensors
            qq = y[:4]
            nq = np.sqrt(qq[0] * qq[0] + qq[1] * qq[1] + qq[2] * qq[2] + qq[3] * qq[3])
            a0, a1, a2, a3 = qq / nq
            fo0, fo1, fo2 = E[3], E[4], E[5]
            b = np.stack((
                (a0 * a0 + a1 * a1 - a2 * a2 - a3 * a3) * fo0 + 2 * (a1 * a2 + a0 * a3) * fo1 + 2 * (a1 * a3 - a0 * a2) * fo2,
                2 * (a1 * a2 - a0 * a3) * fo0 + (a0 * a0 - a1 * a1 + a2 * a2 - a3 * a3) * fo1 + 2 * (a2 * a3 + a0 * a1) * fo2,
                2 * (a1 * a3 + a0 * a2) * fo0 + 2 * (a2 * a3 - a0 * a1) * fo1 + (a0 * a0 - a1 * a1 - a2 * a2 + a3 * a3) * fo2,
            ))
            qm, wm, bm = qq, y[4:], b
            if noisy:
                nz = noise[:, k % NOISE_CHUNK, :].T  # (9, B)
                bm = b + mag_bias + mag_std * nz[0:3]
                if sensors.mag_quantum:
                    bm = np.round(bm / sensors.mag_quantum) * sensors.mag_quantum
                th = att_std * nz[3:6]
                ang = np.sqrt(th[0] * th[0] + th[1] * th[1] + th[2] * th[2])
                s = np.where(ang > 0, np.sin(ang / 2) / np.where(ang > 0, ang, 1.0), 0.5)
                qm = np.stack(_quat_mul_cols(qq, (np.cos(ang / 2), s * th[0], s * th[1], s * th[2])))
                wm = y[4:] + gyro_bias + gyro_std * nz[6:9]
            sgn = np.where(qm[0] < 0.0, -1.0, 1.0)
            x = np.stack((sgn * qm[1], sgn * qm[2], sgn * qm[3], wm[0], wm[1], wm[2] + W0))
            # projection controller m = sat(S(b)^T K x / |b|^2) (paper eq. 17), weak-field guard
            b2 = bm[0] * bm[0] + bm[1] * bm[1] + bm[2] * bm[2]
            ok = b2 >= min_b2
            u = np.einsum("bij,jb->ib", K, x)
            m = np.stack((bm[1] * u[2] - bm[2] * u[1], bm[2] * u[0] - bm[0] * u[2], bm[0] * u[1] - bm[1] * u[0])) / b2
            ms = np.minimum(np.maximum(m, -lim), lim)
            sat += ok & np.any(ms != m, axis=0)
            weak += ~ok
            ms = np.where(ok, ms, 0.0)
            if full_series:
                ang_all[:, k] = np.sqrt(a1 * a1 + a2 * a2 + a3 * a3)  # |q_vec| of the unit quaternion
                mn_all[:, k] = np.sqrt(ms[0] * ms[0] + ms[1] * ms[1] + ms[2] * ms[2])
            if k in rec_index:
                i = rec_index[k]
                Q[:, i], W[:, i], X[:, i], M[:, i], Bb[:, i] = y[:4].T, y[4:].T, x.T, ms.T, b.T
            if k == n:
                break
            # sample and hold over [t_k, t_k+1): S RK4 steps with stage environment rows
            mt = ms
            for i in range(S):
                j = base + 2 * i
                Ea, Eb, Ec = table[j], table[j + 1], table[j + 2]
                k1 = plant.rhs(Ea, y, mt)
                k2 = plant.rhs(Eb, y + hh * k1, mt)
                k3 = plant.rhs(Eb, y + hh * k2, mt)
                k4 = plant.rhs(Ec, y + h * k3, mt)
                y = y + h6 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            nq = np.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2] + y[3] * y[3])
            y = np.vstack((y[:4] / nq, y[4:]))
            bad = ~np.all(np.isfinite(y), axis=0) | (np.abs(y[4:]).max(axis=0) > DIVERGED_RATE)
            diverged |= bad
    return BatchResult(np.asarray(rec, dtype=float) * ts, Q, W, X, M, Bb, T, sat, weak, diverged, n,
                       dict(ts=ts, substeps=S, environment=runs.environment, record_every=int(record_every)),
                       pointing_error_deg(ang_all) if full_series else None, mn_all if full_series else None,
                       np.asarray(rec))


def _geometry(runs: BatchRuns):
    return runs.env_options[0].environment_config(runs.p).geometry
