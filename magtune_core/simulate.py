"""Offline closed-loop simulation (no ROS) of the digital projection-based controller.

Paper section 5: the controller is implemented "in digital form, using a conventional sample
and hold scheme" with period Ts; the plant is the nonlinear model of ``dynamics`` (rigid body,
pitch wheel, gravity gradient, residual dipole 1 A m^2 per axis, eq. 26 field), integrated with
fixed-step RK4 so that runs are bit-for-bit reproducible.

The controller law (``ProjectionController``) and the state construction
(``dynamics.linear_state``) are the ones the ROS 2 controller node calls, so the SIL loop
reproduces this function's trajectory exactly when sensor noise is zero.
"""
from __future__ import annotations

from dataclasses import dataclass, field as dc_field

import numpy as np

from .dynamics import AttitudeDynamics, linear_state, saturate
from .gains import Gains
from .model import AttitudeLTP, Z_ATT, skew_field
from .params import SpacecraftParams

#: Initial rate error of the paper's simulation study, dw(0) [rad/s].
DW0 = (1e-3, 2e-3, 0.0)
#: Default per-axis dipole limit [A m^2] (the paper gives none; typical 10-50 A m^2 small-sat rods).
DEFAULT_DIPOLE_LIMIT = 50.0
#: Below this field magnitude [T] the projection law is ill-conditioned: command zero dipole.
DEFAULT_MIN_FIELD = 1e-7


@dataclass
class ControlOutput:
    """One controller evaluation: saturated dipole and what happened."""

    m: np.ndarray
    saturated: bool = False
    weak_field: bool = False


@dataclass
class ProjectionController:
    """m = sat(S(b)^T K x / |b|^2) (paper eq. 17), with a weak-field guard.

    Written with explicit float arithmetic (no einsum) so that the offline simulation and
    the ROS controller node compute bit-identical dipoles from the same inputs.
    """

    K: np.ndarray
    dipole_limit: float | np.ndarray = DEFAULT_DIPOLE_LIMIT
    min_field: float = DEFAULT_MIN_FIELD

    def __post_init__(self):
        self.K = np.asarray(self.K, dtype=float).reshape(3, 6)
        self.dipole_limit = np.broadcast_to(np.asarray(self.dipole_limit, dtype=float), (3,)).copy()

    def __call__(self, x, b) -> ControlOutput:
        b = np.asarray(b, dtype=float)
        b2 = float(b @ b)
        if not b2 >= self.min_field**2:  # also catches NaN
            return ControlOutput(np.zeros(3), weak_field=True)
        u = self.K @ np.asarray(x, dtype=float)  # ideal torque T_id = K x (eq. 19)
        m = skew_field(b).T @ u / b2
        ms = saturate(m, self.dipole_limit)
        return ControlOutput(ms, saturated=bool(np.any(ms != m)))


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

    def to_npz(self, path, **extra):
        np.savez(path, t=self.t, q=self.q, w=self.w, x=self.x, m=self.m, b=self.b,
                 orbit_period=self.orbit_period, **extra)

    @classmethod
    def from_npz(cls, path) -> "SimResult":
        with np.load(path) as z:
            info = {k: z[k] for k in z.files if k not in ("t", "q", "w", "x", "m", "b", "orbit_period")}
            return cls(z["t"], z["q"], z["w"], z["x"], z["m"], z["b"], float(z["orbit_period"]), info)


def initial_state(p: SpacecraftParams, dw0=DW0, q0=(1.0, 0.0, 0.0, 0.0)) -> np.ndarray:
    """y(0) = [q0; [0, 0, -W0] + dw0]."""
    q0 = np.asarray(q0, dtype=float)
    return np.concatenate([q0 / np.linalg.norm(q0), np.array([0.0, 0.0, -p.orbit_rate]) + np.asarray(dw0, float)])


def simulate(K, p: SpacecraftParams | None = None, *, ts: float = 1.0, orbits: float = 1.0,
             steps: int | None = None, substeps: int = 2, dw0=DW0, q0=(1.0, 0.0, 0.0, 0.0),
             dipole_limit=DEFAULT_DIPOLE_LIMIT, min_field=DEFAULT_MIN_FIELD,
             residual_dipole=(1.0, 1.0, 1.0), field=None, disturbances=(),
             dynamics: AttitudeDynamics | None = None, environment: str = "paper",
             env_options=None) -> SimResult:
    """Closed loop of the nonlinear model with the sample-and-hold projection controller.

    ``steps`` (default ``round(orbits * T / ts)``) controller periods are simulated; each
    period is integrated with ``substeps`` RK4 steps with the dipole held.
    ``environment``: "paper" (eq. 26 field, circular orbit, gravity gradient + residual dipole)
    or "full" (J2 orbit, IGRF, drag, SRP; ``env_options`` a
    :class:`magtune_core.fullenv.FullEnvironmentOptions`): see :mod:`magtune_core.fullenv`. In
    "full", T and W0 are the actual orbit's nominal values (``fullenv.full_params``).
    """
    p = p or SpacecraftParams()
    if dynamics is None:
        from .fullenv import full_params, make_dynamics

        if environment == "full":
            p = full_params(p, env_options)
        dynamics = make_dynamics(environment, p, ts=ts, substeps=substeps, residual_dipole=residual_dipole,
                                 field=field, disturbances=disturbances, options=env_options)
    dyn = dynamics
    ctrl = ProjectionController(K, dipole_limit, min_field)
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
        out = ctrl(x, b)
        sat += out.saturated
        weak += out.weak_field
        X[k], Bb[k], M[k] = x, b, out.m
        if k < n:
            y = dyn.step(t[k], y, ts, out.m, substeps)
    return SimResult(t, Y[:, :4], Y[:, 4:], X, M, Bb, p.orbit_period,
                     dict(saturated_steps=sat, weak_field_steps=weak, ts=ts, substeps=substeps,
                          environment=environment))


def figures_of_merit(res: SimResult) -> dict:
    """Paper Figs. 2-3 summary: |dq_R| final/peak, RMS |dq_R| over orbits 2-5, peak |m|.

    The RMS window is t in [T, 5T] intersected with the run; a run shorter than one orbit
    uses all of it (``rms_window`` reports the window used).
    """
    dq = np.linalg.norm(res.x[:, :3], axis=1)  # |dq_R| = sqrt(x^T Z^T Z x)
    mn = np.linalg.norm(res.m, axis=1)
    T = res.orbit_period
    sel = (res.t >= T) & (res.t <= 5 * T)
    if np.count_nonzero(sel) < 2:  # run not longer than one orbit: use all of it
        sel = np.ones_like(dq, dtype=bool)
    return dict(
        final_dq=float(dq[-1]),
        peak_dq=float(dq.max()),
        rms_dq=float(np.sqrt(np.mean(dq[sel] ** 2))),
        rms_window=(float(res.t[sel][0]), float(res.t[sel][-1])),
        peak_m=float(mn.max()),
        orbits=float(res.t[-1] / T),
    )


def format_figures(fom: dict) -> str:
    a, b = fom["rms_window"]
    return (f"|dq_R| final {fom['final_dq']:.4e}  peak {fom['peak_dq']:.4e}  "
            f"RMS[{a:.0f}s..{b:.0f}s] {fom['rms_dq']:.4e}  |m| peak {fom['peak_m']:.4g} A m^2")


def lq_gains(p: SpacecraftParams | None = None, sigma: float = 60.0, ts: float = 1.0) -> Gains:
    """Stabilizing LQ gain on the time-averaged model (SPEC.md reference design, paper 4.2 start).

    K = -R^-1 Bbar^T P, P from the CARE with Q = Z^T Z, R = sigma^2 I, Bbar = (1/T) int B(t) dt.
    """
    from scipy.linalg import solve_continuous_are

    p = p or SpacecraftParams()
    ltp = AttitudeLTP.from_params(p)
    Bbar = ltp.B_mean()
    R = sigma**2 * np.eye(3)
    P = solve_continuous_are(ltp.A, Bbar, Z_ATT.T @ Z_ATT, R)
    K = -np.linalg.solve(R, Bbar.T @ P)
    return Gains(K, sigma, ts, {"design": "lq_averaged", "field_model": ltp.field.name})
