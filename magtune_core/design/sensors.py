"""Sensor models of the satellite: magnetometer, gyro (Farrenkopf), sun sensor, position fix.

One implementation for the ``attitude_sensors`` node and the batched simulation
(:mod:`magtune_core.sim.batch`): dataclass parameter sets (SI units) and functions on arrays.
Every random input is an array of standard normals the caller draws from its own seeded
``numpy.random.Generator`` (:func:`draw`), nothing global; with zero noise parameters every
function returns the truth bit for bit. Equations and references: docs/sensors.md.

Normals of one controller sample (:data:`NORMALS_PER_STEP`, layout :data:`MAG`, :data:`ATT`,
:data:`GYRO_V`, :data:`GYRO_U`) are the row a node draws per step and the batch draws in blocks,
so both see the same stream for the same seed. Sun sensor and position fix draw from a second
generator (:func:`aux_rng`): they exist only in the full environment.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..base.rotations import cross
from ..env.environment import body_to_eci
from ..env.sun import shadow_cylindrical
from ..onboard.params import TS_DEFAULT

#: Standard normals per controller sample: magnetometer (3), attitude (3), gyro N_v (3), gyro N_u (3).
NORMALS_PER_STEP = 12
MAG, ATT, GYRO_V, GYRO_U = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)
#: Normals per sample of the auxiliary sensors: sun sensor (3), position (3), velocity (3); FIX = both.
AUX_NORMALS = 9
SUN, POS, VEL, FIX = slice(0, 3), slice(3, 6), slice(6, 9), slice(3, 9)
_IDENTITY9 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


def draw(rng: np.random.Generator, n: int | None = None, width: int = NORMALS_PER_STEP) -> np.ndarray:
    """Standard normals of one sample (``n`` None: shape (width,)) or of ``n`` samples (n, width).

    ``rng.standard_normal((n, width))`` fills row by row, so a block equals ``n`` single draws.

    Parameters
    ----------
    rng : numpy.random.Generator
        The caller's seeded generator.
    n : int or None
        Number of samples; None: one sample without the leading axis.
    width : int
        Normals per sample (:data:`NORMALS_PER_STEP` or :data:`AUX_NORMALS`).

    Returns
    -------
    ndarray (width,) or (n, width)
        Standard normals.
    """
    return rng.standard_normal(width if n is None else (n, width))


def aux_rng(seed) -> np.random.Generator:
    """The auxiliary sensors' generator of ``seed``: independent of ``default_rng(seed)``.

    Parameters
    ----------
    seed : int or array_like of int or None
        Entropy of the ``SeedSequence`` whose first spawned child seeds the generator.

    Returns
    -------
    numpy.random.Generator
        The auxiliary generator.
    """
    return np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])


# ---------------------------------------------------------------- magnetometer
@dataclass(frozen=True)
class Magnetometer:
    """Three-axis magnetometer: b_m = quantize(M b + bias + noise_std n) [T].

    ``matrix`` is M = I + scale factors (diagonal) + misalignment (off-diagonal), row-major 9
    values; ``quantum`` the LSB [T] (0: none). The torquers' field reaches it through onboard.torquers.
    """

    noise_std: float = 0.0  #: white noise std per axis [T]
    bias: tuple = (0.0, 0.0, 0.0)  #: constant bias [T], body axes
    matrix: tuple = _IDENTITY9  #: scale factor and misalignment M (row-major)
    quantum: float = 0.0  #: quantization step [T]

    @property
    def covariance(self) -> np.ndarray:
        """Measurement covariance (3, 3) [T^2]: white noise plus uniform quantization error q^2/12.

        Returns
        -------
        ndarray (3, 3)
            (noise_std^2 + quantum^2 / 12) I [T^2].
        """
        return np.eye(3) * (self.noise_std**2 + self.quantum**2 / 12.0)


def magnetometer(model: Magnetometer, b, normals) -> np.ndarray:
    """Measured field [T], shape of ``b`` (..., 3); ``normals`` (..., 3) standard normals.

    Parameters
    ----------
    model : Magnetometer
        Noise, bias, scale/misalignment matrix and quantum.
    b : array_like (..., 3)
        True field [T], body axes.
    normals : array_like (..., 3)
        Standard normals of the white noise.

    Returns
    -------
    ndarray (..., 3)
        quantize(M b + bias + noise_std n) [T]; ``b`` itself (as float array) without errors.
    """
    out = np.asarray(b, dtype=float)
    if model.matrix != _IDENTITY9:
        out = np.einsum("ij,...j->...i", np.reshape(model.matrix, (3, 3)), out)
    if model.noise_std > 0 or any(model.bias):
        out = out + np.asarray(model.bias, dtype=float) + model.noise_std * np.asarray(normals, dtype=float)
    if model.quantum > 0:
        out = np.rint(out / model.quantum) * model.quantum
    return out


# ---------------------------------------------------------------- gyro
@dataclass(frozen=True)
class Gyro:
    """Rate-integrating gyro of Farrenkopf (1978): w_m = w + beta + eta_v, d(beta)/dt = eta_u.

    ``arw`` sigma_v [rad/s^0.5] (angle random walk: the angle error grows as sigma_v sqrt(t)),
    ``rrw`` sigma_u [rad/s^1.5] (rate random walk of the bias: its std grows as sigma_u sqrt(t)),
    ``bias`` beta_0 [rad/s].
    """

    arw: float = 0.0
    rrw: float = 0.0
    bias: tuple = (0.0, 0.0, 0.0)

    def white_std(self, dt: float) -> float:
        """Std [rad/s] of the white part of one sample: sqrt(sigma_v^2/dt + sigma_u^2 dt/12).

        Parameters
        ----------
        dt : float
            Sample period [s].

        Returns
        -------
        float
            Std per axis [rad/s].
        """
        return math.sqrt(self.arw**2 / dt + self.rrw**2 * dt / 12.0)

    def covariance(self, dt: float) -> np.ndarray:
        """Covariance (3, 3) [rad^2/s^2] of the white part of a sample (the bias is a state).

        Parameters
        ----------
        dt : float
            Sample period [s].

        Returns
        -------
        ndarray (3, 3)
            white_std(dt)^2 I [rad^2/s^2].
        """
        return np.eye(3) * self.white_std(dt) ** 2


def gyro(model: Gyro, w, dt: float, beta0, n_v, n_u) -> tuple[np.ndarray, np.ndarray]:
    """Farrenkopf gyro sampled every ``dt`` [s], discretized exactly (Crassidis & Junkins 2012,
    Optimal Estimation of Dynamic Systems, 2nd ed., sec. 7.2.1; Markley & Crassidis 2014, sec. 4.7.1).

    ``beta_{k+1} = beta_k + sigma_u sqrt(dt) N_u,k`` and
    ``w_m,k = w_k + (beta_{k+1} + beta_k)/2 + sqrt(sigma_v^2/dt + sigma_u^2 dt/12) N_v,k``,
    with which the integrated angle error has exactly the continuous model's variance
    sigma_v^2 t + sigma_u^2 t^3/3 (docs/sensors.md). ``w``, ``n_v``, ``n_u`` (..., N, 3):
    N samples; ``beta0`` (..., 3) the bias before sample 0.

    Parameters
    ----------
    model : Gyro
        ARW, RRW and initial bias parameters.
    w : array_like (..., N, 3)
        True rates [rad/s], body axes.
    dt : float
        Sample period [s].
    beta0 : array_like (..., 3)
        Bias before sample 0 [rad/s].
    n_v : array_like (..., N, 3)
        Standard normals of the white rate noise.
    n_u : array_like (..., N, 3)
        Standard normals of the bias walk.

    Returns
    -------
    w_m : ndarray (..., N, 3)
        Measured rates [rad/s].
    beta : ndarray (..., N + 1, 3)
        beta_0 .. beta_N [rad/s] (the last one is beta_0 of the next call).
    """
    w = np.asarray(w, dtype=float)
    beta = gyro_bias_walk(model, dt, np.broadcast_to(np.asarray(beta0, dtype=float), w.shape[:-2] + (3,)), n_u)
    s = model.white_std(dt)
    if s > 0 or np.any(beta):
        w = w + 0.5 * (beta[..., 1:, :] + beta[..., :-1, :]) + s * np.asarray(n_v, dtype=float)
    return w, beta


def gyro_bias_walk(model: Gyro, dt: float, beta0, n_u) -> np.ndarray:
    """beta_0 .. beta_N (..., N + 1, 3) [rad/s]: beta_{k+1} = beta_k + sigma_u sqrt(dt) N_u,k
    (``n_u`` (..., N, 3)), summed in sequence so that N calls of one step give the same numbers.

    Parameters
    ----------
    model : Gyro
        Its ``rrw`` sigma_u [rad/s^1.5] drives the walk.
    dt : float
        Sample period [s].
    beta0 : array_like (..., 3)
        Bias before sample 0 [rad/s].
    n_u : array_like (..., N, 3)
        Standard normals of the walk.

    Returns
    -------
    ndarray (..., N + 1, 3)
        beta_0 .. beta_N [rad/s] (beta0 repeated when rrw is 0).
    """
    n_u = np.asarray(n_u, dtype=float)
    b0 = np.broadcast_to(np.asarray(beta0, dtype=float), n_u.shape[:-2] + (3,))
    if model.rrw > 0:
        inc = model.rrw * math.sqrt(dt) * n_u
        return np.cumsum(np.concatenate([b0[..., None, :], inc], axis=-2), axis=-2)  # add.accumulate: in order
    return np.repeat(b0[..., None, :], n_u.shape[-2] + 1, axis=-2)


def gyro_from(noise_std: float, arw: float, rrw: float, bias, ts: float) -> Gyro:
    """The :class:`Gyro` of the node parameters: a white rate noise ``noise_std`` [rad/s] per
    sample of ``ts`` is the angle random walk sigma_v = noise_std sqrt(ts); it adds to ``arw``
    in variance.

    Parameters
    ----------
    noise_std : float
        White rate noise per sample [rad/s].
    arw : float
        Angle random walk sigma_v [rad/s^0.5].
    rrw : float
        Rate random walk sigma_u [rad/s^1.5].
    bias : array_like (3,)
        Initial bias [rad/s].
    ts : float
        Sample period [s].

    Returns
    -------
    Gyro
        sigma_v = sqrt(arw^2 + noise_std^2 ts), sigma_u = rrw, bias.
    """
    return Gyro(math.sqrt(float(arw) ** 2 + float(noise_std) ** 2 * float(ts)), float(rrw), _t(bias))


# ---------------------------------------------------------------- attitude (truth + noise)
def noisy_attitude(q, std: float, normals) -> np.ndarray:
    """q (x) exp(dtheta/2), dtheta = std n [rad] in body axes: an attitude solution's error.

    ``q`` (..., 4) scalar first, ``normals`` (..., 3); std 0 returns ``q`` itself.

    Parameters
    ----------
    q : array_like (..., 4)
        True attitude quaternion, scalar first.
    std : float
        Angle error std per axis [rad].
    normals : array_like (..., 3)
        Standard normals of the error.

    Returns
    -------
    ndarray (..., 4)
        The perturbed quaternion, scalar first (``q`` as float array when std <= 0).
    """
    q = np.asarray(q, dtype=float)
    if std <= 0:
        return q
    th = std * np.asarray(normals, dtype=float)
    ang = np.linalg.norm(th, axis=-1, keepdims=True)
    s = np.where(ang > 0, np.sin(ang / 2) / np.where(ang > 0, ang, 1.0), 0.5)
    p = np.concatenate([np.cos(ang / 2), s * th], axis=-1)
    q0, q1, q2, q3 = np.moveaxis(q, -1, 0)
    p0, p1, p2, p3 = np.moveaxis(p, -1, 0)
    return np.stack([q0 * p0 - q1 * p1 - q2 * p2 - q3 * p3, q0 * p1 + q1 * p0 + q2 * p3 - q3 * p2,
                     q0 * p2 - q1 * p3 + q2 * p0 + q3 * p1, q0 * p3 + q1 * p2 - q2 * p1 + q3 * p0], axis=-1)


# ---------------------------------------------------------------- sun sensor
@dataclass(frozen=True)
class SunSensor:
    """Sun direction sensor: unit satellite-to-Sun vector in body axes, rotated by a random small
    angle, available when lit (cylindrical Earth shadow of :mod:`magtune_core.env.sun`) and
    within ``fov_half_angle`` of ``boresight`` (pi: the whole sphere, e.g. six coarse sensors)."""

    noise_std: float = 0.0  #: angle error std per axis [rad]
    fov_half_angle: float = math.pi  #: half-angle of the field of view [rad]
    boresight: tuple = (1.0, 0.0, 0.0)  #: field-of-view axis, body axes

    def covariance(self, s) -> np.ndarray:
        """Covariance of the measured unit vector s, (..., 3, 3): sigma^2 (I - s s^T)
        (Shuster's QUEST measurement model, Markley & Crassidis 2014, sec. 5.5.1).

        Parameters
        ----------
        s : array_like (..., 3)
            Unit Sun vector(s), body axes.

        Returns
        -------
        ndarray (..., 3, 3)
            noise_std^2 (I - s s^T) [rad^2].
        """
        s = np.asarray(s, dtype=float)
        return self.noise_std**2 * (np.eye(3) - s[..., :, None] * s[..., None, :])


def sun_direction_body(q_body_orbital, r_eci, v_eci, sun_eci) -> np.ndarray:
    """Unit satellite-to-Sun vector (..., 3) in body axes from the attitude w.r.t. the orbital
    frame of (r, v) and the geocentric Sun position ``sun_eci`` [m] (ECI).

    Parameters
    ----------
    q_body_orbital : array_like (..., 4)
        Attitude of the body w.r.t. the orbital frame (scalar first).
    r_eci : array_like (..., 3)
        Satellite position [m], ECI.
    v_eci : array_like (..., 3)
        Satellite velocity [m/s], ECI.
    sun_eci : array_like (..., 3)
        Geocentric Sun position [m], ECI.

    Returns
    -------
    ndarray (..., 3)
        Unit satellite-to-Sun vector in body axes.
    """
    d = np.asarray(sun_eci, dtype=float) - np.asarray(r_eci, dtype=float)
    s = np.einsum("...ji,...j->...i", body_to_eci(q_body_orbital, r_eci, v_eci), d)
    return s / np.linalg.norm(s, axis=-1, keepdims=True)


def illuminated(r_eci, sun_eci) -> np.ndarray:
    """True where the satellite is lit: :func:`magtune_core.env.sun.shadow_cylindrical` == 1.

    Parameters
    ----------
    r_eci : array_like (..., 3)
        Satellite position [m], ECI.
    sun_eci : array_like (..., 3)
        Geocentric Sun position [m], ECI.

    Returns
    -------
    ndarray of bool (...)
        True where the shadow function is above 0.5 (lit).
    """
    return shadow_cylindrical(r_eci, sun_eci) > 0.5


def sun_sensor(model: SunSensor, s_body, lit, normals) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Measured unit Sun vector: exp([std n]x) s (Rodrigues), and where it is valid.

    ``s_body`` (..., 3) true unit vector, ``lit`` (...) bool (:func:`illuminated`),
    ``normals`` (..., 3).

    Parameters
    ----------
    model : SunSensor
        Noise, field of view and boresight.
    s_body : array_like (..., 3)
        True unit Sun vector, body axes.
    lit : array_like of bool (...)
        Whether the satellite is lit.
    normals : array_like (..., 3)
        Standard normals of the rotation error.

    Returns
    -------
    s_m : ndarray (..., 3)
        Measured unit vector (computed everywhere; use it only where ``valid``).
    valid : ndarray (...) bool
        Lit and inside the field of view.
    in_fov : ndarray (...) bool
        Inside the field of view (lit or not).
    """
    s = np.asarray(s_body, dtype=float)
    bore = np.asarray(model.boresight, dtype=float)
    in_fov = np.sum(s * bore, axis=-1) >= math.cos(model.fov_half_angle) * np.linalg.norm(bore)
    if model.noise_std > 0:
        th = model.noise_std * np.asarray(normals, dtype=float)
        ang = np.linalg.norm(th, axis=-1, keepdims=True)
        k = th / np.where(ang > 0, ang, 1.0)
        s = (s * np.cos(ang) + cross(k, s) * np.sin(ang)
             + k * np.sum(k * s, axis=-1, keepdims=True) * (1.0 - np.cos(ang)))
        s = s / np.linalg.norm(s, axis=-1, keepdims=True)
    return s, np.asarray(lit, dtype=bool) & in_fov, in_fov


# ---------------------------------------------------------------- position fix
@dataclass(frozen=True)
class PositionFix:
    """GNSS-like fix of position and velocity in the ECI frame of the environment (frame 'eci')."""

    noise_std: float = 0.0  #: position error std per axis [m]
    velocity_noise_std: float = 0.0  #: velocity error std per axis [m/s]


def position_fix(model: PositionFix, r_eci, v_eci, normals) -> tuple[np.ndarray, np.ndarray]:
    """Measured (r [m], v [m/s]), (..., 3) each; ``normals`` (..., 6): position then velocity.

    Parameters
    ----------
    model : PositionFix
        Position and velocity noise stds.
    r_eci : array_like (..., 3)
        True position [m], ECI.
    v_eci : array_like (..., 3)
        True velocity [m/s], ECI.
    normals : array_like (..., 6)
        Standard normals: position (first 3), velocity (last 3).

    Returns
    -------
    r : ndarray (..., 3)
        Measured position [m].
    v : ndarray (..., 3)
        Measured velocity [m/s].
    """
    r, v, n = (np.asarray(a, dtype=float) for a in (r_eci, v_eci, normals))
    if model.noise_std > 0:
        r = r + model.noise_std * n[..., 0:3]
    if model.velocity_noise_std > 0:
        v = v + model.velocity_noise_std * n[..., 3:6]
    return r, v


# ---------------------------------------------------------------- the suite of one node
@dataclass(frozen=True)
class SensorSuite:
    """The sensors of one satellite, from the parsed ``SENSOR_FIELDS`` (:meth:`from_values`)."""

    ts: float = TS_DEFAULT  #: sample period [s]
    magnetometer: Magnetometer = field(default_factory=Magnetometer)
    gyro: Gyro = field(default_factory=Gyro)
    attitude_std: float = 0.0  #: std of the attitude solution's error per axis [rad]
    sun: SunSensor = field(default_factory=SunSensor)
    position: PositionFix = field(default_factory=PositionFix)

    @property
    def noisy(self) -> bool:
        """Any noise or bias on the controller path (else the truth is measured, no draw).

        Returns
        -------
        bool
            True if the magnetometer, gyro or attitude solution has any noise, bias, matrix or quantum.
        """
        m, g = self.magnetometer, self.gyro
        return bool(m.noise_std or any(m.bias) or m.matrix != _IDENTITY9 or m.quantum or g.arw or g.rrw
                    or any(g.bias) or self.attitude_std)

    @classmethod
    def from_values(cls, v: dict) -> "SensorSuite":
        """From the parsed node parameters (the gyro: :func:`gyro_from`).

        Parameters
        ----------
        v : dict
            Parsed ``SENSOR_FIELDS`` values (ts, mag_*, gyro_*, attitude_noise_std, sun_*, position/velocity noise).

        Returns
        -------
        SensorSuite
            The sensors of the node.
        """
        ts = float(v["ts"])
        return cls(ts, Magnetometer(float(v["mag_noise_std"]), _t(v["mag_bias"]), _t(v["mag_matrix"]),
                                    float(v["mag_quantum"])),
                   gyro_from(v["gyro_noise_std"], v["gyro_arw"], v["gyro_rrw"], v["gyro_bias"], ts),
                   float(v["attitude_noise_std"]),
                   SunSensor(float(v["sun_noise_std"]), float(v["sun_fov_half_angle"]), _t(v["sun_boresight"])),
                   PositionFix(float(v["position_noise_std"]), float(v["velocity_noise_std"])))


def _t(a) -> tuple:
    return tuple(float(x) for x in np.asarray(a, dtype=float).ravel())


def default_suite(ts: float = TS_DEFAULT) -> SensorSuite:
    """The estimator runs' default sensors (docs/estimation.md#parameters): 100 nT magnetometer, MEMS
    gyro sigma_v 1e-4 rad/s^0.5 (0.34 deg/h^0.5), sigma_u 1e-6 rad/s^1.5, bias (40, -60, 30) deg/h,
    whole-sphere coarse sun sensors 0.5 deg per axis, 10 m / 0.01 m/s position fix.

    Parameters
    ----------
    ts : float
        Sample period [s].

    Returns
    -------
    SensorSuite
        The default suite (attitude_std 0).
    """
    bias = tuple(np.deg2rad(np.array([40.0, -60.0, 30.0])) / 3600.0)
    return SensorSuite(ts, Magnetometer(100e-9), Gyro(1e-4, 1e-6, bias), 0.0, SunSensor(math.radians(0.5)),
                       PositionFix(10.0, 0.01))
