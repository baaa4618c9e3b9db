"""The nonlinear model of magtune_core.sim.dynamics against the linear design model (paper eqs. 15-16).

Tolerances: central differences with h = 1e-6 have truncation error ~h^2 * |f'''| (~1e-12 here:
third derivatives are O(1) in the kinematics, O(W0^2) elsewhere) and round-off ~eps*|f|/h with
|f| <= 1e-3 near the equilibrium (~1e-13), so 1e-9 is a loose bound that still catches any
wrong entry of A (the smallest nonzero entries, 6 k W0^2, are ~3e-6).
"""
import numpy as np
import pytest

from magtune_core.base.rotations import quat_mul, rotation_matrix
from magtune_core.design.model import skew_field, state_matrix, torque_input
from magtune_core.design.params import SpacecraftParams
from magtune_core.onboard.law import linear_state, saturate
from magtune_core.sim.dynamics import AttitudeDynamics, numerical_jacobian


@pytest.fixture
def dyn():
    p = SpacecraftParams()
    return p, AttitudeDynamics.from_params(p, residual_dipole=None)


def test_equilibrium_is_at_rest(dyn):
    p, d = dyn
    y = np.array([1.0, 0, 0, 0, 0, 0, -p.orbit_rate])
    # exact equilibrium: w parallel to I w + h, nadir along a principal axis
    assert np.max(np.abs(d.rhs(0.0, y))) < 1e-18


def test_jacobian_equals_state_matrix(dyn):
    p, d = dyn
    A = numerical_jacobian(d.linear_rhs, np.zeros(6))
    A_ref = state_matrix(p)
    assert np.max(np.abs(A - A_ref)) < 1e-9
    # every structural zero of A is a zero of the nonlinear Jacobian too
    assert np.max(np.abs(A[A_ref == 0])) < 1e-12


def test_jacobian_of_torque_input(dyn):
    p, d = dyn
    BT = numerical_jacobian(lambda u: d.linear_rhs(np.zeros(6), u), np.zeros(3), h=1e-3)
    # linear in u: only round-off (eps / h * |f| ~ 1e-16)
    assert np.max(np.abs(BT - torque_input(p))) < 1e-12


def test_relative_rate_would_not_match(dyn):
    """dw defined as w - R^T[0,0,-W0] (rate w.r.t. orbital axes) gives a different Jacobian:
    documents why x uses the inertial-rate deviation (see module docstring)."""
    p, d = dyn
    w0 = p.orbit_rate

    def f_rel(x):
        dq = x[:3]
        q = np.concatenate([[np.sqrt(1 - dq @ dq)], dq])
        R = rotation_matrix(q)
        w = x[3:] + R.T @ [0, 0, -w0]
        yd = d.rhs(0.0, np.concatenate([q, w]))
        return np.concatenate([yd[1:4], yd[4:]])

    A_rel = numerical_jacobian(f_rel, np.zeros(6))
    assert abs(A_rel[0, 1]) < 1e-12  # no W0 coupling in the kinematics: differs from A[0,1] = -W0
    assert np.max(np.abs(A_rel - state_matrix(p))) > 0.5 * w0


def test_kinematics_and_rotation_conventions():
    rng = np.random.default_rng(3)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    v = rng.normal(size=3)
    qc = q * [1, -1, -1, -1]
    rotated = quat_mul(quat_mul(q, np.concatenate([[0], v])), qc)[1:]
    assert np.allclose(rotation_matrix(q) @ v, rotated, atol=1e-14)
    assert np.allclose(rotation_matrix(q) @ rotation_matrix(q).T, np.eye(3), atol=1e-14)
    # scipy's (scalar-last) active rotation is the same map
    from scipy.spatial.transform import Rotation
    assert np.allclose(Rotation.from_quat(np.roll(q, -1)).as_matrix(), rotation_matrix(q), atol=1e-14)


def test_magnetic_and_residual_torques():
    p = SpacecraftParams()
    d = AttitudeDynamics.from_params(p)  # residual dipole [1,1,1] A m^2
    q = np.array([1.0, 0, 0, 0])
    b = d.body_field(0.0, q)
    assert np.allclose(b, [7e-6, 23e-6, 5e-6])
    T = d.disturbance_torque(0.0, q, np.zeros(3), b)
    assert np.allclose(T, skew_field(b) @ np.ones(3), atol=1e-20)  # paper eq. 32, T_gg = 0 here
    m = np.array([3.0, -1.0, 2.0])
    y = np.array([1.0, 0, 0, 0, 0, 0, -p.orbit_rate])
    wdot = d.rhs(0.0, y, m)[4:]
    assert np.allclose(wdot * p.inertia, skew_field(b) @ (m + 1.0), rtol=1e-12, atol=1e-22)
    assert np.array_equal(saturate([5.0, -5.0, 0.5], 1.0), [1.0, -1.0, 0.5])


def test_linear_state_hemisphere():
    x = linear_state([-0.9, 0.1, -0.2, 0.3], [1e-3, 2e-3, 0.0], 1e-3)
    assert np.allclose(x, [-0.1, 0.2, -0.3, 1e-3, 2e-3, 1e-3])


def test_disturbance_plugins():
    """Torque plug-ins enter the Euler equation; the built-in residual dipole equals its plug-in."""
    from magtune_core.sim.dynamics import residual_dipole_disturbance

    p = SpacecraftParams()
    y = np.array([0.99, 0.1, -0.05, 0.02, 1e-3, -2e-3, -p.orbit_rate])
    y[:4] /= np.linalg.norm(y[:4])
    m = np.array([0.5, -1.0, 2.0])
    built_in = AttitudeDynamics.from_params(p)
    plug = AttitudeDynamics.from_params(p, residual_dipole=None, disturbances=[residual_dipole_disturbance([1, 1, 1])])
    assert np.allclose(built_in.rhs(10.0, y, m), plug.rhs(10.0, y, m), rtol=0, atol=1e-20)
    T0 = np.array([1e-5, -2e-5, 3e-5])
    const = AttitudeDynamics.from_params(p, disturbances=[lambda t, q, w, b: T0])
    dw = const.rhs(10.0, y, m)[4:] - built_in.rhs(10.0, y, m)[4:]
    assert np.allclose(dw, T0 / p.inertia, rtol=1e-9, atol=1e-22)


def test_magnetic_torque_saturates_per_axis():
    from magtune_core.sim.dynamics import magnetic_torque

    b = np.array([2e-5, -1e-5, 5e-6])
    m = np.array([80.0, -3.0, -60.0])
    T = magnetic_torque(m, b, 50.0)
    assert np.allclose(T, skew_field(b) @ np.array([50.0, -3.0, -50.0]), rtol=1e-14, atol=0)
