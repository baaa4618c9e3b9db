"""Offline closed-loop simulation (no ROS) of the digital projection-based controller.

Paper section 5: the controller is implemented "in digital form, using a conventional sample
and hold scheme" with period Ts; the plant is the nonlinear model of ``dynamics`` (rigid body,
pitch wheel, gravity gradient, residual dipole 1 A m^2 per axis, eq. 26 field), integrated with
fixed-step RK4 so that runs are bit-for-bit reproducible.

The controller law and the state construction (:mod:`magtune_core.onboard.law`:
``ProjectionController``, ``linear_state``) are the ones the ROS 2 controller node calls, so the SIL loop
reproduces this function's trajectory exactly when sensor noise is zero.
"""
from __future__ import annotations

from dataclasses import dataclass
from dataclasses import field as dc_field

import numpy as np

from ..design.node_params import INITIAL_RATE_ERROR
from ..design.params import SpacecraftParams
from ..onboard.law import DEFAULT_DIPOLE_LIMIT, DEFAULT_MIN_FIELD, ProjectionController, linear_state
from ..onboard.params import TS_DEFAULT
from ..onboard.torquers import NONE as NO_TORQUERS
from ..onboard.torquers import Torquers
from .dynamics import AttitudeDynamics
from .fullenv import full_params, make_dynamics
from .metrics import figures_of_merit
from .substeps import Substeps

#: Initial rate error of the paper's simulation study, dw(0) [rad/s] (the simulator node's default too).
DW0 = INITIAL_RATE_ERROR


@dataclass
class SimResult:
    """Time histories at the controller instants t_k = k Ts, k = 0..N.

    ``m[k]`` is the (saturated) dipole commanded at t_k and held over [t_k, t_k+1); ``b[k]`` the
    body-frame field measured at t_k; ``x[k] = [dq; dw]`` the linear state at t_k.
    """

    t: np.ndarray
    q: np.ndarray
    w: np.ndarray
    x: np.ndarray
    m: np.ndarray
    b: np.ndarray
    orbit_period: float
    info: dict = dc_field(default_factory=dict)

    def figures_of_merit(self) -> dict:
        """:func:`magtune_core.sim.metrics.figures_of_merit` of this run."""
        return figures_of_merit(self.t, self.x, self.m, self.orbit_period)

    def to_npz(self, path, **extra):
        """Save the histories (and ``extra`` arrays) to an ``.npz`` file that :meth:`from_npz` reads back."""
        np.savez(path, t=self.t, q=self.q, w=self.w, x=self.x, m=self.m, b=self.b,
                 orbit_period=self.orbit_period, **extra)

    @classmethod
    def from_npz(cls, path) -> "SimResult":
        """A result saved by :meth:`to_npz`; the extra arrays land in ``info``."""
        with np.load(path) as z:
            info = {k: z[k] for k in z.files if k not in ("t", "q", "w", "x", "m", "b", "orbit_period")}
            return cls(z["t"], z["q"], z["w"], z["x"], z["m"], z["b"], float(z["orbit_period"]), info)


#: Body rate [rad/s] beyond which a run has diverged (about 950 rpm: no magnetic attitude loop
#: comes back from it; the paper's runs stay below 2e-3 rad/s).
DIVERGED_RATE = 100.0
#: Exit status of the simulator node when the run diverged (the runner reports the step).
DIVERGED_EXIT = 4
#: Exit status of the simulator node when its peers did not come up within startup_timeout.
STARTUP_EXIT = 3


def divergence(y) -> str | None:
    """Why the state ``y = [q; w]`` is diverged (non-finite, or |w| > DIVERGED_RATE), else None."""
    y = np.asarray(y, dtype=float)
    if not np.all(np.isfinite(y)):
        return "non-finite state (NaN/Inf)"
    rate = float(np.linalg.norm(y[4:7]))
    if rate > DIVERGED_RATE:
        return f"body rate {rate:.3g} rad/s above {DIVERGED_RATE:g} rad/s"
    return None


def initial_state(p: SpacecraftParams, dw0=DW0, q0=(1.0, 0.0, 0.0, 0.0)) -> np.ndarray:
    """y(0) = [q0; [0, 0, -W0] + dw0]."""
    q0 = np.asarray(q0, dtype=float)
    return np.concatenate([q0 / np.linalg.norm(q0), np.array([0.0, 0.0, -p.orbit_rate]) + np.asarray(dw0, float)])


def simulate(K, p: SpacecraftParams | None = None, *, ts: float = TS_DEFAULT, orbits: float = 1.0,
             steps: int | None = None, substeps: int | None = 2, dw0=DW0, q0=(1.0, 0.0, 0.0, 0.0),
             dipole_limit=DEFAULT_DIPOLE_LIMIT, min_field=DEFAULT_MIN_FIELD,
             residual_dipole=(1.0, 1.0, 1.0), field=None, disturbances=(),
             dynamics: AttitudeDynamics | None = None, environment: str = "paper",
             env_options=None, torquers: Torquers = NO_TORQUERS) -> SimResult:
    """Closed loop of the nonlinear model with the sample-and-hold projection controller.

    ``steps`` (default ``round(orbits * T / ts)``) controller periods are simulated; each
    period is integrated with ``substeps`` RK4 steps with the dipole held (None: re-chosen every
    period from the rate, :class:`magtune_core.sim.substeps.Substeps` from the initial one; 2 from the
    paper's dw(0)).
    ``environment``: "paper" (eq. 26 field, circular orbit, gravity gradient + residual dipole)
    or "full" (J2 orbit, IGRF, drag, SRP; ``env_options`` a
    :class:`magtune_core.sim.fullenv.FullEnvironmentOptions`): see :mod:`magtune_core.sim.fullenv`. In
    "full", T and W0 are the actual orbit's nominal values (``fullenv.full_params``).
    The control law is paper eq. (17), m = S(b)^T K x / |b|^2, saturated per axis; the set-up is
    the simulation study of paper section 5. ``torquers`` (:class:`magtune_core.onboard.torquers.Torquers`):
    their field in the field the law reads, the duty cycle and its compensation (default: none).

    Returns
    -------
    SimResult
        Histories at t_k = k Ts, k = 0..steps, and ``info`` (saturated / weak-field steps, divergence).
    """
    p = p or SpacecraftParams()
    rule = (Substeps.for_rate(ts, np.array([0.0, 0.0, -p.orbit_rate]) + np.asarray(dw0, float), torquers=torquers)
            if substeps is None else Substeps.ladder(ts, substeps, substeps, torquers))  # switch-off on the grid
    if dynamics is None:
        if environment == "full":
            p = full_params(p, env_options)
        dynamics = make_dynamics(environment, p, ts=ts, substeps=rule.most, residual_dipole=residual_dipole,
                                 field=field, disturbances=disturbances, options=env_options)
    dyn = dynamics
    ctrl = ProjectionController(K, torquers.law_limit(dipole_limit, ts), min_field)
    weights = rule.weights(torquers)
    m_last = np.zeros(3)
    n = int(steps if steps is not None else round(orbits * p.orbit_period / ts))
    y = initial_state(p, dw0, q0)
    t = np.arange(n + 1) * ts
    Y = np.zeros((n + 1, 7))
    X = np.zeros((n + 1, 6))
    M = np.zeros((n + 1, 3))
    Bb = np.zeros((n + 1, 3))
    sat = weak = 0
    for k in range(n + 1):
        Y[k] = y
        b = dyn.body_field(t[k], y[:4])
        x = linear_state(y[:4], y[4:], dyn.orbit_rate)
        out = ctrl(x, b + torquers.field(m_last) if torquers.coupled else b)
        sat += out.saturated
        weak += out.weak_field
        m_last = torquers.drive(out.m, ts)
        X[k], Bb[k], M[k] = x, b, m_last
        if k < n:
            S = rule.at(y)
            y = dyn.step(t[k], y, ts, m_last, S, weights[S])
    return SimResult(t, Y[:, :4], Y[:, 4:], X, M, Bb, p.orbit_period,
                     dict(saturated_steps=sat, weak_field_steps=weak, ts=ts, substeps=rule.most, substep_levels=rule.levels,
                          environment=environment))
