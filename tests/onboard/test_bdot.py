"""B-dot detumbling law (magtune_core.onboard.bdot): the energy identity, the gain rule, the derivative
filter against its analytic responses and an independent continuous-time simulation."""
import math

import numpy as np
import pytest
from scipy import signal

from magtune_core.base.rotations import rotation_matrix
from magtune_core.design.params import SpacecraftParams
from magtune_core.onboard.bdot import BdotController, FieldDerivativeFilter, FilterState, bdot_gain, geomagnetic_inclination
from magtune_core.sim.dynamics import AttitudeDynamics

B_INERTIAL = np.array([2e-5, -1e-5, 3e-5])  # a constant field [T]


def _inertial_body(p):
    """The rigid body with its pitch wheel in a constant inertial field: W0 = 0 makes the orbital
    frame inertial, no gravity gradient, no residual dipole, so the only torque is m x b."""
    return AttitudeDynamics(p.inertia, p.wheel_momentum, 0.0, lambda t: B_INERTIAL, gravity_gradient=False)


def test_gain_rule_of_avanzini_giulietti():
    p = SpacecraftParams()
    # 87 deg orbit, dipole tilt 9.2 deg: the orbit crosses the geomagnetic pole plane, xi_m = 90 deg
    assert geomagnetic_inclination(math.radians(87.0)) == pytest.approx(math.pi / 2)
    assert geomagnetic_inclination(math.radians(30.0)) == pytest.approx(math.radians(39.2))
    assert geomagnetic_inclination(0.0) == pytest.approx(math.radians(9.2))
    k = bdot_gain(p.orbit_rate, math.pi / 2, p.inertia)
    assert k == pytest.approx(2 * p.orbit_rate * 2.0 * 17.0, rel=1e-15)  # J_min = Iyy = 17 kg m^2
    assert bdot_gain(p.orbit_rate, 0.3, np.diag(p.inertia)) == pytest.approx(bdot_gain(p.orbit_rate, 0.3, p.inertia))


@pytest.mark.parametrize("limit", [np.inf, 5.0])
def test_energy_rate_identity(limit):
    """d/dt (1/2 w^T I w) = w . T (the wheel's gyroscopic term w . (w x h) vanishes); with the exact
    body-frame derivative db/dt = -w x b of a constant inertial field the normalized law gives
    m = (k/|b|^2) w x b, so dT/dt = -(k/|b|^2) |w x b|^2 <= 0; saturated per axis, m_i keeps the sign of
    (w x b)_i and dT/dt = -m_sat . (w x b) <= 0 still."""
    p = SpacecraftParams()
    dyn = _inertial_body(p)
    k = 0.08
    ctrl = BdotController(k, dipole_limit=limit)
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rng.standard_normal(4)
        q /= np.linalg.norm(q)
        w = rng.uniform(-0.1, 0.1, 3)
        b = dyn.body_field(0.0, q)
        m = ctrl.dipole(b, -np.cross(w, b))
        wdot = dyn.rhs(0.0, np.r_[q, w], m)[4:]
        dT = w @ p_inertia(p) @ wdot
        wxb = np.cross(w, b)
        if np.isinf(limit):
            expected = -k / (b @ b) * (wxb @ wxb)
        else:
            expected = -m @ wxb
            assert np.all(np.abs(m) <= limit)
        # rounding only: the terms are ~1e-4 N m x 0.1 rad/s, summed in a different order
        assert dT == pytest.approx(expected, rel=1e-10, abs=1e-18)
        assert dT <= 0.0


def p_inertia(p):
    return np.diag(p.inertia)


def test_sampled_loop_removes_energy_monotonically_on_average():
    """Sample and hold at Ts = 1 s with the filtered derivative (not the exact one) from 3 deg/s per
    axis: the kinetic energy averaged over 200 s windows never rises and falls (measured: to 0.42 of
    its start); what stays is bound by the angular momentum along the field, which no magnetic torque
    (normal to b) changes: its inertial component stays constant to the RK4 error (~1e-10 relative)."""
    p = SpacecraftParams()
    dyn = _inertial_body(p)
    ctrl = BdotController(bdot_gain(p.orbit_rate, math.pi / 2, p.inertia), dipole_limit=50.0)
    filt = FieldDerivativeFilter(1.0, 0.2)
    y = np.r_[1.0, 0.0, 0.0, 0.0, np.radians([3.0, 3.0, 3.0])]
    st, E, H = FilterState(), [], []
    I = p_inertia(p)
    bhat = B_INERTIAL / np.linalg.norm(B_INERTIAL)
    for k in range(4000):
        b = dyn.body_field(float(k), y[:4])
        st, bdot = filt.step(st, b)
        E.append(0.5 * y[4:] @ I @ y[4:])
        H.append(bhat @ rotation_matrix(y[:4]) @ (I @ y[4:] + p.wheel_momentum))
        y = dyn.step(float(k), y, 1.0, ctrl.dipole(b, bdot), 4)
    win = np.asarray(E).reshape(-1, 200).mean(axis=1)
    assert np.all(np.diff(win) <= 1e-12 * win[0]), np.diff(win) / win[0]
    assert win[-1] < 0.5 * win[0]
    H = np.asarray(H)
    assert np.max(np.abs(H - H[0])) < 1e-8 * np.abs(H[0])


def test_filter_ramp_is_the_analytic_step_response():
    """A field ramp b = b0 + r t has a step in db/dt at t = 0; the continuous filter s/(tau s + 1)
    answers r (1 - exp(-t/tau)); the filter is exact for piecewise-linear fields, so the samples agree
    to rounding (~k eps from the powers a^k)."""
    ts, wc = 2.0, 0.05
    f = FieldDerivativeFilter(ts, wc)
    r = np.array([1e-7, -2e-7, 5e-8])
    st = FilterState()
    st, y0 = f.step(st, np.array([1e-5, 2e-5, 3e-5]))
    assert np.all(y0 == 0.0)
    for k in range(1, 200):
        st, y = f.step(st, np.array([1e-5, 2e-5, 3e-5]) + r * k * ts)
        np.testing.assert_allclose(y, r * (1.0 - math.exp(-wc * k * ts)), rtol=1e-11, atol=1e-22)


def test_filter_equals_continuous_filter_on_the_interpolated_field():
    """Independent check: scipy.signal.lsim of s/(tau s + 1) driven by the linear interpolation of
    the samples (lsim's input hold) equals the discrete filter at the samples, for a field with a
    step and a sinusoid. lsim's own error is rounding of its matrix exponential: ~1e-12 relative."""
    ts, wc = 1.0, 0.2
    t = np.arange(300) * ts
    b = 3e-5 * np.sin(0.05 * t) + np.where(t >= 50, 1e-6, 0.0)
    f = FieldDerivativeFilter(ts, wc)
    st, out = FilterState(), []
    for v in b:
        st, y = f.step(st, [v, 0.0, 0.0])
        out.append(y[0])
    # start the continuous filter at rest with the first sample as its zero (the discrete filter's b_prev)
    _, yc, _ = signal.lsim(signal.lti([1.0, 0.0], [1.0 / wc, 1.0]), b - b[0], t)
    scale = np.max(np.abs(yc))
    np.testing.assert_allclose(out, yc, rtol=0, atol=1e-9 * scale)


def test_filter_noise_gain():
    """White magnetometer noise of std s: the plain difference has std s sqrt(2)/Ts, the filter
    (1 - a)/sqrt(1 + a) of that (module docstring); 2e5 seeded samples estimate a std to ~0.2 %."""
    ts, wc = 1.0, 0.2
    f = FieldDerivativeFilter(ts, wc)
    n = np.random.default_rng(7).standard_normal((200_000, 3)) * 1e-7
    st, out = FilterState(), []
    for v in n:
        st, y = f.step(st, v)
        out.append(y)
    a = f.pole
    expected = 1e-7 * math.sqrt(2.0) / ts * (1.0 - a) / math.sqrt(1.0 + a)
    assert np.std(np.asarray(out)[1000:]) == pytest.approx(expected, rel=0.02)


def test_weak_field_and_raw_law():
    c = BdotController(2.0, dipole_limit=50.0, normalized=False)
    np.testing.assert_allclose(c.dipole([1e-5, 0, 0], [1e-6, -2e-6, 0.0]), [-2e-6, 4e-6, 0.0], rtol=1e-15)
    assert np.all(c.dipole([1e-9, 0, 0], [1.0, 1.0, 1.0]) == 0.0)
    assert np.all(c.dipole([np.nan, 0, 0], [1.0, 1.0, 1.0]) == 0.0)
