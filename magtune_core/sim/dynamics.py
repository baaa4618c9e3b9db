"""Nonlinear attitude dynamics of a momentum-biased, magnetically actuated satellite (pure numpy).

Conventions (SPEC.md "The model", paper section 3):

* orbital axes: X to the Earth's centre (yaw), Y along the velocity (roll), Z = X x Y = minus
  the orbit normal, i.e. opposite the orbital angular momentum r x v (pitch); the orbital frame
  turns about its -Z axis at the orbit rate W0, so its inertial angular velocity in orbital
  axes is ``[0, 0, -W0]``;
* ``q = [q0, q1, q2, q3]`` scalar first, attitude of the body w.r.t. orbital axes; ``R(q)``
  takes body vectors to orbital axes (``v_orb = q (x) v_body (x) q*``);
* ``w``: inertial angular velocity of the body, in body axes;
* Euler equation with a constant-speed pitch wheel of momentum ``h = [0, 0, -J Wwheel]``:
  ``I w' = -w x (I w + h) + T``;
* kinematics (paper eq. 11): ``q' = 0.5 q (x) [0; w - R(q)^T [0, 0, -W0]]``;
* gravity gradient on a circular orbit: ``T_gg = 3 W0^2 c x (I c)``, ``c = R(q)^T e_X`` the nadir
  unit vector in body axes;
* magnetic torque (paper eq. 12): ``T_mag = m x b = S(b) m`` with ``b = R(q)^T b_orb(t)`` the field
  in body axes; residual dipole (paper eq. 32): ``T_d = m_res x b = S(b) [1, 1, 1]^T``.

Linear state (paper eq. 14, SPEC.md): ``x = [dq; dw]`` with ``dq = q_vec`` (sign chosen so that
``q0 >= 0``) and ``dw = w - [0, 0, -W0]``: the deviation of the *inertial* body rate from its
nominal value, both in body axes, the nominal vector taken with constant body components.
This is the choice for which the Jacobian of this model equals ``model.state_matrix`` (A of
eq. 15): the kinematic rows of A, ``dq' = 0.5 dw + [-W0 dq2, W0 dq1, 0]``, come from
``R(q)^T [0,0,-W0] = [0,0,-W0] - 2 dq x [0,0,-W0] + O(dq^2)``.  (Had ``dw`` been the rate
relative to the orbital frame, ``w - R(q)^T [0,0,-W0]``, those W0 terms would move into the
dynamic rows; tests/sim/test_dynamics.py checks both statements.)

The field and the disturbance torques are pluggable: ``field`` is any callable
``t -> b_orb(t)`` (tesla, orbital axes), e.g. ``SpacecraftParams.field()`` (paper eq. 26) or an
IGRF model along the orbit; ``disturbances`` is a list of callables
``(t, q, w, b_body) -> torque in body axes`` [N m] (e.g. aerodynamic drag, solar radiation
pressure). Gravity gradient is part of the rigid-body model, not a plug-in: it defines the
linearization; the residual dipole is built in (``residual_dipole``, scalar code for speed)
and equals the plug-in ``residual_dipole_disturbance``.
"""
from __future__ import annotations

from dataclasses import dataclass
from dataclasses import field as dc_field
from typing import Callable, Sequence

import numpy as np

from ..base.rotations import cross, dcm_floats, rotation_matrix
from ..design.params import SpacecraftParams
from ..env.environment import residual_dipole_torque
from ..onboard.law import saturate

FieldFn = Callable[[float], np.ndarray]
TorqueFn = Callable[[float, np.ndarray, np.ndarray, np.ndarray], np.ndarray]

#: State layout of the nonlinear model: y = [q0, q1, q2, q3, wx, wy, wz].
NY = 7


def magnetic_torque(m, b, m_max=np.inf) -> np.ndarray:
    """T_mag = sat(m) x b = S(b) sat(m) (paper eq. 12) with per-axis dipole saturation [N m].

    Returns
    -------
    ndarray (3,)
        The magnetic torque in body axes [N m] (``m`` clipped to +-``m_max`` per axis first).
    """
    return cross(saturate(m, m_max), b)


def residual_dipole_disturbance(m_res) -> TorqueFn:
    """Plug-in ``(t, q, w, b) -> T_d`` of the residual dipole torque m_res x b (paper eq. 32)."""
    m_res = np.asarray(m_res, dtype=float).reshape(3)

    def torque(t, q, w, b):
        return residual_dipole_torque(m_res, b)

    return torque


@dataclass
class AttitudeDynamics:
    """Rigid body + constant-momentum pitch wheel + gravity gradient on a circular orbit.

    ``rhs(t, y, m)`` is the time derivative of ``y = [q; w]`` under the commanded dipole ``m``
    (already saturated by the caller) plus the plug-in disturbances.
    """

    inertia: np.ndarray
    wheel_momentum: np.ndarray
    orbit_rate: float
    field: FieldFn
    disturbances: Sequence[TorqueFn] = dc_field(default_factory=list)
    gravity_gradient: bool = True
    #: residual magnetic dipole m_res [A m^2] (paper eq. 32): T_d = m_res x b, built in for speed
    residual_dipole: Sequence[float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        I = np.asarray(self.inertia, dtype=float)
        self.inertia = np.diag(I) if I.ndim == 1 else I
        self.inertia_inv = np.linalg.inv(self.inertia)
        self.wheel_momentum = np.asarray(self.wheel_momentum, dtype=float).reshape(3)
        self.disturbances = list(self.disturbances)
        # plain-float copies for the scalar right-hand side
        self._I = tuple(tuple(float(v) for v in r) for r in self.inertia)
        self._J = tuple(tuple(float(v) for v in r) for r in self.inertia_inv)
        self._h = tuple(float(v) for v in self.wheel_momentum)
        self._field_cache: dict = {}
        self.residual_dipole = tuple(float(v) for v in np.asarray(self.residual_dipole, dtype=float).reshape(3))

    def field_at(self, t: float):
        """b_orb(t) as three floats, memoized for the few instants an RK4 step revisits."""
        v = self._field_cache.get(t)
        if v is None:
            if len(self._field_cache) > 8:
                self._field_cache.clear()
            v = self._field_cache[t] = tuple(float(x) for x in np.asarray(self.field(t), dtype=float).reshape(3))
        return v

    @classmethod
    def from_params(cls, p: SpacecraftParams, field: FieldFn | None = None,
                    residual_dipole=(1.0, 1.0, 1.0), disturbances: Sequence[TorqueFn] = ()) -> "AttitudeDynamics":
        """Paper section 5 set-up: eq. (26) field (unless ``field`` given) and the residual dipole."""
        m_res = (0.0, 0.0, 0.0) if residual_dipole is None else residual_dipole
        return cls(p.inertia, p.wheel_momentum, p.orbit_rate, field or p.field(), list(disturbances),
                   residual_dipole=m_res)

    # --- pieces -------------------------------------------------------------------------
    def orbital_frame_rate(self, t: float) -> np.ndarray:
        """w_oi, inertial angular velocity of the orbital frame in orbital axes [rad/s]:
        ``[0, 0, -W0]`` on the circular orbit (the full environment overrides it)."""
        return np.array([0.0, 0.0, -self.orbit_rate])

    def relative_rate(self, t: float, q, w) -> np.ndarray:
        """Angular velocity of the body w.r.t. the orbital frame, in body axes [rad/s]:
        ``w - R(q)^T w_oi(t)`` (what nav_msgs/Odometry's twist holds for frame 'orbital' ->
        child 'body', REP-105); ``w`` is the inertial body rate in body axes."""
        return np.asarray(w, dtype=float) - rotation_matrix(q).T @ self.orbital_frame_rate(t)

    def body_field(self, t: float, q) -> np.ndarray:
        """b = R(q)^T b_orb(t), tesla, body axes."""
        return rotation_matrix(q).T @ np.asarray(self.field(t), dtype=float).reshape(3)

    def gravity_gradient_torque(self, q) -> np.ndarray:
        """T_gg = 3 W0^2 c x (I c), c = R(q)^T [1, 0, 0] (nadir in body axes)."""
        c = rotation_matrix(q)[0, :]  # first row of R = first column of R^T
        return 3.0 * self.orbit_rate**2 * cross(c, self.inertia @ c)

    def disturbance_torque(self, t: float, q, w, b) -> np.ndarray:
        """Gravity gradient (if enabled) + residual dipole + plug-in disturbance torques [N m]."""
        T = self.gravity_gradient_torque(q) if self.gravity_gradient else np.zeros(3)
        T = T + cross(self.residual_dipole, b)
        for f in self.disturbances:
            T = T + np.asarray(f(t, q, w, b), dtype=float)
        return T

    def rhs(self, t: float, y, m=None, torque=None) -> np.ndarray:
        """dy/dt for y = [q (4); w (3)] under dipole ``m`` [A m^2] and/or extra body ``torque`` [N m].

    Kinematics q' = 0.5 q (x) [0; w - R(q)^T w_oi] and Euler's I w' = T - w x (I w + h) (paper
    section 3), T = magnetic (eq. 12) + disturbance torques. Returns dy/dt, an ndarray (7,)."""
        return np.array(self._rhs(t, [float(v) for v in y], m, torque))

    def _rhs(self, t: float, y, m=None, torque=None) -> tuple:
        """rhs on plain floats (the SIL simulator calls it 4 x substeps times per step)."""
        q0, q1, q2, q3, wx, wy, wz = y
        # rows of R(q) = columns of R^T: R^T e_X (nadir), R^T e_Z (-orbit normal), and R^T v
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = dcm_floats(q0, q1, q2, q3)
        tx = ty = tz = 0.0
        mr0, mr1, mr2 = self.residual_dipole
        if m is not None or self.disturbances or mr0 or mr1 or mr2:
            fo0, fo1, fo2 = self.field_at(t)
            b0 = r00 * fo0 + r10 * fo1 + r20 * fo2
            b1 = r01 * fo0 + r11 * fo1 + r21 * fo2
            b2 = r02 * fo0 + r12 * fo1 + r22 * fo2
            if m is not None:
                m0, m1, m2 = m
                tx, ty, tz = m1 * b2 - m2 * b1, m2 * b0 - m0 * b2, m0 * b1 - m1 * b0
            if mr0 or mr1 or mr2:  # residual dipole disturbance m_res x b (paper eq. 32)
                tx, ty, tz = tx + (mr1 * b2 - mr2 * b1), ty + (mr2 * b0 - mr0 * b2), tz + (mr0 * b1 - mr1 * b0)
            if self.disturbances:
                qa, wa, b = np.array([q0, q1, q2, q3]), np.array([wx, wy, wz]), np.array([b0, b1, b2])
                for f in self.disturbances:
                    d0, d1, d2 = f(t, qa, wa, b)
                    tx, ty, tz = tx + d0, ty + d1, tz + d2
        I = self._I
        if self.gravity_gradient:
            k = 3.0 * self.orbit_rate**2
            c0, c1, c2 = r00, r01, r02
            i0 = I[0][0] * c0 + I[0][1] * c1 + I[0][2] * c2
            i1 = I[1][0] * c0 + I[1][1] * c1 + I[1][2] * c2
            i2 = I[2][0] * c0 + I[2][1] * c1 + I[2][2] * c2
            tx, ty, tz = tx + k * (c1 * i2 - c2 * i1), ty + k * (c2 * i0 - c0 * i2), tz + k * (c0 * i1 - c1 * i0)
        if torque is not None:
            tx, ty, tz = tx + torque[0], ty + torque[1], tz + torque[2]
        # w_rel = w - R^T [0, 0, -W0] = w + W0 * (third row of R)
        W0 = self.orbit_rate
        return self._derivative(q0, q1, q2, q3, wx, wy, wz, wx + W0 * r20, wy + W0 * r21, wz + W0 * r22, tx, ty, tz)

    def _derivative(self, q0, q1, q2, q3, wx, wy, wz, vx, vy, vz, tx, ty, tz) -> tuple:
        """(q', w') on plain floats: q' = 0.5 q (x) [0; v] with v the body rate relative to the
        orbital frame, I w' = T - w x (I w + h) (rigid body with wheel momentum h)."""
        I = self._I
        h0, h1, h2 = self._h
        L0 = I[0][0] * wx + I[0][1] * wy + I[0][2] * wz + h0
        L1 = I[1][0] * wx + I[1][1] * wy + I[1][2] * wz + h1
        L2 = I[2][0] * wx + I[2][1] * wy + I[2][2] * wz + h2
        e0, e1, e2 = tx - (wy * L2 - wz * L1), ty - (wz * L0 - wx * L2), tz - (wx * L1 - wy * L0)
        J = self._J
        return (
            0.5 * (-q1 * vx - q2 * vy - q3 * vz),
            0.5 * (q0 * vx + q2 * vz - q3 * vy),
            0.5 * (q0 * vy - q1 * vz + q3 * vx),
            0.5 * (q0 * vz + q1 * vy - q2 * vx),
            J[0][0] * e0 + J[0][1] * e1 + J[0][2] * e2,
            J[1][0] * e0 + J[1][1] * e1 + J[1][2] * e2,
            J[2][0] * e0 + J[2][1] * e1 + J[2][2] * e2,
        )

    def step(self, t: float, y, dt: float, m=None, substeps: int = 1, weights=None) -> np.ndarray:
        """Advance y over [t, t + dt] with ``substeps`` classical RK4 steps, dipole m held (ZOH).

    Returns y(t + dt), an ndarray (7,): the response of one sample period of the controller.

        ``weights`` (substeps,) scales the dipole per sub-step: the torquers' duty cycle
        (:meth:`magtune_core.onboard.torquers.Torquers.substep_weights`; None: held throughout).
        Deterministic (fixed steps, fixed operation order); the quaternion is renormalized at
        the end of the interval.
        """
        y = [float(v) for v in y]
        m = None if m is None else tuple(float(v) for v in m)
        h = dt / substeps
        h2, h6 = 0.5 * h, h / 6.0
        f = self._rhs
        m_held = m
        for i in range(substeps):
            ti = t + i * h
            if weights is not None and m_held is not None:
                w = float(weights[i])
                m = (m_held[0] * w, m_held[1] * w, m_held[2] * w)
            k1 = f(ti, y, m)
            k2 = f(ti + h2, [a + h2 * b for a, b in zip(y, k1)], m)
            k3 = f(ti + h2, [a + h2 * b for a, b in zip(y, k2)], m)
            k4 = f(ti + h, [a + h * b for a, b in zip(y, k3)], m)
            y = [a + h6 * (b1 + 2.0 * b2 + 2.0 * b3 + b4) for a, b1, b2, b3, b4 in zip(y, k1, k2, k3, k4)]
        n = (y[0] * y[0] + y[1] * y[1] + y[2] * y[2] + y[3] * y[3]) ** 0.5
        return np.array([y[0] / n, y[1] / n, y[2] / n, y[3] / n, y[4], y[5], y[6]])

    # --- linearization ------------------------------------------------------------------
    def linear_rhs(self, x, u=None) -> np.ndarray:
        """dx/dt of the nonlinear model written in the linear state x = [dq; dw] (no field torques).

        ``u`` is a body torque [N m]; ``q0 = +sqrt(1 - |dq|^2)``. Used for the Jacobian check
        against A and B_T of paper eqs. (15)-(16).
        """
        x = np.asarray(x, dtype=float)
        dq = x[:3]
        q = np.concatenate([[np.sqrt(1.0 - dq @ dq)], dq])
        w = x[3:] + np.array([0.0, 0.0, -self.orbit_rate])
        saved = self.disturbances, self.residual_dipole
        self.disturbances, self.residual_dipole = [], (0.0, 0.0, 0.0)
        try:
            ydot = self.rhs(0.0, np.concatenate([q, w]), None, None if u is None else np.asarray(u, dtype=float))
        finally:
            self.disturbances, self.residual_dipole = saved
        return np.concatenate([ydot[1:4], ydot[4:]])


def numerical_jacobian(f, x0, h: float = 1e-6):
    """Central-difference Jacobian of f at x0 (truncation O(h^2), round-off O(eps |f| / h)).

    What checks the linear model A, B_T of paper eqs. (15)-(16) against the nonlinear one (SPEC.md).

    Returns
    -------
    ndarray (len(f(x0)), len(x0))
        df/dx at x0.
    """
    x0 = np.asarray(x0, dtype=float)
    f0 = np.asarray(f(x0))
    J = np.zeros((f0.size, x0.size))
    for j in range(x0.size):
        e = np.zeros_like(x0)
        e[j] = h
        J[:, j] = (np.asarray(f(x0 + e)) - np.asarray(f(x0 - e))) / (2 * h)
    return J
