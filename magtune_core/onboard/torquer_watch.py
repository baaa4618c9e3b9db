"""On-board detection of torquer faults from the momentum residual (no truth): dead, stuck, reversed, gain drop.

The body's angular momentum changes only by the torques on it. Over a window, the measured change
J (w_end - w_start) (w: the gyro minus the estimated bias, the estimator's published rate), plus the
integral of the gyroscopic term w x (J w + h) (h: the wheel's momentum), minus the integral of the
modelled torques (the commanded dipole x the measured field, the calibrated residual dipole x the field,
the gravity gradient of the attitude estimate) is the integral of what the model misses: a dipole error
dm entering as dm x b = S(b) dm, and a bounded rest. Robotics' generalized momentum observer: the gyro is
never differentiated, its white noise enters at the window's ends, not once per sample over Ts.

Per torquer axis i the applied dipole is (1 + g_i) m_i + c_i (m_i commanded): ``c`` an offset (the
residual dipole, a stuck torquer's value), ``g`` a gain error (dead -1, reversed -2, half gain -0.5;
stuck: -1 with c its value). The residual R_k (trapezoid rule between samples) is averaged over
sub-windows of ``sub_window`` samples; the equations y_j = R_(j+1) - R_j between consecutive sub-window
means (one outlier sample weighs 1/``sub_window``, the end-point noise variance falls by ``sub_window``)
are regressed on [S(b), S(b) diag(m)] (their sub-window means the same way): 6 unknowns (c, g).

Noise model, derived, not fitted: the gyro's white part (``FilterModel``'s sigma_v, sigma_u, ts) enters
through the end points (J) and the gyroscopic integral (its Jacobian A = [w]x J - [J w + h]x), exactly per
sample; consecutive equations share a sub-window (a block-tridiagonal covariance, checked against a Monte
Carlo in tests/onboard/test_torquer_watch.py). The estimator's bias error db (std ``bias_error_std``,
correlation time ``bias_error_time``) enters through the same coefficients, and an unmodelled torque (std
``torque_std``), both first-order Gauss-Markov held per sub-window: with the wheel, a bias error of 5e-5
rad/s is a torque h x db of 1e-4 N m in the x-y plane, as much as 3 A m^2 in a 3e-5 T field. The fit is
generalized least squares against that covariance, with a vague prior (:data:`PRIOR_STD`) so an axis that
is never commanded has an unbounded, not a singular, gain.

Test (every sub-window; windows of ``windows`` equations, the shorter ones so a fault's onset does not dilute
the evidence): single-fault structured hypotheses. H0: every axis nominal (g = 0, |c| <= ``residual_bound``);
H_i: axis i anything, the other two nominal. D0, D_i are the chi-square distances of the fit from them
(:func:`box_min`), T_i = D0 - D_i the generalized likelihood ratio of H_i. Under H0, every T_i <= D0 <= a
chi-square of 6 degrees of freedom: P(max_i T_i > gamma) <= ``false_alarm`` per test with gamma the
chi-square(6) level of ``false_alarm`` / len(windows) (55.7 for 1e-9). An axis is isolated when its T_i
exceeds gamma and every other axis' T by ``isolation_margin``, H_i leaves at most ``isolation_fit``
unexplained and i leads every shorter window over gamma; a fault is declared after ``persistence`` tests
isolating the same axis. Its kind: the distances of the axis' (c_i, g_i), conditioned on the others
nominal, from each kind's set; named once the window fits the model (:func:`chi2_level`: a window the fault
began in does not) and one kind is nearer by ``kind_margin``, else the verdict says ``fault`` and a later verdict names the kind.

Gyro and field spikes (beyond ``spike_gate``, ``field_gate``) are replaced by the previous sample; more than
``gate_limit`` in a row restart the window (a step). Pure, no clock, no I/O; the state is a handful of small
arrays, all of which may carry leading batch axes (``shape``: a ground bench replays many noise draws with the
same arithmetic); the flight watch is ``shape=()`` and :meth:`TorquerWatch.step` returns a
:class:`TorquerVerdict` or None. Inhibit it (``active=False``) where the model does not hold or its inputs do
not exist: DETUMBLE (no attitude, fast rates), SAFE, an estimate not valid; rates above ``max_rate`` inhibit
it by themselves. docs/modes.md#torquer-fault-detection has the figures and what it cannot see.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..base.rotations import cross, rotation_matrix, skew_field
from .modes import ACQUISITION, DETUMBLE, POINTING, SAFE

#: Fault kinds, by code (the index in ``TorquerWatch.declared``; -1: none).
DEAD, STUCK, REVERSED, GAIN_DROP = "dead", "stuck", "reversed", "gain drop"
#: A fault no kind's set explains (e.g. a gain above the command's); one whose kind the window cannot tell yet.
UNEXPLAINED, UNRESOLVED = "unexplained", "fault"
KINDS = (DEAD, STUCK, REVERSED, GAIN_DROP, UNEXPLAINED, UNRESOLVED)
UNEXPLAINED_CODE, UNRESOLVED_CODE = KINDS.index(UNEXPLAINED), KINDS.index(UNRESOLVED)
AXES = ("x", "y", "z")
#: Vague prior std of the unknowns: offset [A m^2], gain error [-].
PRIOR_STD = (1e3, 1e2)
NPAR = 6


@dataclass(frozen=True)
class TorquerWatchParams:
    """Spacecraft, sensor noise and decision parameters of :class:`TorquerWatch` (SI units).

    The defaults are the paper's satellite (inertia, pitch wheel, orbit rate) and the estimator's
    default gyro model; ``bias_error_std`` / ``bias_error_time`` the on-board MEKF's gyro-bias error in the
    paper environment, magnetometer only (RMS 9-10 deg/h on x and y; its autocorrelation 0.78 at 300 s, which a
    first-order process of 1200 s matches: docs/estimation.md, docs/modes.md#torquer-fault-detection).
    """

    inertia: tuple = (35.0, 17.0, 25.0)  #: principal moments (3) or the full matrix (9, row-major) [kg m^2]
    wheel_momentum: tuple = (0.0, 0.0, 2.0)  #: wheel angular momentum h in body axes [N m s]
    orbit_rate: float = 1.1190399136531285e-3  #: W0 [rad/s] of the gravity gradient (0: not modelled)
    ts: float = 1.0  #: sample period [s]
    gyro_arw: float = 1e-4  #: sigma_v [rad/s^0.5]
    gyro_rrw: float = 1e-6  #: sigma_u [rad/s^1.5]
    bias_error_std: float = 5e-5  #: std of the bias estimate's error [rad/s] per axis
    bias_error_time: float = 1200.0  #: its correlation time [s] (also the unmodelled torque's)
    torque_std: float = 2e-6  #: std of unmodelled torques [N m] per axis (gravity gradient of a 2-deg error)
    residual_dipole: tuple = (0.0, 0.0, 0.0)  #: calibrated residual dipole, modelled [A m^2]
    residual_bound: float = 2.0  #: bound of the uncalibrated residual dipole per axis [A m^2]
    #: the fraction of a period the torquers drive (onboard.torquers.Torquers.on_fraction): a duty-cycled period
    #: applies this times the command as published, compensated or not (unmodelled, a 0.2-s off time at 1 s
    #: read as a gain drop of 0.2 on every axis: 2 of 20 fault-free batched runs were declared)
    on_fraction: float = 1.0
    sub_window: int = 60  #: samples per sub-window (one test per sub-window)
    windows: tuple = (8, 4, 2)  #: equations per test window, longest first: a window spans n + 1 sub-windows
    min_window: int = 8  #: equations needed before the first test after a (re)start
    false_alarm: float = 1e-9  #: bound of the false-alarm probability per test (all three axes)
    persistence: int = 2  #: consecutive tests over the threshold before a verdict
    fit_limit: float = 13.8  #: a kind fits when its distance is below this (chi-square 2 dof, 1e-3)
    kind_penalty: float = 2.0  #: added to the distance of a kind with a free parameter (stuck, gain drop)
    kind_margin: float = 4.0  #: a kind is named when nearer (penalized) than the next by this
    isolation_margin: float = 16.0  #: an axis is blamed when its T exceeds every other axis' by this ...
    isolation_fit: float = 18.5  #: ... and its hypothesis leaves at most this unexplained (chi-square 4, 1e-3)
    gain_drop: tuple = (0.1, 0.9)  #: remaining gain of a gain drop [-]
    max_rate: float = 0.02  #: inhibited above this |w| [rad/s]
    spike_gate: float = 1.5e-3  #: a gyro sample changing by more is replaced by the previous one [rad/s]
    field_gate: float = 1e-5  #: a field sample changing by more is replaced by the previous one [T]
    gate_limit: int = 3  #: more replaced samples in a row restart the window

    @property
    def threshold(self) -> float:
        """gamma: the chi-square(6) level exceeded with probability ``false_alarm`` / (number of windows): 55.7
        for 1e-9 and 3 windows (a union bound over the windows of one test).

        Returns
        -------
        float
            The test threshold.
        """
        return chi2_even_level(self.false_alarm / len(self.windows), 2 * 3)

    @property
    def white_std(self) -> float:
        """Std [rad/s] of the white part of one gyro sample: sqrt(sigma_v^2 / ts + sigma_u^2 ts / 12).

        Returns
        -------
        float
            The std per axis [rad/s].
        """
        return math.sqrt(self.gyro_arw**2 / self.ts + self.gyro_rrw**2 * self.ts / 12.0)

    @classmethod
    def of_filter(cls, model, inertia, wheel_momentum, orbit_rate: float, **kw) -> "TorquerWatchParams":
        """The watch matched to the estimator's sensor model and the spacecraft.

        Parameters
        ----------
        model : FilterModel
            :class:`magtune_core.onboard.estimator.FilterModel` (its ``ts``, ``gyro_arw``, ``gyro_rrw``).
        inertia : array_like (3,) or (3, 3)
            Inertia [kg m^2].
        wheel_momentum : array_like (3,)
            Wheel momentum in body axes [N m s].
        orbit_rate : float
            W0 [rad/s].
        **kw
            Other fields.

        Returns
        -------
        TorquerWatchParams
            The parameters.
        """
        return cls(inertia=tuple(float(v) for v in np.ravel(inertia)),
                   wheel_momentum=tuple(float(v) for v in np.ravel(wheel_momentum)), orbit_rate=float(orbit_rate),
                   ts=float(model.ts), gyro_arw=float(model.gyro_arw), gyro_rrw=float(model.gyro_rrw), **kw)

    def inertia_matrix(self) -> np.ndarray:
        """J (3, 3) [kg m^2].

        Returns
        -------
        ndarray (3, 3)
            Diagonal from 3 moments, or the 9 values row-major.
        """
        v = np.asarray(self.inertia, dtype=float)
        return np.diag(v) if v.size == 3 else v.reshape(3, 3)


def watch_mode(mode: str | None, armed: bool) -> tuple[bool, bool]:
    """Whether the flight mode lets the watch run this sample, and whether it is armed after it.

    Armed in POINTING, disarmed by DETUMBLE and SAFE; it watches in POINTING, and in ACQUISITION only while armed:
    an ACQUISITION that a fault forced out of POINTING (a stuck torquer does that before the field has turned
    enough to isolate it), not the capture after a detumble, whose spin-up, saturated commands and young bias
    estimate the model does not hold for (545 of 1000 fault-free batched deployments named a torquer there,
    none after settling). Without a mode manager (``mode`` None) it always watches.

    Parameters
    ----------
    mode : str or None
        The mode manager's mode (onboard.modes.MODES), None without one.
    armed : bool
        Armed before this sample.

    Returns
    -------
    (bool, bool)
        The mode lets the watch run; armed after this sample.
    """
    armed = (armed or mode == POINTING) and mode not in (DETUMBLE, SAFE)
    return mode in (None, POINTING) or (mode == ACQUISITION and armed), armed


def unit_name(axis: int) -> str:
    """The name of torquer ``axis`` as a unit (the issue's ``torquer x|y|z``: /diagnostics, mode notices, campaign rows).

    Parameters
    ----------
    axis : int
        0, 1, 2.

    Returns
    -------
    str
        E.g. ``torquer y``.
    """
    return f"torquer {AXES[axis]}"


@dataclass(frozen=True)
class TorquerVerdict:
    """A declared torquer fault: ``axis`` (0, 1, 2), ``kind`` (:data:`KINDS`), the test statistic and the
    axis' estimates at the declaring test (offset [A m^2], gain error [-], their stds). ``str()`` is the
    message, e.g. ``torquer z: stuck``."""

    axis: int
    kind: str
    statistic: float
    offset: float
    gain: float
    offset_std: float
    gain_std: float

    @property
    def unit(self) -> str:
        """The unit's name on /diagnostics and in campaign rows.

        Returns
        -------
        str
            :func:`unit_name` of the axis, e.g. ``torquer z``.
        """
        return unit_name(self.axis)

    def __str__(self) -> str:
        return f"{self.unit}: {self.kind}"

    @property
    def detail(self) -> str:
        """The message with the estimates.

        Returns
        -------
        str
            E.g. ``torquer z: stuck (T 812 > threshold; offset 9.9 +- 0.4 A m^2, gain -1.0 +- 0.2)``.
        """
        return (f"{self} (T {self.statistic:.3g}; offset {self.offset:.3g} +- {self.offset_std:.2g} A m^2, "
                f"gain {self.gain:+.3g} +- {self.gain_std:.2g})")


def _skew(v) -> np.ndarray:
    """[v]x (..., 3, 3) with [v]x u = v x u."""
    return -skew_field(v)


def box_distance(theta, Pi, c_box, g_box) -> np.ndarray:
    """min over c in ``c_box``, g in ``g_box`` of [c_hat - c, g_hat - g] Pi [c_hat - c, g_hat - g]^T.

    A convex quadratic over a box: its minimum is the unconstrained one if inside, else on an edge,
    where it is the clipped one-dimensional minimum.

    Parameters
    ----------
    theta : ndarray (..., 2)
        (c_hat, g_hat) of one axis.
    Pi : ndarray (..., 2, 2)
        Inverse of their covariance.
    c_box, g_box : tuple of float
        (lo, hi) of the offset [A m^2] and the gain error (lo == hi: a point; +-inf allowed for c).

    Returns
    -------
    ndarray (...)
        The chi-square distance to the box.
    """
    c, g = theta[..., 0], theta[..., 1]
    pcc, pcg, pgg = Pi[..., 0, 0], Pi[..., 0, 1], Pi[..., 1, 1]

    def q(cc, gg):
        dc, dg = c - cc, g - gg
        with np.errstate(invalid="ignore"):
            out = pcc * dc * dc + 2.0 * pcg * dc * dg + pgg * dg * dg
        return np.where(np.isfinite(cc) & np.isfinite(gg), out, np.inf)

    inside = (c_box[0] <= c) & (c <= c_box[1]) & (g_box[0] <= g) & (g <= g_box[1])
    best = np.where(inside, 0.0, np.inf)
    for gg in g_box:  # edges g = const: c clipped
        cc = np.clip(c + pcg * (g - gg) / pcc, *c_box)
        best = np.minimum(best, q(cc, np.full_like(c, gg)))
    for cc in c_box:  # edges c = const: g clipped
        if np.isfinite(cc):
            gg = np.clip(g + pcg * (c - cc) / pgg, *g_box)
            best = np.minimum(best, q(np.full_like(g, cc), gg))
    return best


def chi2_level(dof, z: float = 3.09):
    """The chi-square(dof) level exceeded with the normal tail probability of ``z`` (Wilson-Hilferty).

    Parameters
    ----------
    dof : array_like
        Degrees of freedom (> 0).
    z : float
        Normal quantile (3.09: probability 1e-3).

    Returns
    -------
    ndarray
        dof (1 - 2/(9 dof) + z sqrt(2/(9 dof)))^3.
    """
    k = np.maximum(np.asarray(dof, dtype=float), 1.0)
    return k * (1.0 - 2.0 / (9.0 * k) + z * np.sqrt(2.0 / (9.0 * k))) ** 3


def chi2_even_level(probability: float, dof: int) -> float:
    """The level a chi-square of even ``dof`` exceeds with ``probability``.

    P(X > x) = exp(-x/2) sum_(k < dof/2) (x/2)^k / k!, solved by bisection (decreasing in x).

    Parameters
    ----------
    probability : float
        Tail probability in (0, 1).
    dof : int
        Degrees of freedom (even).

    Returns
    -------
    float
        The level x.
    """
    def tail(x):
        term, total = 1.0, 1.0
        for k in range(1, dof // 2):
            term *= 0.5 * x / k
            total += term
        return math.exp(-0.5 * x) * total

    lo, hi = 0.0, 10.0 * dof - 20.0 * math.log(probability)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if tail(mid) > probability else (lo, mid)
    return 0.5 * (lo + hi)


_FACES: dict = {}


def _faces(lo: tuple, hi: tuple) -> list:
    """The faces of a box (cached per box): (held indices, their values, free indices, boxed free indices)."""
    key = (lo, hi)
    if key not in _FACES:
        n = len(lo)
        boxed = [i for i in range(n) if lo[i] < hi[i] and (math.isfinite(lo[i]) or math.isfinite(hi[i]))]
        held = [i for i in range(n) if lo[i] == hi[i]]
        faces = []
        for face in np.ndindex(*(3,) * len(boxed)):  # each boxed variable: 0 free, 1 at lo, 2 at hi
            at = {i: (lo, hi)[f - 1][i] for f, i in zip(face, boxed) if f}
            if any(math.isinf(v) for v in at.values()):
                continue
            C = held + sorted(at)
            F = [i for i in range(n) if i not in C]
            v = np.array([lo[i] if i in held else at[i] for i in C])
            faces.append((np.array(C, int), v, np.array(F, int), [i for i in boxed if i in F]))
        _FACES[key] = faces
    return _FACES[key]


def box_min(theta, P, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """min over lo <= x <= hi of (x - theta)^T P^-1 (x - theta), and the minimizer.

    A convex quadratic over a box: its minimum is the unconstrained minimum of one face (each bounded
    variable free, or at its lower or upper bound) that lies in the box; the minimum over the feasible face
    minima is the box's. On a face whose constrained variables C are held at v, the free ones F are the
    conditional mean theta_F + P_FC P_CC^-1 (v - theta_C) and the value is (v - theta_C)^T P_CC^-1 (v - theta_C).

    Parameters
    ----------
    theta : ndarray (..., n)
        The estimate.
    P : ndarray (..., n, n)
        Its covariance.
    lo, hi : sequence of float (n,)
        Bounds; lo == hi holds the variable, +-inf leaves it free.

    Returns
    -------
    value : ndarray (...)
        The chi-square distance from the box.
    x : ndarray (..., n)
        The nearest point of the box.
    """
    lo, hi = tuple(float(v) for v in lo), tuple(float(v) for v in hi)
    best = np.full(theta.shape[:-1], np.inf)
    x_best = np.array(theta, dtype=float)
    for C, v, F, boxed_free in _faces(lo, hi):
        x = np.array(theta, dtype=float)
        if C.size:
            d = v - theta[..., C]
            z = np.linalg.solve(P[..., C[:, None], C], d[..., None])
            value = (d * z[..., 0]).sum(-1)
            x[..., C] = v
            if F.size:
                x[..., F] = theta[..., F] + (P[..., F[:, None], C] @ z)[..., 0]
        else:
            value = np.zeros(theta.shape[:-1])
        take = value < best
        for i in boxed_free:
            take &= (x[..., i] >= lo[i] - 1e-12) & (x[..., i] <= hi[i] + 1e-12)
        best = np.where(take, value, best)
        x_best = np.where(take[..., None], x, x_best)
    return best, x_best


def isolate(p: TorquerWatchParams, theta, P, consistent):
    """Single-fault structured hypotheses: the fault-free set, one axis faulty, and that axis' kind.

    H0: every axis nominal (g = 0, |c| <= ``residual_bound``). H_i: axis i anything, the others nominal.
    D0 and D_i are the chi-square distances of the fit from them (:func:`box_min`); T_i = D0 - D_i is the
    generalized likelihood ratio of H_i against H0. Under H0, T_i <= D0 <= a chi-square of 6 degrees of
    freedom, for all three axes at once. The kind of axis i: the distances of its (c_i, g_i), conditioned on
    the other axes at their H_i values, from each kind's set (:func:`box_distance`).

    Parameters
    ----------
    p : TorquerWatchParams
        Residual-dipole bound, gain-drop range, fit limit, kind penalty and margin.
    theta : ndarray (..., 6)
        [c (3), g (3)] of the fit.
    P : ndarray (..., 6, 6)
        Its covariance.
    consistent : ndarray (...) of bool
        The window fits the model (its residual below :func:`chi2_level`): a window a fault began in does not,
        and names no kind.

    The kind's sets: dead {g = -1, |c| <= bound}, stuck {g = -1} (it contains dead, so dead needs no margin
    over it: the penalty of stuck's free offset decides), reversed {g = -2, |c| <= bound}, gain drop
    {1 + g in ``gain_drop``, |c| <= bound}.

    Returns
    -------
    D0 : ndarray (...)
        The distance from H0 (at most a chi-square of 6 degrees of freedom when H0 holds).
    T : ndarray (..., 3)
        D0 - D_i per axis.
    D : ndarray (..., 3)
        D_i: what H_i leaves unexplained (at most a chi-square of 4 degrees of freedom when H_i holds).
    kind : ndarray (..., 3) of int
        Index into :data:`KINDS` per axis: the nearest set (penalized) when the window is consistent and it is
        nearer by ``kind_margin`` than the next; :data:`UNEXPLAINED` when consistent and none is within
        ``fit_limit``; else :data:`UNRESOLVED`.
    est : ndarray (..., 3, 2), sd : ndarray (..., 3, 2)
        The conditional (c_i, g_i) under H_i and their stds.
    """
    cb = p.residual_bound
    lo0, hi0 = [-cb] * 3 + [0.0] * 3, [cb] * 3 + [0.0] * 3
    D0, _ = box_min(theta, P, lo0, hi0)
    lo_g, hi_g = p.gain_drop[0] - 1.0, p.gain_drop[1] - 1.0
    boxes = (((-cb, cb), (-1.0, -1.0)), ((-np.inf, np.inf), (-1.0, -1.0)), ((-cb, cb), (-2.0, -2.0)),
             ((-cb, cb), (lo_g, hi_g)))
    penalty = np.array([0.0, p.kind_penalty, 0.0, p.kind_penalty])
    T, D, kinds, est, sds = [], [], [], [], []
    for i in range(3):
        lo, hi = list(lo0), list(hi0)
        lo[i], hi[i], lo[3 + i], hi[3 + i] = -np.inf, np.inf, -np.inf, np.inf
        Di, x = box_min(theta, P, lo, hi)
        T.append(D0 - Di)
        D.append(Di)
        own, oth = [i, 3 + i], [j for j in range(6) if j not in (i, 3 + i)]
        G = P[..., own, :][..., :, oth] @ np.linalg.inv(P[..., oth, :][..., :, oth])
        cond = P[..., own, :][..., :, own] - G @ P[..., oth, :][..., :, own]
        th = x[..., own]  # the conditional mean: H_i's minimizer on the free axis
        Pi = np.linalg.inv(cond)
        d = np.stack([box_distance(th, Pi, c_box, g_box) for c_box, g_box in boxes], -1)
        pen = d + penalty
        k = np.argmin(pen, -1)
        fits = np.take_along_axis(d, k[..., None], -1)[..., 0] <= p.fit_limit
        rivals = np.where((k[..., None] == 0) & (np.arange(4) == 1), np.inf, pen)  # stuck contains dead: no rival
        clear = np.sort(rivals, -1)[..., 1] - np.min(pen, -1) >= p.kind_margin
        kinds.append(np.where(~consistent, UNRESOLVED_CODE, np.where(~fits, UNEXPLAINED_CODE,
                                                                      np.where(clear, k, UNRESOLVED_CODE))))
        est.append(th)
        sds.append(np.sqrt(np.diagonal(cond, axis1=-2, axis2=-1)))
    return D0, np.stack(T, -1), np.stack(D, -1), np.stack(kinds, -1), np.stack(est, -2), np.stack(sds, -2)


def _noise_blocks(p: TorquerWatchParams, J, A):
    """Per sub-window, the white-noise covariance pieces of the equations it enters (divided by sigma^2).

    A sub-window B enters y_j = R_(j+1) - R_j (R the sub-window means) as the minus block of y_j, with
    coefficients G-_u = -J/L + (ts/L) s A on the noise of its samples, and as the plus block of y_(j-1), with
    G+_u = J/L + (ts/L) (L - s) A (s = u + 1/2, u the sample's place in B: the trapezoid rule). A, the
    Jacobian of the gyroscopic term, is taken at the sub-window's mean rate (it changes by |J dw| << |h| in it).

    Parameters
    ----------
    p : TorquerWatchParams
        ``ts`` and ``sub_window`` (L).
    J : ndarray (3, 3)
        Inertia.
    A : ndarray (..., 3, 3)
        Per sub-window, dF/dw at its mean rate.

    Returns
    -------
    tuple of ndarray (..., 3, 3)
        sum G- G-^T, sum G+ G+^T, sum G+ G-^T, sum G- and sum G+.
    """
    ts, L = p.ts, float(p.sub_window)
    JJ = J @ J.T
    AA = A @ np.swapaxes(A, -1, -2)
    JA = J @ np.swapaxes(A, -1, -2)
    AJ = A @ J.T
    s2 = L / 3.0 - 1.0 / (12.0 * L)  # sum of s^2 / L^3 ... over u = 0 .. L-1, per L^2
    mm = JJ / L - 0.5 * ts * (JA + AJ) + ts * ts * s2 * AA
    pp = JJ / L + 0.5 * ts * (JA + AJ) + ts * ts * s2 * AA
    pm = -JJ / L + 0.5 * ts * (JA - AJ) + ts * ts * (L / 6.0 + 1.0 / (12.0 * L)) * AA
    return mm, pp, pm, -J + 0.5 * ts * L * A, J + 0.5 * ts * L * A


def _covariance(p: TorquerWatchParams, J, A, ok):
    """Covariance (..., 3n, 3n) of the n equations of a window of n + 1 sub-windows.

    Parameters
    ----------
    p : TorquerWatchParams
        Noise parameters.
    J : ndarray (3, 3)
        Inertia.
    A : ndarray (..., n + 1, 3, 3)
        Per sub-window, the gyroscopic Jacobian at its mean rate.
    ok : ndarray (..., n) of bool
        Equations in use (the others get a unit, uncoupled variance).

    Returns
    -------
    ndarray (..., 3n, 3n)
        White gyro noise (tridiagonal) + bias error and unmodelled torque (Gauss-Markov, held per sub-window).
    """
    L = p.sub_window
    mm, pp, pm, gm, gp = _noise_blocks(p, J, A)
    n = mm.shape[-3] - 1
    shape = mm.shape[:-3]
    s2 = p.white_std**2
    C = np.zeros(shape + (n, 3, n + 1, 3))
    W = np.zeros(shape + (n, 3, n, 3))
    for j in range(n):
        W[..., j, :, j, :] = s2 * (mm[..., j, :, :] + pp[..., j + 1, :, :])
        if j + 1 < n:
            W[..., j, :, j + 1, :] = s2 * pm[..., j + 1, :, :]  # E[y_j y_(j+1)^T]: G+ of y_j, G- of y_(j+1)
            W[..., j + 1, :, j, :] = s2 * np.swapaxes(pm[..., j + 1, :, :], -1, -2)
        C[..., j, :, j, :] = gm[..., j, :, :]
        C[..., j, :, j + 1, :] = gp[..., j + 1, :, :]
    k = np.arange(n + 1)
    rho = np.exp(-np.abs(k[:, None] - k[None, :]) * L * p.ts / p.bias_error_time)
    C = C.reshape(shape + (3 * n, 3 * (n + 1)))
    Cov = W.reshape(shape + (3 * n, 3 * n)) + p.bias_error_std**2 * C @ np.kron(rho, np.eye(3)) @ np.swapaxes(C, -1, -2)
    Cu = np.zeros((n, n + 1))
    Cu[k[:-1], k[:-1]] = Cu[k[:-1], k[1:]] = 0.5 * L * p.ts  # a torque held per sub-window
    Cov = Cov + p.torque_std**2 * np.kron(Cu @ rho @ Cu.T, np.eye(3))
    m3 = np.repeat(ok, 3, axis=-1)
    Cov = np.where(m3[..., :, None] & m3[..., None, :], Cov, 0.0)
    return Cov + np.where(m3, 0.0, 1.0)[..., None] * np.eye(3 * n)


def fit(p: TorquerWatchParams, J, Y, Phi, A, ok) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Generalized least squares of the window's equations Y = Phi theta + e, with the vague prior.

    Parameters
    ----------
    p : TorquerWatchParams
        Noise parameters.
    J : ndarray (3, 3)
        Inertia.
    Y : ndarray (..., n, 3)
        y_j = R_(j+1) - R_j [N m s].
    Phi : ndarray (..., n, 3, 6)
        Their regressors.
    A : ndarray (..., n + 1, 3, 3)
        The sub-windows' gyroscopic Jacobians (:func:`_covariance`).
    ok : ndarray (..., n) of bool
        Equations in use.

    Returns
    -------
    theta : ndarray (..., 6)
        [c, g].
    P : ndarray (..., 6, 6)
        Its covariance.
    gof : ndarray (...)
        The weighted residual r^T Cov^-1 r (chi-square of 3 n_used - 6 degrees of freedom for the right model).
    """
    n = Y.shape[-2]
    okf = ok[..., :, None].astype(float)
    y = (Y * okf).reshape(Y.shape[:-2] + (3 * n, 1))
    X = (Phi * okf[..., None]).reshape(Phi.shape[:-3] + (3 * n, NPAR))
    Cov = _covariance(p, J, A, ok)
    WXy = np.linalg.solve(Cov, np.concatenate([X, y], -1))
    WX, Wy = WXy[..., :NPAR], WXy[..., NPAR:]
    F = np.swapaxes(X, -1, -2) @ WX + np.diag(np.repeat(np.asarray(PRIOR_STD, dtype=float), 3) ** -2)
    r = np.swapaxes(WX, -1, -2) @ y
    s = 1.0 / np.sqrt(np.diagonal(F, axis1=-2, axis2=-1))  # equilibrate the offsets against the gains
    P = np.linalg.inv(F * s[..., :, None] * s[..., None, :]) * s[..., :, None] * s[..., None, :]
    theta = P @ r
    gof = (np.swapaxes(y, -1, -2) @ Wy - np.swapaxes(r, -1, -2) @ theta)[..., 0, 0]  # y'Wy - theta'F theta
    return theta[..., 0], 0.5 * (P + np.swapaxes(P, -1, -2)), gof


@dataclass
class TorquerWatch:
    """Torquer fault detector, stepped once per control sample (see the module docstring).

    ``shape`` () for one satellite; a ground bench may give batch axes (every input then carries them).
    After a test (``tests`` counts them): ``d0`` (...) the distance from the fault-free set and ``statistic``
    (..., 3) the T_i (the largest over the windows; nan before the first test), ``kind`` (..., 3) the kind
    index of an isolated axis (-1 elsewhere), ``declared`` (..., 3) the declared kind per axis (-1: none),
    ``theta``/``P`` the fit of the window used and ``estimate``/``estimate_std`` (..., 3, 2) each axis'
    (c_i, g_i) under its hypothesis.
    """

    params: TorquerWatchParams = field(default_factory=TorquerWatchParams)
    shape: tuple = ()

    def __post_init__(self):
        p, S = self.params, tuple(self.shape)
        self.J = p.inertia_matrix()
        self.m_cal = np.asarray(p.residual_dipole, dtype=float)
        self.h = np.asarray(p.wheel_momentum, dtype=float)
        nb = p.windows[0] + 1
        self.k = 0  # samples into the current sub-window (common to the batch)
        self.tests = 0
        self.have_prev = np.zeros(S, bool)
        self.w_prev, self.b_prev, self.F_prev = np.zeros(S + (3,)), np.zeros(S + (3,)), np.zeros(S + (3,))
        self.rejected = np.zeros(S, int)
        self.cum, self.cum_psi = np.zeros(S + (3,)), np.zeros(S + (3, NPAR))
        self.sum_R, self.sum_psi, self.sum_w = np.zeros(S + (3,)), np.zeros(S + (3, NPAR)), np.zeros(S + (3,))
        self.bad = np.zeros(S, bool)
        self.ring_R, self.ring_psi, self.ring_A = np.zeros(S + (nb, 3)), np.zeros(S + (nb, 3, NPAR)), np.zeros(
            S + (nb, 3, 3))
        self.nblocks = np.zeros(S, int)
        self.count, self.pending = np.zeros(S + (3,), int), np.zeros(S + (3,), int)
        self.pending_kind, self.declared, self.kind = np.full(S + (3,), -1), np.full(S + (3,), -1), np.full(S + (3,), -1)
        self.statistic, self.d0 = np.full(S + (3,), np.nan), np.full(S, np.nan)
        self.estimate, self.estimate_std = np.full(S + (3, 2), np.nan), np.full(S + (3, 2), np.nan)
        self.gof, self.dof = np.full(S, np.nan), np.zeros(S, int)
        self.theta, self.P = np.full(S + (NPAR,), np.nan), np.full(S + (NPAR, NPAR), np.nan)

    def reset(self) -> None:
        """Forget everything, the declared faults included (a ground command after a repair or a new law)."""
        self.__post_init__()

    def step(self, w, b, m_prev, q=None, active=True) -> TorquerVerdict | None:
        """Take one control sample; the verdict when a fault is declared or its kind changes.

        Parameters
        ----------
        w : array_like (..., 3)
            Gyro minus the estimated bias [rad/s], body axes (nan: no sample).
        b : array_like (..., 3) or None
            Measured field [T], body axes (nan or None: no sample).
        m_prev : array_like (..., 3)
            Dipole commanded for the period that just ended [A m^2].
        q : array_like (..., 4) or None
            Attitude estimate w.r.t. the orbital axes, scalar first (None: no gravity-gradient model).
        active : bool or array_like of bool (...)
            False inhibits (the window restarts): DETUMBLE, SAFE, an estimate not valid.

        Returns
        -------
        TorquerVerdict or None
            One satellite (``shape`` ()): the new verdict (the largest statistic if two axes at once), else
            None. With batch axes always None: read ``declared`` and the mask :meth:`advance` returns.
        """
        new = self.advance(w, b, m_prev, q, active)
        if self.shape != () or not new.any():
            return None
        i = int(np.argmax(np.where(new, self.statistic, -np.inf)))
        return self.verdict(i)

    def verdict(self, axis: int) -> TorquerVerdict:
        """The declared verdict of ``axis`` with the last test's figures (one satellite).

        Parameters
        ----------
        axis : int
            0, 1, 2.

        Returns
        -------
        TorquerVerdict
            Its kind (``declared``; the nearest kind if none is declared), statistic and estimates.
        """
        k = int(self.declared[axis]) if self.declared[axis] >= 0 else int(self.kind[axis])
        (c, g), (sc, sg) = self.estimate[axis], self.estimate_std[axis]
        return TorquerVerdict(axis, KINDS[k] if k >= 0 else "", float(self.statistic[axis]), float(c), float(g),
                              float(sc), float(sg))

    def advance(self, w, b, m_prev, q=None, active=True) -> np.ndarray:
        """:meth:`step` on any batch shape.

        Parameters
        ----------
        w, b, m_prev, q, active
            As :meth:`step`.

        Returns
        -------
        ndarray (..., 3) of bool
            Axes whose verdict is new at this sample.
        """
        S, p = tuple(self.shape), self.params
        w = np.asarray(w, dtype=float)
        b = np.full(S + (3,), np.nan) if b is None else np.asarray(b, dtype=float)
        m = np.asarray(m_prev, dtype=float) * p.on_fraction  # the period's mean dipole, as commanded
        ok = np.asarray(active, bool) & np.isfinite(w.sum(-1) + b.sum(-1) + m.sum(-1))
        if q is not None:
            q = np.asarray(q, dtype=float)
            ok = ok & np.isfinite(q.sum(-1))
        if not ok.all():
            w, b, m = (np.where(ok[..., None], v, 0.0) for v in (w, b, m))
            q = None if q is None else np.where(ok[..., None], q, np.array([1.0, 0.0, 0.0, 0.0]))
        w, b = self._gate(w, b, ok)
        ok = ok & ((w * w).sum(-1) <= p.max_rate**2)  # after the gate: a spike is not a fast rate
        self._integrate(w, b, m, q, ok)
        self.k += 1
        if self.k == p.sub_window:
            return self._close_block()
        return np.zeros(S + (3,), bool)

    def _gate(self, w, b, ok):
        """Replace a spike by the previous sample; a run of them longer than ``gate_limit`` is a step: restart."""
        p = self.params
        spike = self.have_prev & ok & ((np.abs(w - self.w_prev).max(-1) > p.spike_gate)
                                       | (np.abs(b - self.b_prev).max(-1) > p.field_gate))
        if not spike.any() and not self.rejected.any():
            return w, b
        self.rejected = np.where(spike, self.rejected + 1, 0)
        step = self.rejected > p.gate_limit
        hold = spike & ~step
        self.have_prev = self.have_prev & ~step  # a step: no integration across it, the window restarts
        self.rejected = np.where(step, 0, self.rejected)
        return np.where(hold[..., None], self.w_prev, w), np.where(hold[..., None], self.b_prev, b)

    def _integrate(self, w, b, m, q, ok) -> None:
        """One trapezoid step of the residual R_k and its regressors; the sub-window's sums."""
        p, J, ts = self.params, self.J, self.params.ts
        H = w @ J.T + self.h
        F = cross(w, H)
        if q is not None and p.orbit_rate > 0:
            c = rotation_matrix(q)[..., 0, :]  # nadir in body axes: R^T e_X, the first row of R
            F = F - 3.0 * p.orbit_rate**2 * cross(c, c @ J.T)
        go = ok & self.have_prev
        bm = 0.5 * (self.b_prev + b)
        Sb = skew_field(bm)
        torque = 0.5 * (self.F_prev + F) - cross(m + self.m_cal, bm)
        dpsi = np.concatenate([Sb, Sb * m[..., None, :]], -1)
        if go.all():
            self.cum = self.cum + ts * torque
            self.cum_psi = self.cum_psi + ts * dpsi
        else:
            self.cum = self.cum + ts * np.where(go[..., None], torque, 0.0)
            self.cum_psi = self.cum_psi + ts * np.where(go[..., None, None], dpsi, 0.0)
        self.sum_R = self.sum_R + w @ J.T + self.cum
        self.sum_psi = self.sum_psi + self.cum_psi
        self.sum_w = self.sum_w + w
        # a sample that could not be integrated (no previous one) breaks the sub-window, unless it is its first
        self.bad = self.bad | ~ok | (~self.have_prev & (self.k > 0))
        self.have_prev = ok
        self.w_prev, self.b_prev, self.F_prev = w, b, F

    def _close_block(self) -> np.ndarray:
        """End of a sub-window: keep its means, test the windows, decide."""
        p, L, S = self.params, float(self.params.sub_window), tuple(self.shape)
        good = ~self.bad
        w_mean = self.sum_w / L
        H = w_mean @ self.J.T + self.h
        A = _skew(w_mean) @ self.J - _skew(H)
        ax = len(S)
        for name, val in (("ring_R", self.sum_R / L), ("ring_psi", self.sum_psi / L), ("ring_A", A)):
            buf = getattr(self, name)
            rolled = np.concatenate([buf[(slice(None),) * ax + (slice(1, None),)], np.expand_dims(val, ax)], axis=ax)
            setattr(self, name, np.where(good.reshape(S + (1,) * (buf.ndim - len(S))), rolled, buf))
        n = p.windows[0]
        self.nblocks = np.where(good, np.minimum(self.nblocks + 1, n + 1), 0)
        self.sum_R, self.sum_psi, self.sum_w = np.zeros(S + (3,)), np.zeros(S + (3, NPAR)), np.zeros(S + (3,))
        self.bad, self.k = np.zeros(S, bool), 0
        ready = self.nblocks >= p.min_window + 1
        if not ready.any():
            return np.zeros(S + (3,), bool)
        self.tests += 1
        Y, Phi = np.diff(self.ring_R, axis=-2), np.diff(self.ring_psi, axis=-3)
        have = np.arange(n) >= (n + 1 - self.nblocks)[..., None]
        out = []
        for m in p.windows:  # the last m equations
            ok = have[..., n - m:]
            theta, P, gof = fit(p, self.J, Y[..., n - m:, :], Phi[..., n - m:, :, :], self.ring_A[..., n - m:, :, :], ok)
            dof = 3 * ok.sum(-1) - NPAR
            out.append((theta, P, gof, dof) + isolate(p, theta, P, gof <= chi2_level(dof)))
        return self._decide(ready, out)

    def _decide(self, ready, out) -> np.ndarray:
        """Isolation and persistence over the windows of one test.

        A window isolates axis i when T_i is above the threshold, above every other axis' T by
        ``isolation_margin``, H_i leaves at most ``isolation_fit`` unexplained, and i has the largest T of every
        shorter window over the threshold (a tie refutes it): after an onset the longer windows mix the fault with
        the nominal data before it, and the loop's reaction on another axis can explain that mix better, while the
        shorter windows, which hold the fault alone, cannot tell the axes apart yet (without this rule a stuck y
        was declared x first in 11 of 108 batched full-stack runs). The test isolates i when a window does and
        none isolates another axis; its kind and estimates are the longest such window's. A fault is declared on
        an axis isolated in ``persistence`` tests in a row (its kind may be :data:`UNRESOLVED`); a declared axis
        takes another named kind after ``persistence`` tests naming it.
        """
        p, gamma, S = self.params, self.params.threshold, tuple(self.shape)
        iso, pick, lead = np.zeros(S + (3,), bool), np.full(S, -1), np.ones(S + (3,), bool)
        for k in range(len(out) - 1, -1, -1):  # shortest first: the longest isolating window is picked last
            T, D = out[k][5], out[k][6]
            second = np.sort(T, -1)[..., -2:-1]
            iso_k = lead & (T > gamma) & (T - second >= p.isolation_margin) & (D <= p.isolation_fit)
            iso |= iso_k
            pick = np.where(iso_k.any(-1), k, pick)
            lead &= (T > second) | (T.max(-1, keepdims=True) <= gamma)  # i leads this window, or none passes
        single = iso.sum(-1) == 1
        iso &= single[..., None] & ready[..., None]
        def take(j):
            v = np.stack([o[j] for o in out])
            idx = np.maximum(pick, 0).reshape((1,) + S + (1,) * (v.ndim - 1 - len(S)))
            return np.take_along_axis(v, idx, axis=0)[0]

        theta, P, gof, T, kind = take(0), take(1), take(2), np.max(np.stack([o[5] for o in out]), 0), take(7)
        self.d0 = np.where(ready, np.max(np.stack([o[4] for o in out]), 0), np.nan)
        r = ready[..., None]
        self.statistic, self.kind = np.where(r, T, np.nan), np.where(r & iso, kind, -1)
        self.theta, self.P, self.gof = np.where(r, theta, np.nan), np.where(r[..., None], P, np.nan), gof
        self.estimate, self.estimate_std = take(8), take(9)
        undeclared = self.declared < 0
        hit = iso & undeclared
        self.count = np.where(hit, self.count + 1, 0)
        declare = hit & (self.count >= p.persistence)
        other = iso & ~undeclared & (kind != self.declared) & (kind != UNRESOLVED_CODE)
        self.pending = np.where(other & (kind == self.pending_kind), self.pending + 1, np.where(other, 1, 0))
        self.pending_kind = np.where(other, kind, -1)
        change = other & (self.pending >= p.persistence)
        new = declare | change
        self.declared = np.where(new, kind, self.declared)
        self.pending = np.where(change, 0, self.pending)
        self.count = np.where(declare, 0, self.count)
        return new
