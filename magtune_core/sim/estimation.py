"""Offline attitude estimation: truth along a run, the sensor models, the MEKF, its statistics.

The truth is a sequence of attitudes q_bo(t_k) (body w.r.t. orbital axes, e.g. a
:class:`magtune_core.sim.simulate.SimResult`) turned into the inertial attitude the gyro sees
(:func:`truth_along`); the sensors are those of :mod:`magtune_core.design.sensors` with a seed;
the filter :mod:`magtune_core.onboard.mekf` starts from a coarse fix
(:mod:`magtune_core.onboard.attitude_fix`). On-board models: in the full environment IGRF at the
position fix (degree configurable) and the Sun model of :mod:`magtune_core.env.sun`; in the paper
environment the environment's own field (eq. 26), so the filter is not biased by a model the truth
does not use. Equations and figures: docs/estimation.md.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from ..base.rotations import matrix_to_quat, quat_mul, rotation_matrix
from ..design.params import SpacecraftParams
from ..design.sensors import (
    AUX_NORMALS,
    FIX,
    GYRO_U,
    GYRO_V,
    MAG,
    SUN,
    SensorSuite,
    aux_rng,
    default_suite,
    draw,
    gyro,
    magnetometer,
    position_fix,
    sun_sensor,
)
from ..env.environment import Environment, body_to_eci
from ..env.sun import shadow_cylindrical
from ..onboard.estimator import MekfStream, OnboardModels
from ..onboard.mekf import MAG_BIAS_STD, attitude_error, quat_rotvec, rotvec_quat
from .fullenv import FullEnvironmentOptions


@dataclass(frozen=True)
class Truth:
    """Truth at t_k = k ts (N + 1 samples) in an inertial reference frame: ECI in the full
    environment, the orbital axes at t = 0 in the paper's (whose orbital frame turns at
    [0, 0, -W0] about a fixed axis)."""

    t: np.ndarray  #: (N+1,) [s]
    q: np.ndarray  #: (N+1, 4) body w.r.t. reference
    w: np.ndarray  #: (N, 3) mean body rate over [t_k, t_k+1): rotation vector / ts [rad/s]
    b_ref: np.ndarray  #: (N+1, 3) field in reference axes [T]
    b_body: np.ndarray  #: (N+1, 3) field in body axes [T]
    sun_ref: np.ndarray | None = None  #: (N+1, 3) unit satellite-Sun vector, reference axes
    sun_body: np.ndarray | None = None  #: (N+1, 3) the same in body axes
    lit: np.ndarray | None = None  #: (N+1,) bool, cylindrical shadow
    r: np.ndarray | None = None  #: (N+1, 3) ECI position [m]
    v: np.ndarray | None = None  #: (N+1, 3) ECI velocity [m/s]
    environment: str = "paper"  #: "paper", "full" or "kinematic" (built by the caller)
    jd0: float = 0.0  #: Julian date of t = 0 (full environment)

    @property
    def ts(self) -> float:
        """Sample period [s]."""
        return float(self.t[1] - self.t[0])


def _rz(angle) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def mean_rates(q, ts: float) -> np.ndarray:
    """(N, 3) body rates [rad/s] taking q_k to q_k+1 at constant rate: log(q_k^-1 (x) q_k+1) / ts."""
    conj = np.array([1.0, -1.0, -1.0, -1.0])
    return np.array([quat_rotvec(quat_mul(q[k] * conj, q[k + 1])) for k in range(len(q) - 1)]) / ts


def truth_along(t, q_bo, p: SpacecraftParams | None = None, environment: str = "paper",
                options: FullEnvironmentOptions | None = None) -> Truth:
    """The :class:`Truth` of a run's attitudes ``q_bo`` (N+1, 4) at times ``t`` (uniform).

    "paper": reference = orbital axes at t = 0, R_ref<-orb(t) = R_z(-W0 t), field eq. 26 of ``p``;
    no Sun. "full": reference = ECI; J2 orbit, IGRF (``options.igrf_degree``), Sun and
    cylindrical shadow of :class:`magtune_core.env.environment.Environment`.

    Returns
    -------
    Truth
        The reference-frame truth; ``w`` the constant-rate interpolation between the samples
        (what a rate-integrating gyro measures up to its noise).
    """
    p = p or SpacecraftParams()
    t = np.asarray(t, dtype=float)
    q_bo = np.asarray(q_bo, dtype=float)
    R_bo = rotation_matrix(q_bo)
    if environment == "paper":
        R_bi = _rz(-p.orbit_rate * t) @ R_bo
        b_ref = np.einsum("kij,kj->ki", _rz(-p.orbit_rate * t), np.asarray(p.field()(t)).reshape(len(t), 3))
        extra = {}
    else:
        opts = options or FullEnvironmentOptions()
        env = Environment(opts.environment_config(p), orbit_duration=float(t[-1]) + 60.0)
        r, v = env.orbit.state(t)
        R_bi = body_to_eci(q_bo, r, v)
        b_ref = env.magnetic_field_eci(t, r)
        sun = env.sun_eci(t)
        d = sun - r
        s_ref = d / np.linalg.norm(d, axis=-1, keepdims=True)
        extra = dict(sun_ref=s_ref, sun_body=np.einsum("kji,kj->ki", R_bi, s_ref),
                     lit=shadow_cylindrical(r, sun) > 0.5, r=r, v=v, environment="full", jd0=env.jd0)
    q = np.array([matrix_to_quat(R) for R in R_bi])
    for k in range(1, len(q)):  # continuous sign
        if q[k] @ q[k - 1] < 0:
            q[k] = -q[k]
    ts = float(t[1] - t[0])
    return Truth(t, q, mean_rates(q, ts), b_ref, np.einsum("kji,kj->ki", R_bi, b_ref), **extra)


def onboard_field(truth: Truth, p: SpacecraftParams | None = None, igrf_degree: int = 10):
    """The on-board field model ``(k, r_meas) -> b_ref [T]`` (reference axes) of ``truth``'s
    environment: IGRF of ``igrf_degree`` at the measured position (full,
    :class:`magtune_core.onboard.estimator.OnboardModels`, as the node), eq. 26 (paper)."""
    if truth.environment != "full":
        return lambda k, r_meas: truth.b_ref[k]
    models = OnboardModels("full", truth.jd0, igrf_degree)
    return lambda k, r_meas: models.field(float(truth.t[k]), r_meas)


def onboard_sun(truth: Truth):
    """The on-board Sun model ``(k, r_meas) -> unit satellite-Sun vector`` (reference axes): in the
    full environment the Sun position of date minus the measured position
    (:meth:`magtune_core.onboard.estimator.OnboardModels.sun`); otherwise the truth's own ``sun_ref``."""
    if truth.environment != "full":
        return lambda k, r_meas: truth.sun_ref[k]
    models = OnboardModels("full", truth.jd0, 1)
    return lambda k, r_meas: models.sun(float(truth.t[k]), r_meas)


@dataclass
class MekfRun:
    """Histories of an offline MEKF run at t_k (NaN before the filter starts at ``k0``)."""

    t: np.ndarray
    q: np.ndarray  #: (N+1, 4) estimate after the updates at t_k
    bias: np.ndarray  #: (N+1, 3) estimated gyro bias [rad/s]
    P: np.ndarray  #: (N+1, 9, 9) of [dtheta; db; dm] (onboard.mekf)
    error: np.ndarray  #: (N+1, 3) attitude error dtheta [rad], body axes (q_true = q (x) exp(dtheta/2))
    bias_error: np.ndarray  #: (N+1, 3) true minus estimated bias [rad/s]
    nees: np.ndarray  #: (N+1,) attitude NEES dtheta^T P_tt^-1 dtheta (3 dof)
    nis_mag: np.ndarray  #: (N+1,) NIS of the magnetometer (3 dof)
    nis_sun: np.ndarray  #: (N+1,) NIS of the sun sensor (2 dof; NaN: no measurement)
    k0: int = 0  #: first sample with an estimate (coarse fix)
    counts: dict = field(default_factory=dict)  #: accepted / rejected updates per sensor
    lit: np.ndarray | None = None  #: (N+1,) sun sensor valid
    mag_bias: np.ndarray | None = None  #: (N+1, 3) estimated magnetometer bias [T]
    mag_bias_error: np.ndarray | None = None  #: (N+1, 3) true (the suite's constant bias) minus estimated [T]

    def sigma(self) -> np.ndarray:
        """(N+1, 3) standard deviations of the attitude error per body axis [rad]."""
        return np.sqrt(np.diagonal(self.P[:, :3, :3], axis1=1, axis2=2))


def run_mekf(truth: Truth, suite: SensorSuite | None = None, seed: int = 0, *, use_sun: bool = True,
             field_model=None, sun_model=None, bias_std: float = 5e-4, gate_probability: float = 0.9999,
             init_angle: float = math.radians(10.0), mag_bias_std: float = MAG_BIAS_STD,
             mag_bias_rw: float = 0.0) -> MekfRun:
    """Simulate the sensors on ``truth`` (seed ``seed``) and run the MEKF over it.

    Per sample: magnetometer update against ``field_model`` (default :func:`onboard_field`),
    then the sun sensor's against ``sun_model`` (default :func:`onboard_sun`) (unit vector, R = sigma_s^2 I, 2-dof gate) when valid and ``use_sun``,
    then propagation with the gyro sample. Start: Davenport fix of magnetometer and sun sensor at
    t_0 when the Sun is seen, else of the magnetometer now and the first one carried forward by
    the raw gyro once the reference field has turned by ``init_angle`` (its error inflated by
    (bias_std T)^2 + sigma_v^2 T). Initial bias 0 with std ``bias_std`` [rad/s]; magnetometer bias
    0 with std ``mag_bias_std`` [T] (0: not estimated) and random walk ``mag_bias_rw`` [T/s^0.5].

    Returns
    -------
    MekfRun
        Estimates, covariances, errors, NEES, NIS and the gate counts.
    """
    suite = suite or default_suite(truth.ts)
    n1, ts = len(truth.t), truth.ts
    rng = np.random.default_rng(seed)
    nrm = draw(rng, n1)
    aux = draw(aux_rng(seed), n1, AUX_NORMALS)
    mag = magnetometer(suite.magnetometer, truth.b_body, nrm[:, MAG])
    w_m, beta = gyro(suite.gyro, truth.w, ts, suite.gyro.bias, nrm[:-1, GYRO_V], nrm[:-1, GYRO_U])
    have_sun = use_sun and truth.sun_body is not None
    if have_sun:
        s_m, s_ok, _ = sun_sensor(suite.sun, truth.sun_body, truth.lit, aux[:, SUN])
    else:
        s_m, s_ok = None, np.zeros(n1, dtype=bool)
    r_m = (position_fix(suite.position, truth.r, truth.v, aux[:, FIX])[0] if truth.r is not None
           else np.zeros((n1, 3)))
    field_model = field_model or onboard_field(truth)
    sun_model = sun_model or onboard_sun(truth)
    stream = MekfStream(suite, bias_std=bias_std, gate_probability=gate_probability, init_angle=init_angle,
                        mag_bias_std=mag_bias_std, mag_bias_rw=mag_bias_rw)
    out = _empty(truth, n1)
    out.k0 = -1
    counts = dict(mag_accepted=0, mag_rejected=0, sun_accepted=0, sun_rejected=0)
    for k in range(n1):
        sun = (s_m[k], sun_model(k, r_m[k])) if s_ok[k] else (None, None)
        step = stream.step(w_m[k - 1] if k else None, mag[k], field_model(k, r_m[k]), *sun)
        if step.state is None:
            continue
        if step.started:
            out.k0 = k
        out.nis_mag[k] = step.nis_mag
        counts["mag_accepted" if step.mag_accepted else "mag_rejected"] += 1
        if step.sun_accepted is not None:
            out.nis_sun[k] = step.nis_sun
            counts["sun_accepted" if step.sun_accepted else "sun_rejected"] += 1
        state = step.state
        out.q[k], out.bias[k], out.P[k], out.mag_bias[k] = state.q, state.b, state.P, state.m
        e = attitude_error(truth.q[k], state.q)
        out.error[k] = e
        out.nees[k] = e @ np.linalg.solve(state.P[:3, :3], e)
    if out.k0 < 0:
        raise ValueError("the reference field never turned by init_angle: no coarse fix from the magnetometer alone")
    out.bias_error = beta - out.bias
    out.mag_bias_error = np.asarray(suite.magnetometer.bias, dtype=float) - out.mag_bias
    out.counts, out.lit = counts, s_ok
    return out


def _empty(truth: Truth, n1: int) -> MekfRun:
    nan = np.full
    return MekfRun(truth.t, nan((n1, 4), np.nan), nan((n1, 3), np.nan), nan((n1, 9, 9), np.nan),
                   nan((n1, 3), np.nan), nan((n1, 3), np.nan), nan(n1, np.nan), nan(n1, np.nan), nan(n1, np.nan),
                   mag_bias=nan((n1, 3), np.nan))


# ---------------------------------------------------------------- statistics
def nees_windows(nees, n: int, dof: int = 3, probability: float = 0.95) -> tuple[np.ndarray, float, float]:
    """Window means of ``nees`` over ``n`` consecutive samples and the two-sided chi-square band
    of the mean of n independent chi2(dof) values (Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4.2).

    Returns
    -------
    means : ndarray (M,)
        Mean NEES of each complete window.
    low, high : float
        The ``probability`` band chi2.ppf((1 -+ p)/2, n dof) / n.
    """
    x = np.asarray(nees, dtype=float)
    x = x[np.isfinite(x)]
    m = len(x) // n
    means = x[: m * n].reshape(m, n).mean(axis=1)
    a = (1.0 - probability) / 2
    return means, float(chi2.ppf(a, n * dof) / n), float(chi2.ppf(1 - a, n * dof) / n)


def error_summary(run: MekfRun, start: int = 0) -> dict:
    """RMS error per body axis [rad], fraction of samples inside 3 sigma per axis, mean NEES,
    from sample ``start`` on (after the filter started).

    Returns
    -------
    dict
        ``rms`` (3,), ``inside_3sigma`` (3,), ``nees_mean``, ``bias_rms`` (3,) [rad/s], counts.
    """
    s = slice(max(start, run.k0), None)
    e, sig = run.error[s], run.sigma()[s]
    return dict(rms=np.sqrt(np.mean(e**2, axis=0)), inside_3sigma=np.mean(np.abs(e) <= 3 * sig, axis=0),
                nees_mean=float(np.mean(run.nees[s])), bias_rms=np.sqrt(np.mean(run.bias_error[s] ** 2, axis=0)),
                **run.counts)


def kinematic_truth(n: int, ts: float, rate, b_ref, sun_ref=None, lit=None, q0=(1.0, 0.0, 0.0, 0.0)) -> Truth:
    """A truth of ``n`` steps without dynamics: body rate ``rate(t)`` [rad/s] (held at its
    mid-step value over each step, so the quaternion integrates exactly), reference field
    ``b_ref(t)`` (N+1, 3) [T] and a fixed unit Sun vector ``sun_ref`` (3,) visible where ``lit``
    (N+1,) bool (default everywhere); the consistency checks' truth (docs/estimation.md).

    Returns
    -------
    Truth
        environment "kinematic": the filter's reference vectors are the truth's.
    """
    t = np.arange(n + 1) * float(ts)
    w = np.asarray(rate(t[:-1] + 0.5 * ts), dtype=float).reshape(n, 3)
    q = np.empty((n + 1, 4))
    q[0] = np.asarray(q0, dtype=float) / np.linalg.norm(q0)
    for k in range(n):
        q[k + 1] = quat_mul(q[k], rotvec_quat(w[k] * ts))
    R = rotation_matrix(q)
    br = np.asarray(b_ref(t), dtype=float).reshape(n + 1, 3)
    extra = {}
    if sun_ref is not None:
        s = np.broadcast_to(np.asarray(sun_ref, dtype=float) / np.linalg.norm(sun_ref), (n + 1, 3))
        extra = dict(sun_ref=s, sun_body=np.einsum("kji,kj->ki", R, s),
                     lit=np.ones(n + 1, dtype=bool) if lit is None else np.asarray(lit, dtype=bool))
    return Truth(t, q, w, br, np.einsum("kji,kj->ki", R, br), environment="kinematic", **extra)
