"""The torquers' model (magtune_core.onboard.torquers): the coupling matrix against the dipole's
potential, the duty cycle's sub-step grid and weights against an exactly switched reference
integration, the compensation's mean dipole, the field a sample sees."""
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from magtune_core.base.errors import ConfigError
from magtune_core.design.gains import load_gains
from magtune_core.design.params import load_spacecraft
from magtune_core.onboard.law import ProjectionController, linear_state
from magtune_core.onboard.torquers import MU0_4PI, Torquers, dipole_coupling
from magtune_core.sim.dynamics import AttitudeDynamics
from magtune_core.sim.simulate import DW0, initial_state, simulate


def test_dipole_coupling_is_minus_the_gradient_of_the_magnetic_potential():
    """b = -mu0 grad(phi), phi = m . r / (4 pi |r|^3): each column of C (unit m along an axis) against a
    central-difference gradient. Step 1e-5 m on |r| ~ 0.5 m: truncation (h/r)^2 ~ 4e-10 relative."""
    r0 = np.array([0.4, -0.3, 0.2])
    C = dipole_coupling(r0)
    h = 1e-5
    for j in range(3):
        m = np.eye(3)[j]

        def phi(r):
            return MU0_4PI * (m @ r) / np.linalg.norm(r) ** 3

        grad = np.array([(phi(r0 + h * e) - phi(r0 - h * e)) / (2 * h) for e in np.eye(3)])
        assert np.allclose(C[:, j], -grad, rtol=1e-7, atol=1e-15)
    # on the axis of a dipole: 2 mu0 m / (4 pi r^3); across it: -mu0 m / (4 pi r^3)
    assert np.allclose(np.diag(dipole_coupling([1.0, 0.0, 0.0])), [2e-7, -1e-7, -1e-7], rtol=1e-15)


@pytest.mark.parametrize("ts, off, asked, expect", [(1.0, 0.2, 2, 5), (1.0, 0.3, 2, 10), (1.0, 0.5, 2, 2),
                                                     (20.0, 0.2, 2, 100), (1.0, 0.0, 2, 2), (1.0, 0.2, 7, 10)])
def test_switch_off_on_the_sub_step_grid(ts, off, asked, expect):
    tq = Torquers(off_time=off)
    n = tq.substeps(ts, asked)
    assert n == expect
    w = tq.substep_weights(ts, n)
    assert set(w.tolist()) <= {0.0, 1.0}  # exact switch: whole sub-steps on or off
    assert w.sum() * ts / n == pytest.approx(ts - off, abs=1e-12)  # on for Ts - off_time


def test_off_time_that_never_lands_on_a_grid_or_exceeds_the_period_is_refused():
    with pytest.raises(ConfigError, match="torquer_off_time"):
        Torquers(off_time=1.0).check(1.0, "x")
    with pytest.raises(ConfigError, match="torquer_off_time.*multiple of ts/1000"):
        Torquers(off_time=1.234567e-4).check(1.0, "x")


def test_compensation_keeps_the_period_mean_dipole_and_the_torquers_limit():
    tq = Torquers(off_time=0.2)
    f = tq.on_fraction(1.0)
    law = ProjectionController(np.eye(3, 6) * 1e-3, tq.law_limit(50.0, 1.0))
    b = np.array([2e-5, -1e-5, 3e-5])
    for x in (np.array([1e-3, 0, 0, 0, 0, 0]), np.array([10.0, -10.0, 10.0, 0, 0, 0])):  # inside / saturating
        out = law(x, b)
        drive = tq.drive(out.m, 1.0)
        assert np.all(np.abs(drive) <= 50.0 * (1 + 1e-15))
        assert np.allclose(drive * f, out.m, rtol=1e-15)  # the mean over the period is the law's
    assert out.saturated and np.max(np.abs(drive)) == pytest.approx(50.0, rel=1e-15)
    off = Torquers(off_time=0.2, compensate=False)
    assert off.command_scale(1.0) == 1.0 and np.array_equal(off.drive(out.m, 1.0), out.m)


def test_the_sample_sees_the_last_drive_decayed():
    C = dipole_coupling([0.8, 0.1, -0.2])
    m = np.array([10.0, -20.0, 5.0])
    assert np.allclose(Torquers(tuple(C.ravel())).field(m), C @ m, rtol=1e-14)  # always on: all of it
    assert not np.any(Torquers(tuple(C.ravel()), off_time=0.2).field(m))  # off, instant decay: none
    tau = Torquers(tuple(C.ravel()), off_time=0.2, decay_time=0.1)
    assert np.allclose(tau.field(m), math.exp(-2.0) * (C @ m), rtol=1e-14)


def test_duty_cycled_loop_against_an_exactly_switched_reference():
    """The closed loop with the duty cycle on the sub-step grid vs the same controller on a plant
    integrated by DOP853 (rtol 1e-12) over [t_k, t_k + 0.8 s] with the dipole and [t_k + 0.8, t_k+1]
    without: 600 s agree to 3e-10 in the quaternion (RK4's h^4 error at h = 0.2 s); 1e-8 bounds that
    with margin and stays 5,000 times below what the duty cycle itself changes (5e-5)."""
    p = load_spacecraft("config/spacecraft.yaml")
    K = load_gains("config/gains/sigma_120.yaml").K
    tq, n = Torquers(off_time=0.2), 600
    r = simulate(K, p, ts=1.0, steps=n, substeps=2, torquers=tq)
    assert r.info["substeps"] == 5
    dyn = AttitudeDynamics.from_params(p)
    ctrl = ProjectionController(K, tq.law_limit(50.0, 1.0))
    y, Y = initial_state(p, DW0), [initial_state(p, DW0)]
    for k in range(n):
        m = tq.drive(ctrl(linear_state(y[:4], y[4:], dyn.orbit_rate), dyn.body_field(float(k), y[:4])).m, 1.0)
        for t0, t1, mm in ((k, k + 0.8, m), (k + 0.8, k + 1.0, np.zeros(3))):
            y = solve_ivp(lambda t, s, mm=mm: dyn.rhs(t, s, mm), (t0, t1), y, method="DOP853", rtol=1e-12,
                          atol=1e-14).y[:, -1]
        y[:4] /= np.linalg.norm(y[:4])
        Y.append(y)
    Y = np.array(Y)
    assert np.max(np.abs(Y[:, :4] - r.q)) < 1e-8 and np.max(np.abs(Y[:, 4:] - r.w)) < 1e-9
    always_on = simulate(K, p, ts=1.0, steps=n, substeps=5)
    assert np.max(np.abs(always_on.q - r.q)) > 1e-5
