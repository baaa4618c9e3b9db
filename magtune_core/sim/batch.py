"""Batched closed-loop simulation: many dispersed runs advanced together, in compiled loops.

The per-run loop (:func:`magtune_core.sim.simulate.simulate`) evaluates the plant on plain
Python floats, one run at a time (~2.7 s of CPU per full-environment orbit with its own orbit,
IGRF and environment table). Here a batch of B runs is one Dask task:

* the J2 orbits of the B runs are propagated as one DOP853 system (:class:`_BatchOrbits`);
* the attitude-independent environment (orbital frame and rate, IGRF, gravity-gradient gain,
  density, wind, Sun, shadow) is tabulated per run, in chunks of controller periods, on the grid of
  RK4 stage times ``j Ts / (2 substeps)`` -- the grid the single-run simulator uses -- by the
  compiled :func:`magtune_core.sim.batch_kernels.env_rows` (the formulas of
  :func:`magtune_core.sim.fullenv.environment_table`; the IGRF field, the density, the Sun and the
  ephemeris are evaluated exactly at the controller instants and interpolated at the intermediate
  RK4 stages with a degree-7 Lagrange polynomial: ~1e-9 relative on the field, below the rounding
  jitter of the Julian date itself, see env_rows);
* the sensors, the sample-and-hold projection controller (paper eq. 17 with per-axis saturation
  and the weak-field guard, :mod:`magtune_core.onboard.law`) and ``substeps`` classical RK4 steps
  (same stages, same fixed step, same end-of-interval quaternion renormalization as
  :meth:`AttitudeDynamics.step`) run in the compiled :func:`~magtune_core.sim.batch_kernels.closed_loop`.

Per run, the arithmetic is the single-run arithmetic (same formulas, same order of the terms up
to a few reassociations), so with zero sensor noise every run equals ``simulate`` with the same
parameters to ~1e-12 (tests/sim/test_batch.py checks 1e-9, paper and full environment).
Runs are independent: a run's result does not depend on which other runs share its batch
(sensor noise comes from the run's own generator, drawn in fixed chunks of
:data:`NOISE_CHUNK` steps; the environment nodes are fixed instants), which is what makes a
Monte Carlo campaign reproducible whatever the number of workers.

Where the time goes (cProfile, 200 runs x 1 orbit, full environment, one process): before the
compiled loops 61 s (IGRF 27 %, rest of the environment 30 %, plant right-hand side ~40 %);
now ~8 s (environment ~55 %, closed loop ~30 %, orbit propagation + dense output ~15 %).

Sensors: the models of :mod:`magtune_core.design.sensors`, the ``attitude_sensors`` node's:
magnetometer ``b_meas = M b + bias + N(0, std^2)`` (optionally quantized), attitude
``q_meas = q (x) exp(dtheta/2)`` with ``dtheta ~ N(0, std^2 I)`` in body axes, the Farrenkopf
gyro (white noise, angle and rate random walk; its bias walk computed per noise block by
:func:`magtune_core.design.sensors.gyro_bias_walk`, the formula the node runs), from the same
rows of normals as the node for the same seed. The controller's linear state (eq. 14) is built
from ``q_meas, w_meas`` and its dipole from ``b_meas``; the plant feels the true field.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.integrate import solve_ivp

from ..design.params import SpacecraftParams
from ..design.sensors import AUX_NORMALS, GYRO_U, NORMALS_PER_STEP, Gyro, aux_rng, draw, gyro_bias_walk, gyro_from
from ..env.environment import Environment
from ..env.igrf import IGRF
from ..env.orbit import eci_to_orbital, initial_state, orbital_rate
from ..env.sun import shadow_cylindrical
from ..onboard.bdot import FieldDerivativeFilter, bdot_gain, geomagnetic_inclination
from ..onboard.law import DEFAULT_MIN_FIELD
from ..onboard.mekf import MAG_BIAS_STD
from ..onboard.mekf_kernel import kernel_state, with_validity
from ..onboard.modes import DETUMBLE, MODES, ModeParams
from ..onboard.modes_kernel import GUARDS, MODE_CODE, kernel_params
from ..onboard.params import TS_DEFAULT, VALIDITY_FIELDS, WATCH_FIELDS
from ..onboard.sensor_watch import SensorWatchParams
from ..onboard.sensor_watch import new_state as new_watch_state
from ..onboard.torquers import NONE as NO_TORQUERS
from ..onboard.torquers import Torquers
from .batch_kernels import (
    Chunk,
    Controller,
    EstimatorIO,
    Modes,
    Outputs,
    Plant,
    Sensors,
    closed_loop,
    env_rows,
    igrf_arrays,
    orbit_rhs,
)
from .fault_kernels import kernel_faults
from .fullenv import FullEnvironmentOptions, _environment, environment_table, nominal_orbit_period
from .metrics import pointing_error_deg
from .substeps import Substeps

#: Sensor noise is drawn per run in blocks of this many controller steps (design.sensors.NORMALS_PER_STEP
#: normals per step: magnetometer, attitude, gyro), so the stream a run sees does not depend on its batch.
NOISE_CHUNK = 1024
#: Controller steps whose environment is computed at once (bounded memory: ~15 x 8 B x
#: (2 substeps x CHUNK + 1) per run).
ENV_CHUNK = 512
_VALIDITY = {f.name: f.default for f in VALIDITY_FIELDS}
_WATCH = {f.name: f.default for f in WATCH_FIELDS}
assert NOISE_CHUNK % ENV_CHUNK == 0
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
    gyro_arw: np.ndarray | None = None  #: (B,) angle random walk sigma_v [rad/s^0.5] (adds to gyro_std^2 Ts)
    gyro_rrw: np.ndarray | None = None  #: (B,) rate random walk sigma_u [rad/s^1.5]
    mag_matrix: np.ndarray | None = None  #: (B, 3, 3) magnetometer scale factor and misalignment (None: I)

    @classmethod
    def none(cls, n: int) -> "SensorNoise":
        """Perfect sensors for ``n`` runs (the single-run ``simulate`` case)."""
        z, z3 = np.zeros(n), np.zeros((n, 3))
        return cls(z, z3, z, z3, z, [0] * n)

    @property
    def any(self) -> bool:
        """True if any run has noise, a bias or quantization (else the compiled loop skips the sensors)."""
        return bool(np.any(self.mag_std) or np.any(self.mag_bias) or np.any(self.gyro_std) or np.any(self.gyro_bias)
                    or np.any(self.attitude_std) or self.mag_quantum or np.any(self._per_run(self.gyro_arw))
                    or np.any(self._per_run(self.gyro_rrw)) or self.mag_matrix is not None)

    def _per_run(self, v) -> np.ndarray:
        return np.broadcast_to(np.asarray(0.0 if v is None else v, float), (len(self.seeds),))

    def gyros(self, ts: float) -> list[Gyro]:
        """Each run's :class:`~magtune_core.design.sensors.Gyro` (:func:`~magtune_core.design.sensors.gyro_from`)."""
        std, arw, rrw = (self._per_run(v) for v in (self.gyro_std, self.gyro_arw, self.gyro_rrw))
        bias = np.asarray(self.gyro_bias, float).reshape(-1, 3)
        return [gyro_from(std[i], arw[i], rrw[i], bias[i], ts) for i in range(len(self.seeds))]


@dataclass(frozen=True)
class BatchModes:
    """Fly the flight modes in the batch (:mod:`magtune_core.onboard.modes`, B-dot of :mod:`magtune_core.onboard.bdot`).

    ``params`` the mode machine's thresholds and timers; ``bdot_gain`` k [N m s] (0: the Avanzini-Giulietti
    rule :func:`~magtune_core.onboard.bdot.bdot_gain` from the nominal spacecraft ``BatchRuns.p``: the flight
    software knows the nominal inertia, not a run's dispersed one); ``bdot_cutoff`` of the derivative filter
    [rad/s]; every run starts in ``initial_mode``. The fields of ``MODE_FIELDS`` and ``BDOT_FIELDS``.
    """

    params: ModeParams = ModeParams()
    bdot_gain: float = 0.0
    bdot_cutoff: float = 0.2
    normalized: bool = True
    initial_mode: str = DETUMBLE

    def gain(self, p: SpacecraftParams) -> float:
        """The B-dot gain flown [N m s] (``bdot_gain`` or the rule, as simulate_modes' ``bdot_k``)."""
        return float(self.bdot_gain or bdot_gain(p.orbit_rate, geomagnetic_inclination(math.radians(p.inclination_deg)),
                                                 p.inertia))


@dataclass(frozen=True)
class BatchEstimator:
    """Fly the attitude estimator in the batch: the controller reads the MEKF's estimate
    (:mod:`magtune_core.onboard.mekf_kernel`, equal to :class:`magtune_core.onboard.estimator.MekfStream`)
    instead of the truth plus attitude noise, as ``magtune sil --attitude estimator`` does.

    The filter's model of the sensors (``mag_noise_std`` [T], ``gyro_arw`` sigma_v, ``gyro_rrw`` sigma_u,
    ``sun_noise_std`` [rad]) and tuning are the fields of the node's ``ESTIMATOR_FIELDS``; the truth's sun
    sensor (whole sphere, lit by the cylindrical shadow) has ``sun_sensor_std`` [rad]. On-board reference
    vectors: the environment's field and Sun of date at the true position (the node takes them at the
    position fix: 10 m moves the IGRF field by ~1e-10 T, 1e-3 of the magnetometer noise), the orbital
    axes of the true orbit state.
    """

    mag_noise_std: float = 100e-9
    gyro_arw: float = 1e-4
    gyro_rrw: float = 1e-6
    sun_noise_std: float = math.radians(0.5)
    gate_probability: float = 0.9999
    initial_bias_std: float = 5e-4
    init_angle: float = math.radians(10.0)
    initial_mag_bias_std: float = MAG_BIAS_STD
    mag_bias_rw: float = 0.0
    sun_sensor_std: float = math.radians(0.5)
    #: the estimate's validity (onboard.validity; VALIDITY_FIELDS' defaults): off unless the modes fly it
    validity_gate: bool = _VALIDITY["validity_gate"]
    valid_sigma: float = _VALIDITY["valid_sigma"]
    valid_nis_tau: float = _VALIDITY["valid_nis_tau"]
    valid_nis_limit: float = _VALIDITY["valid_nis_limit"]
    reinit_time: float = _VALIDITY["reinit_time"]
    #: the sensor watch and its recovery (onboard.sensor_watch; WATCH_FIELDS' defaults), as the node runs them
    sensor_watch: bool = _WATCH["sensor_watch"]
    watch_arm_rate: float = _WATCH["watch_arm_rate"]
    recover_mag_bias_std: float = _WATCH["recover_mag_bias_std"]
    recover_gyro_bias_std: float = _WATCH["recover_gyro_bias_std"]
    recover_attitude_std: float = _WATCH["recover_attitude_std"]
    #: record the torquer watch's inputs at every step (BatchResult.torquer_inputs, the node's watch_torquers; replayed
    #: after the run by sim.batch_torquer, the watch having no feedback). Off unless asked, unlike the node's field:
    #: ~105 B per run-step and the replay's CPU
    torquer_watch: bool = False


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
        """Number of runs B (the rows of ``q0``)."""
        return int(np.asarray(self.q0).shape[0])


@dataclass
class TorquerInputs:
    """What the torquer watch (:class:`magtune_core.onboard.torquer_watch.TorquerWatch`) reads at every controller
    instant t_k = k ``ts`` of every run, as the attitude_estimator node feeds it (``watch_torquers``): arrays
    (B, N + 1, .) float64 and ``active`` (B, N + 1) bool. Recorded by :func:`simulate_batch` with
    ``BatchEstimator(torquer_watch=True)``; replayed by :func:`magtune_core.sim.batch_torquer.replay`."""

    w: np.ndarray  #: (B, N + 1, 3) gyro sample of t_k minus the estimator's bias estimate at k [rad/s] (nan: no state)
    b: np.ndarray  #: (B, N + 1, 3) measured field at t_k [T] (the magnetometer sample the filter took)
    m_prev: np.ndarray  #: (B, N + 1, 3) dipole commanded at t_(k-1), as published (after saturation) [A m^2] (nan at k = 0)
    q: np.ndarray  #: (B, N + 1, 4) the estimate w.r.t. the orbital axes, scalar first (nan: no state)
    #: (B, N + 1) a valid estimate, a mode onboard.torquer_watch.watch_mode lets the watch run in (POINTING or an
    #: ACQUISITION after it; the manager's last, the decision of k - 1; or no modes), a command at k - 1: the node's rule
    active: np.ndarray
    ts: float  #: controller period [s]

    @property
    def shape(self) -> tuple:
        """(B, N + 1): runs and instants."""
        return tuple(self.active.shape)

    @property
    def stepped(self) -> np.ndarray:
        """(B, N + 1) bool: the filter had a state (after its coarse fix, not between a restart and the next fix):
        the instants at which the node steps its watch (it skips the others)."""
        return np.isfinite(self.q[..., 0])


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
    #: every controller instant, (B, N+1); ``record_index`` the instants kept in the histories;
    #: ``saturated`` (B, N+1) bool: the command of that instant saturated an axis
    pointing_deg: np.ndarray | None = None
    m_norm: np.ndarray | None = None
    record_index: np.ndarray | None = None
    saturated: np.ndarray | None = None
    #: with modes (:class:`BatchModes`): ``mode`` (B, N+1) int8 mode code after each instant's decision (with
    #: ``full_series``; code = index in onboard.modes.MODES), ``transitions`` (B,) count, ``detumble_time`` the
    #: first instant DETUMBLE was left and ``pointing_time`` the first instant POINTING was entered [s] (nan:
    #: never), ``final_mode`` (B,) code at the last instant
    mode: np.ndarray | None = None
    transitions: np.ndarray | None = None
    detumble_time: np.ndarray | None = None
    pointing_time: np.ndarray | None = None
    final_mode: np.ndarray | None = None
    #: with an estimator (:class:`BatchEstimator`): ``est_error``, ``est_sigma`` (B, N+1, 3) float32 estimation error
    #: dtheta and sqrt(P_ii) [rad] and ``est_nees`` (B, N+1) (with ``full_series``; nan before the fix), ``est_k0``
    #: (B,) the coarse fix's step, ``no_attitude_steps`` (B,), ``est_counts`` (B, 4) mag accepted / rejected,
    #: sun accepted / rejected; at the recorded instants ``est_q`` (B, R, 4) body w.r.t. the filter's reference
    #: (ECI; paper: orbital axes at t = 0), ``est_bias`` (B, R, 3), ``est_P`` (B, R, 9, 9) of [dtheta; db; dm],
    #: ``est_mag_bias`` (B, R, 3) the magnetometer-bias estimate [T]
    est_error: np.ndarray | None = None
    est_sigma: np.ndarray | None = None
    est_nees: np.ndarray | None = None
    est_k0: np.ndarray | None = None
    no_attitude_steps: np.ndarray | None = None
    est_counts: np.ndarray | None = None
    est_q: np.ndarray | None = None
    est_bias: np.ndarray | None = None
    est_P: np.ndarray | None = None
    est_mag_bias: np.ndarray | None = None
    #: the sensor watch (with an estimator): ``fdir_code`` (B,) the first verdict (0 none, onboard.sensor_watch
    #: MAG_FAULT, GYRO_FAULT, MAG_AMBIGUOUS), ``fdir_time`` (B,) its time [s] (nan: none), ``fdir_count`` (B,)
    #: verdicts, ``fdir_back`` (B,) units reported back
    fdir_code: np.ndarray | None = None
    fdir_time: np.ndarray | None = None
    fdir_count: np.ndarray | None = None
    fdir_back: np.ndarray | None = None
    #: with ``BatchEstimator(torquer_watch=True)``: the torquer watch's inputs at every instant (:class:`TorquerInputs`)
    torquer_inputs: TorquerInputs | None = None


def _as3x3(I: np.ndarray, n: int) -> np.ndarray:
    I = np.asarray(I, dtype=float)
    if I.ndim == 1:
        I = np.broadcast_to(I, (n, 3))
    if I.ndim == 2 and I.shape == (n, 3):
        return np.einsum("bi,ij->bij", I, np.eye(3))
    if I.shape == (3, 3):
        return np.broadcast_to(I, (n, 3, 3)).copy()
    return I.reshape(n, 3, 3)


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
        return orbit_rhs(y, self.zonal)  # gravity_acceleration of every run, compiled

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
        self.runs, self._buf = runs, None
        if runs.environment == "full":
            unique = list(dict.fromkeys(runs.env_options))
            self.index = np.array([unique.index(o) for o in runs.env_options])
            # the Environment's inertia only serves its own torque helpers (unused here): the
            # Environment of the base spacecraft is the environment of every run on that orbit
            self.envs, periods = [], []
            cfgs = [o.environment_config(runs.p) for o in unique]
            self.orbits = None
            # nodes of the interpolated IGRF field, density and Sun (batch_kernels.env_rows): the controller
            # instants, so the control law reads exactly the single-run field
            self.stride = self.per_step
            self.last_node = 1 << 60
            if len(unique) == 1:  # one orbit: the single-run Environment itself (it extends itself)
                self.envs = [_environment(cfgs[0])]
            else:
                duration = max(6 * 5700.0, duration + 10.0 + 8 * self.stride * self.dt)
                self.orbits = _BatchOrbits([c.orbit for c in cfgs], duration)
                self.envs = [_ViewEnvironment(c, _OrbitView(self.orbits, i, c.orbit)) for i, c in enumerate(cfgs)]
                self.last_node = int(self.orbits.t_end / (self.dt * self.stride) * (1 - 1e-12))
            self.igrf = [igrf_arrays(env.igrf) for env in self.envs]
            for env in self.envs:
                periods.append(_nominal_period(env))
            self.periods = np.array(periods)[self.index]
            self.field_fns = [None if o.field == "igrf" else runs.p.field(o.field) for o in unique]
        else:
            self.field = runs.p.field()
            self.W0 = runs.p.orbit_rate
            self.periods = np.full(runs.size, float(runs.p.orbit_period))
            self.index = np.zeros(runs.size, dtype=np.int64)

    def _buffer(self, npts: int) -> np.ndarray:
        """(U, npts, 15) rows reused from chunk to chunk (a fresh 100-MB table per chunk of a 250-run batch
        costs its page faults every time); each chunk's rows are read before the next chunk's are written."""
        if self._buf is None or self._buf.shape[1] < npts:
            self._buf = np.empty((len(self.envs), npts + 64, 15))
        return self._buf[:, :npts]

    def chunk(self, k0: int, k1: int) -> np.ndarray:
        """Rows for grid indices k0*per_step .. k1*per_step, shape (U, npts, 15): one table per distinct
        environment (run b reads ``[self.index[b]]``; U = 1 for "paper"), each contiguous (the compiled
        loop walks one run's rows in order)."""
        ja, jb = k0 * self.per_step, k1 * self.per_step
        if self.runs.environment == "full":
            # the points plus the interpolation nodes around them (batch_kernels.env_rows)
            st = self.stride
            last = self.last_node
            lo = st * max(min(ja // st - 3, last - 7), 0)
            hi = max(jb, st * min(jb // st + 4, last))
            j = np.arange(lo, hi + 1)
            t = j * self.dt
            out = self._buffer(t.size)
            nodes = t[::st]  # lo is a node: the ephemeris is evaluated there only
            Y = self.orbits.states(nodes) if self.orbits is not None else None
            Yi = np.empty((6, t.size))
            for i, (env, ff) in enumerate(zip(self.envs, self.field_fns)):
                if ff is None:  # IGRF: the compiled rows (batch_kernels.env_rows ~ environment_table)
                    if Y is None:
                        r, v = env.orbit.state(nodes)
                        Yi[:3, ::st], Yi[3:, ::st] = r.T, v.T
                    else:
                        Yi[:, ::st] = Y[i]
                    cfg = env.config
                    env_rows(Yi, t, lo, st, last, ja - lo, jb - lo + 1, float(env.jd0), *self.igrf[i], int(cfg.igrf_degree),
                             int(cfg.orbit.zonal_degree), bool(cfg.drag), bool(cfg.srp), float(cfg.hp_exponent),
                             out[i])
                else:
                    out[i] = environment_table(env, t, ff)
            return out[:, ja - lo:jb - lo + 1]
        t = np.arange(ja, jb + 1) * self.dt
        out = np.zeros((1, t.size, 15))
        out[0, :, 2] = -self.W0
        out[0, :, 3:6] = np.asarray(self.field(t), dtype=float).reshape(t.size, 3)
        out[0, :, 6] = 3.0 * self.W0**2
        return out


def _estimator_cols(tables: "_EnvTables", k0: int, k1: int, ts: float) -> np.ndarray:
    """(U, k1 - k0, 13) the estimator's rows at the controller instants k0 .. k1-1 (batch_kernels.EstimatorIO.cols):
    R_oi row-major, unit satellite->Sun in ECI and lit (cylindrical shadow, env.sun) of every distinct
    environment; in the paper environment R_oi = R_z(W0 t) (reference: the orbital axes at t = 0), no Sun."""
    t = np.arange(k0, k1) * ts
    runs = tables.runs
    if runs.environment != "full":
        c, s = np.cos(runs.p.orbit_rate * t), np.sin(runs.p.orbit_rate * t)
        out = np.zeros((1, t.size, 13))
        out[0, :, 0], out[0, :, 1], out[0, :, 3], out[0, :, 4], out[0, :, 8] = c, -s, s, c, 1.0
        return out
    out = np.empty((len(tables.envs), t.size, 13))
    for i, env in enumerate(tables.envs):
        r, v = env.orbit.state(t)
        sun = env.sun_eci(t)
        d = sun - r
        out[i, :, :9] = eci_to_orbital(r, v).reshape(t.size, 9)
        out[i, :, 9:12] = d / np.linalg.norm(d, axis=-1, keepdims=True)
        out[i, :, 12] = shadow_cylindrical(r, sun) > 0.5
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
    orbital-frame rate (:func:`magtune_core.sim.fullenv.nominal_orbit_period`, as ``simulate`` uses).

    Returns
    -------
    ndarray (B,)
        T per run [s] (the controller's W0 = 2 pi / T, paper eq. 14).
    """
    if runs.environment == "full":
        periods = {o: nominal_orbit_period(runs.p, o) for o in dict.fromkeys(runs.env_options)}
        return np.array([periods[o] for o in runs.env_options])
    return np.full(runs.size, float(runs.p.orbit_period))


def _noise_blocks(sensors: SensorNoise, ts: float):
    """Generator of the per-run blocks: (normals (B, CHUNK, 12), gyro (beta_k + beta_k+1)/2 (B, CHUNK, 3)),
    the Farrenkopf bias walk carried from block to block (design.sensors.gyro_bias_walk)."""
    gens = [np.random.default_rng(s) for s in sensors.seeds]
    gyros = sensors.gyros(ts)
    beta = [np.asarray(g.bias, dtype=float) for g in gyros]

    def block():
        normals = np.stack([draw(g, NOISE_CHUNK) for g in gens])  # (B, CHUNK, NORMALS_PER_STEP)
        avg = np.empty((len(gens), NOISE_CHUNK, 3))
        for i, g in enumerate(gyros):
            walk = gyro_bias_walk(g, ts, beta[i], normals[i, :, GYRO_U])
            avg[i] = 0.5 * (walk[1:] + walk[:-1])
            beta[i] = walk[-1]
        return normals, avg

    return block


def _aux_blocks(sensors: SensorNoise):
    """Generator of the auxiliary sensors' normals (B, CHUNK, 9) per block, from design.sensors.aux_rng(seed)
    of every run (the node's second generator: the sun sensor reads columns 0-2)."""
    gens = [aux_rng(s) for s in sensors.seeds]
    return lambda: np.stack([draw(g, NOISE_CHUNK, AUX_NORMALS) for g in gens])


def simulate_batch(runs: BatchRuns, *, ts: float = TS_DEFAULT, steps: int, substeps: int = 2, max_substeps: int = 0,
                   record_every: int = 1, orbit_periods=None, full_series: bool = False,
                   modes: BatchModes | None = None, estimator: BatchEstimator | None = None,
                   torquers: Torquers = NO_TORQUERS, faults=()) -> BatchResult:
    """Closed loop of B runs of the nonlinear model with the sample-and-hold projection controller.

    Same loop as :func:`magtune_core.sim.simulate.simulate` (``steps`` controller periods of
    ``ts``, each integrated with ``substeps`` RK4 steps with the dipole held), all runs at once.
    ``record_every``: keep every k-th controller instant in the histories (campaigns keep a
    downsampled history; figures of merit needing every step are accumulated on the fly:
    saturated and weak-field counts, divergence). ``orbit_periods`` (B,) overrides the nominal
    periods (default :func:`run_orbit_periods`). ``full_series``: also keep the true pointing
    error and |m| at every instant (what the figures of merit of a campaign need).
    Control law of paper eq. (17) with per-axis saturation; set-up of paper section 5.
    ``modes``: fly the flight modes (DETUMBLE: B-dot, ACQUISITION / POINTING: eq. 17, SAFE: zero), as
    :func:`magtune_core.sim.modes_loop.simulate_modes` does for one run; None: eq. 17 throughout (bit
    for bit the loop without modes). ``torquers`` (onboard.torquers.Torquers): as the SIL's nodes, every run.
    ``max_substeps`` > ``substeps``: each run's sub-steps re-chosen every step from its rate (sim.substeps.Substeps).
    ``faults``: injected faults (design.faults: Fault objects or spec strings), the same for every run
    (sim.fault_kernels: the kinds the batch flies).

    Returns
    -------
    BatchResult
        Histories (B, n_rec, .) at t = k Ts for k = 0, record_every, ..., and always the last step.
    """
    torquers.check(ts, "simulate_batch")
    fk = kernel_faults(faults, ts)
    rule = Substeps.ladder(ts, int(substeps), max(int(substeps), int(max_substeps)), torquers)  # switch-off on the grid
    B, n, S, per = runs.size, int(steps), rule.most, 2 * rule.most  # per: grid points per period (finest h / 2)
    tables = _EnvTables(runs, ts / per, per, duration=n * ts)
    T = np.asarray(orbit_periods if orbit_periods is not None else tables.periods, dtype=float)
    W0 = 2.0 * np.pi / T
    env_fn = runs.env_options[0] if runs.environment == "full" else None
    if runs.environment == "full" and any((o.drag, o.srp, o.gravity_gradient) != (env_fn.drag, env_fn.srp,
                                          env_fn.gravity_gradient) for o in runs.env_options):
        raise ValueError("simulate_batch: all runs of a batch must switch the same disturbances on")
    drag, srp = bool(env_fn and env_fn.drag), bool(env_fn and env_fn.srp)
    gg = True if env_fn is None else bool(env_fn.gravity_gradient)
    A, cp, cd, es, ed = np.zeros(3), np.zeros(3), 0.0, 0.0, 0.0
    if env_fn is not None:
        geo = _geometry(runs)
        A = np.ascontiguousarray(np.asarray(geo.faces()[1][:3], dtype=float))
        cp = np.asarray(geo.cp_offset, dtype=float)
        cd, es, ed = float(geo.cd), float(geo.spec_reflect), float(geo.diff_reflect)
    I = np.ascontiguousarray(_as3x3(runs.inertia, B))
    J = np.ascontiguousarray(np.linalg.inv(I))
    hw = np.asarray(runs.p.wheel_momentum, dtype=float).reshape(3).copy()
    mres = np.ascontiguousarray(np.broadcast_to(np.asarray(runs.residual_dipole, float), (B, 3)).T)
    K = np.ascontiguousarray(np.broadcast_to(np.asarray(runs.K, dtype=float), (B, 3, 6)))
    lim = np.broadcast_to(np.asarray(runs.dipole_limit, dtype=float).reshape(B, -1), (B, 3)).T.copy()  # (3, B)
    q0 = np.asarray(runs.q0, dtype=float)
    q0 = q0 / np.linalg.norm(q0, axis=1, keepdims=True)
    y = np.ascontiguousarray(np.vstack([q0.T, (np.array([0.0, 0.0, -1.0])[:, None] * W0[None, :])
                                        + np.asarray(runs.dw0, float).T]))
    sensors = runs.sensors if runs.sensors is not None else SensorNoise.none(B)
    noisy = sensors.any or estimator is not None  # the estimator draws the rows even for perfect sensors
    mag_bias = np.ascontiguousarray(np.asarray(sensors.mag_bias, float).reshape(B, 3).T)
    mag_std, att_std = (np.ascontiguousarray(np.broadcast_to(np.asarray(v, float), (B,)))
                        for v in (sensors.mag_std, sensors.attitude_std))
    mag_on = sensors.mag_matrix is not None
    mag_M = np.ascontiguousarray(np.broadcast_to(np.asarray(sensors.mag_matrix if mag_on else np.eye(3), float),
                                                 (B, 3, 3)))
    gyro_white = np.array([g.white_std(ts) for g in sensors.gyros(ts)])
    block = _noise_blocks(sensors, ts) if noisy else None
    noise, gyro_avg = np.zeros((B, 1, NORMALS_PER_STEP)), np.zeros((B, 1, 3))
    rec = list(range(0, n + 1, max(1, int(record_every))))
    if rec[-1] != n:
        rec.append(n)
    rec_slot = np.full(n + 1, -1, dtype=np.int64)
    rec_slot[rec] = np.arange(len(rec))
    R = len(rec)
    Q, W, X, M, Bb = (np.empty((B, R, d)) for d in (4, 3, 6, 3, 3))
    sat, weak, diverged = np.zeros(B, dtype=np.int64), np.zeros(B, dtype=np.int64), np.zeros(B, dtype=bool)
    min_b2 = runs.min_field**2
    ang_all = np.empty((B, n + 1) if full_series else (B, 1))
    mn_all = np.empty_like(ang_all)  # |m| per step
    sat_all = np.zeros(ang_all.shape, dtype=np.bool_)
    index = np.ascontiguousarray(tables.index, dtype=np.int64)
    plant = Plant(I, J, hw, mres, gg, drag, srp, A, cp, cd, es, ed)
    law_lim, scale, weights, coupling = _torquer_arrays(torquers, lim, ts, rule, B)
    ctrl = Controller(K, law_lim, W0, min_b2, scale, weights)
    sens = Sensors(noisy, noise, 0, mag_bias, mag_std, float(sensors.mag_quantum or 0.0), mag_on, mag_M, att_std,
                   gyro_avg, gyro_white, *coupling)
    out = Outputs(sat, weak, diverged, DIVERGED_RATE, bool(full_series), ang_all, mn_all, rec_slot, Q, W, X, M, Bb,
                  sat_all)
    mstate, levels = _modes_state(modes, runs, B, n, ts, bool(full_series)), _levels(rule)
    # controller steps in chunks of ENV_CHUNK (a divisor of NOISE_CHUNK): one environment table and one
    # compiled call per chunk (batch_kernels.closed_loop: sensors, controller, S RK4 steps per period)
    est, eio, aux_block = _estimator_state(estimator, sensors, B, n, R, ts, bool(full_series))
    for kc in range(0, n + 1, ENV_CHUNK):
        k1 = min(kc + ENV_CHUNK, n + 1)
        table = tables.chunk(kc, k1)
        if noisy and kc % NOISE_CHUNK == 0:
            noise, gyro_avg = block()
            sens = sens._replace(noise=noise, gyro_avg=gyro_avg, noise_k0=kc)
        eio = _estimator_chunk(est, eio, tables, kc, k1, ts, aux_block)
        closed_loop(y, Chunk(table, index, kc, kc, k1, n, per, *levels), plant, ctrl, sens, out, mstate, est, eio, fk)
    res = BatchResult(np.asarray(rec, dtype=float) * ts, Q, W, X, M, Bb, T, sat, weak, diverged, n,
                      dict(ts=ts, substeps=S, substep_levels=rule.levels, environment=runs.environment, record_every=int(record_every)),
                      pointing_error_deg(ang_all) if full_series else None, mn_all if full_series else None,
                      np.asarray(rec), sat_all if full_series else None)
    return _with_modes(_with_estimator(res, est, eio, full_series), mstate, full_series)


def _torquer_arrays(torquers: Torquers, lim: np.ndarray, ts: float, rule: Substeps, B: int):
    """The kernel's view of :class:`~magtune_core.onboard.torquers.Torquers`: the laws' limits (3, B), the
    drive's scale, the sub-step weights per level (levels, most; zero-padded) and (coupled, g C, the last
    drive (3, B))."""
    g = torquers.sample_factor()
    wts = np.zeros((len(rule.levels), rule.most))
    for i, s in enumerate(rule.levels):
        wts[i, :s] = torquers.substep_weights(ts, s)
    return (np.ascontiguousarray(torquers.law_limit(lim, ts)), float(torquers.command_scale(ts)), wts,
            (torquers.coupled and g > 0, np.ascontiguousarray(g * torquers.matrix), np.zeros((3, B))))


def _levels(rule: Substeps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kernel's view of :class:`~magtune_core.sim.substeps.Substeps`: the levels (L,) int64, the squared
    rate each covers (L,) and the RK4 step Ts / level (L,) (the division dynamics.step does)."""
    return (np.array(rule.levels, dtype=np.int64), rule.thresholds(),
            np.array([rule.ts / s for s in rule.levels]))


def _estimator_state(estimator: BatchEstimator | None, sensors: SensorNoise, B: int, n: int, R: int, ts: float,
                     full: bool):
    """The kernel's filters and EstimatorIO (placeholders the kernel does not read without an estimator)
    and the auxiliary normals' block generator."""
    e = estimator
    if e is None:
        z1, z3 = np.zeros((1, 1, 13)), np.zeros((1, 1, 9))
        est = kernel_state(1, ts, arw=1.0, rrw=1.0, mag_cov=np.eye(3), sun_std=1.0, on=False)
        return est, EstimatorIO(z1, z3, np.zeros(1), np.zeros((1, 1, 3), np.float32), np.zeros((1, 1, 3), np.float32),
                                np.zeros((1, 1), np.float32), np.zeros(1, np.int64), np.zeros((1, 1, 4)),
                                np.zeros((1, 1, 3)), np.zeros((1, 1, 9, 9)), np.zeros((1, 1, 3)),
                                *_watch_arrays(None, None, 1), *_torquer_watch_arrays(False, 1, 0)), None
    est = kernel_state(B, ts, arw=e.gyro_arw, rrw=e.gyro_rrw, mag_cov=e.mag_noise_std**2 * np.eye(3),
                       sun_std=e.sun_noise_std, gate_probability=e.gate_probability, bias_std=e.initial_bias_std,
                       init_angle=e.init_angle, mag_bias_std=e.initial_mag_bias_std, mag_bias_rw=e.mag_bias_rw)
    if e.validity_gate:
        est = with_validity(est, e.valid_sigma, e.valid_nis_tau, e.valid_nis_limit, e.reinit_time)
    shape = (B, n + 1) if full else (B, 1)
    eio = EstimatorIO(np.zeros((1, 1, 13)), np.zeros((B, 1, 9)), np.full(B, float(e.sun_sensor_std)),
                      np.full(shape + (3,), np.nan, np.float32), np.full(shape + (3,), np.nan, np.float32),
                      np.full(shape, np.nan, np.float32), np.zeros(B, np.int64), np.full((B, R, 4), np.nan),
                      np.full((B, R, 3), np.nan), np.full((B, R, 9, 9), np.nan), np.full((B, R, 3), np.nan),
                      *_watch_arrays(e, est, B), *_torquer_watch_arrays(e.torquer_watch, B, n))
    return est, eio, _aux_blocks(sensors)


def _watch_arrays(e: BatchEstimator | None, est, B: int) -> tuple:
    """EstimatorIO's sensor-watch fields: the watch of the node (SensorWatchParams.of_stream: the filter's ts, sigma_u
    and gates) for every run, or an empty parameter array (no watch)."""
    on = e is not None and e.sensor_watch
    wp = SensorWatchParams(est.ts, e.gyro_rrw, est.gate_mag, est.gate_sun).array() if on else np.zeros(0)
    rec = np.array([e.recover_mag_bias_std, e.recover_gyro_bias_std, e.recover_attitude_std]) if on else np.zeros(3)
    return (np.tile(new_watch_state(), (B, 1)), wp, float(e.watch_arm_rate) if on else 0.0, rec,
            np.zeros(B, np.int64), np.full(B, np.nan), np.zeros(B, np.int64), np.zeros(B, np.int64))


def _torquer_watch_arrays(on: bool, B: int, n: int) -> tuple:
    """EstimatorIO's torquer-watch fields: (on, w, b, m_prev, q, active, armed), (B, n + 1, .) nan and False when ``on``,
    else (1, 1, .) placeholders the kernel does not write."""
    B, N = (B, n + 1) if on else (1, 1)
    return (bool(on), np.full((B, N, 3), np.nan), np.full((B, N, 3), np.nan), np.full((B, N, 3), np.nan),
            np.full((B, N, 4), np.nan), np.zeros((B, N), dtype=np.bool_), np.zeros(B, dtype=np.bool_))


def _estimator_chunk(est, eio: EstimatorIO, tables: _EnvTables, kc: int, k1: int, ts: float, aux_block) -> EstimatorIO:
    """The estimator's inputs of the chunk kc .. k1-1: reference rows, and a new block of auxiliary normals
    at every NOISE_CHUNK (unchanged without an estimator)."""
    if not est.on:
        return eio
    if kc % NOISE_CHUNK == 0:
        eio = eio._replace(aux=aux_block())
    return eio._replace(cols=_estimator_cols(tables, kc, k1, ts))


def _with_estimator(res: BatchResult, est, eio: EstimatorIO, full: bool) -> BatchResult:
    """``res`` with the estimator's outputs (BatchResult.est_error and the rest; none without an estimator)."""
    if not est.on:
        return res
    if full:
        res.est_error, res.est_sigma, res.est_nees = eio.err, eio.sig, eio.nees
    res.est_k0, res.no_attitude_steps, res.est_counts = est.k0.copy(), eio.no_att.copy(), est.counts.copy()
    res.est_q, res.est_bias, res.est_P, res.est_mag_bias = eio.Qe, eio.be, eio.Pe, eio.me
    if eio.wp.size:
        res.fdir_code, res.fdir_time, res.fdir_count, res.fdir_back = eio.fdir_code, eio.fdir_t, eio.fdir_n, eio.fdir_back
    if eio.tw_on:
        res.torquer_inputs = TorquerInputs(eio.tw_w, eio.tw_b, eio.tw_m, eio.tw_q, eio.tw_act, float(est.ts))
    return res


def _with_modes(res: BatchResult, mstate: Modes, full: bool) -> BatchResult:
    """``res`` with the mode outputs of the kernel state ``mstate`` (BatchResult.mode and the rest; none
    when the modes are off)."""
    if not mstate.on:
        return res
    res.mode = mstate.mode_all if full else None
    res.transitions, res.detumble_time, res.pointing_time = mstate.n_tr, mstate.t_detumble, mstate.t_pointing
    res.final_mode = mstate.mode.copy()
    return res


def _modes_state(modes: BatchModes | None, runs: BatchRuns, B: int, n: int, ts: float, full: bool) -> Modes:
    """The kernel's :class:`~magtune_core.sim.batch_kernels.Modes` (``on`` False with ``modes`` None)."""
    on = modes is not None
    m = modes or BatchModes()
    if m.initial_mode not in MODES:
        raise ValueError(f"BatchModes: initial_mode must be one of {', '.join(MODES)}, got {m.initial_mode!r}")
    k = np.full(B, m.gain(runs.p) if on else 0.0)
    return Modes(on, kernel_params(m.params), k, bool(m.normalized), float(runs.min_field),
                 FieldDerivativeFilter(float(ts), float(m.bdot_cutoff)).pole, float(ts), np.full(B, MODE_CODE[m.initial_mode], dtype=np.int64),
                 np.full((B, len(GUARDS)), np.nan), np.zeros((B, 3)), np.zeros((B, 3)), np.ones(B, dtype=np.bool_),
                 np.zeros(B, dtype=np.int64), np.full(B, np.nan), np.full(B, np.nan),
                 np.full((B, n + 1) if (on and full) else (B, 1), -1, dtype=np.int8))


def _geometry(runs: BatchRuns):
    return runs.env_options[0].environment_config(runs.p).geometry
