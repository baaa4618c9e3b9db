"""Batched simulator (magtune_core.sim.batch): every run of a batch equals the single-run
``simulate`` (paper and full environment), runs are independent of their batch, sensors act as
modelled, divergence is flagged per run."""
from dataclasses import replace
from datetime import datetime

import numpy as np
import pytest

from magtune_core.design.gains import load_gains
from magtune_core.design.params import load_spacecraft
from magtune_core.onboard.law import ProjectionController, linear_state
from magtune_core.sim.batch import BatchRuns, SensorNoise, simulate_batch
from magtune_core.sim.fullenv import FullEnvironmentOptions
from magtune_core.sim.simulate import simulate

#: Equality with the single-run loop. Both compute the same formulas in float64 and differ only by
#: the association of a few sums (~1e-16 relative per step); over a few hundred steps of a
#: stable closed loop that stays ~1e-14. 1e-9 (the issue's bar) leaves five orders of margin.
TOL = 1e-9
STEPS = 150


@pytest.fixture(scope="module")
def setup():
    p = load_spacecraft("config/spacecraft.yaml")
    # The paper-method gain: batch and single runs do the same arithmetic in a different order, and
    # with the stiff J-optimal gains (re-shipped in issue 9: c2 ~ 34,000) that round-off is
    # amplified at saturation switches to 1e-5 within half an orbit of the full environment, so
    # the 1e-9 equivalence is checked on a loop that does not amplify it.
    K = load_gains("config/gains/paper_method/sigma_120.yaml").K
    rng = np.random.default_rng(12)
    B = 3
    q0 = np.array([1.0, 0.0, 0.0, 0.0]) + 0.1 * rng.standard_normal((B, 4))
    q0 /= np.linalg.norm(q0, axis=1, keepdims=True)
    return dict(p=p, K=K, B=B, inertia=p.inertia * (1 + 0.05 * rng.standard_normal((B, 3))),
                mres=1 + 0.3 * rng.standard_normal((B, 3)), q0=q0, dw0=1e-3 * rng.standard_normal((B, 3)),
                lim=np.array([50.0, 5.0, 30.0]))  # run 1 saturates


def _runs(s, environment, opts=None, sensors=None, **over):
    kw = dict(K=s["K"], inertia=s["inertia"], residual_dipole=s["mres"], dipole_limit=s["lim"], q0=s["q0"], dw0=s["dw0"],
              p=s["p"], environment=environment, env_options=opts, sensors=sensors)
    kw.update(over)
    return BatchRuns(**kw)


def _assert_close(a, b, scale=1.0):
    assert np.max(np.abs(np.asarray(a) - np.asarray(b))) <= TOL * scale


@pytest.mark.parametrize("environment", ["paper", "full"])
def test_each_run_equals_single_run_simulate(setup, environment):
    s = setup
    opts = ([FullEnvironmentOptions(raan_deg=r, epoch=datetime(2026, m, 5)) for r, m in ((0.0, 1), (40.0, 6), (200.0, 11))]
            if environment == "full" else None)
    res = simulate_batch(_runs(s, environment, opts), ts=1.0, steps=STEPS)
    for i in range(s["B"]):
        r = simulate(s["K"], replace(s["p"], inertia=s["inertia"][i]), ts=1.0, steps=STEPS, dw0=s["dw0"][i], q0=s["q0"][i],
                     dipole_limit=s["lim"][i], residual_dipole=s["mres"][i], environment=environment,
                     env_options=opts[i] if opts else None)
        # nominal period from the batched ephemeris (full: three orbits integrated as one system, each
        # within its single-run tolerance, positions agree to ~1e-5 m of 6.8e6 m)
        assert res.orbit_period[i] == pytest.approx(r.orbit_period, rel=1e-10)
        _assert_close(res.t, r.t)
        _assert_close(res.q[i], r.q)
        _assert_close(res.w[i], r.w)
        _assert_close(res.x[i], r.x)
        _assert_close(res.m[i], r.m, scale=50.0)  # dipoles up to the 50 A m^2 limit
        _assert_close(res.b[i], r.b, scale=1e-4)  # field ~5e-5 T
        assert res.saturated_steps[i] == r.info["saturated_steps"] and res.weak_field_steps[i] == r.info["weak_field_steps"]
    assert res.saturated_steps[1] > 0 and not res.diverged.any()


def _noisy(B, seeds):
    return SensorNoise(mag_std=np.full(B, 2e-7), mag_bias=np.tile([3e-7, -1e-7, 2e-7], (B, 1)),
                       gyro_std=np.full(B, 1e-5), gyro_bias=np.tile([2e-6, 0.0, -1e-6], (B, 1)),
                       attitude_std=np.full(B, 1e-3), seeds=seeds)


def test_runs_do_not_depend_on_their_batch(setup):
    """With sensor noise: a run alone equals the same run inside a batch (noise from its own seed)."""
    s = setup
    seeds = [[7, i, 1] for i in range(s["B"])]
    res = simulate_batch(_runs(s, "paper", sensors=_noisy(s["B"], seeds)), ts=1.0, steps=STEPS)
    clean = simulate_batch(_runs(s, "paper"), ts=1.0, steps=STEPS)
    for i in (0, 2):
        one = _runs(s, "paper", sensors=_noisy(1, [seeds[i]]), K=s["K"], inertia=s["inertia"][i:i + 1],
                    residual_dipole=s["mres"][i:i + 1], dipole_limit=s["lim"][i:i + 1], q0=s["q0"][i:i + 1],
                    dw0=s["dw0"][i:i + 1])
        alone = simulate_batch(one, ts=1.0, steps=STEPS)
        np.testing.assert_allclose(alone.x[0], res.x[i], rtol=0, atol=1e-13)
        np.testing.assert_allclose(alone.m[0], res.m[i], rtol=0, atol=1e-11)
        # the noise acts: the controller's state differs from the noise-free run by ~ the gyro noise
        assert 1e-6 < np.max(np.abs(res.x[i, :, 3:] - clean.x[i, :, 3:])) < 1e-3


def test_magnetometer_bias_reaches_the_control_law(setup):
    """Independent check of the sensor path at t = 0: m(0) is the flight law on (q, w, b + bias)."""
    s = setup
    bias = np.array([[4e-6, -3e-6, 2e-6]])
    sens = SensorNoise(np.zeros(1), bias, np.zeros(1), np.zeros((1, 3)), np.zeros(1), [0])
    # a gain that does not saturate every axis at t = 0 (the shipped J-optimal one does, and a
    # saturated command cannot show the bias): the paper method's
    K = load_gains("config/gains/paper_method/sigma_120.yaml").K
    one = _runs(s, "paper", sensors=sens, inertia=s["inertia"][:1], residual_dipole=s["mres"][:1], dipole_limit=s["lim"][:1],
                q0=s["q0"][:1], dw0=s["dw0"][:1], K=K)
    res = simulate_batch(one, ts=1.0, steps=2)
    x = linear_state(res.q[0, 0], res.w[0, 0], s["p"].orbit_rate)
    out = ProjectionController(K, s["lim"][0])(x, res.b[0, 0] + bias[0])
    np.testing.assert_allclose(res.m[0, 0], out.m, rtol=1e-12, atol=1e-12)
    assert np.sum(np.abs(out.m) >= s["lim"][0] * (1 - 1e-12)) < 3  # some axis is free to show the bias
    assert np.max(np.abs(res.m[0, 0] - ProjectionController(K, s["lim"][0])(x, res.b[0, 0]).m)) > 1e-3


def test_divergence_is_flagged_per_run(setup):
    s = setup
    dw0 = s["dw0"].copy()
    dw0[1] = [2.0, 0.0, 0.0]  # 2 rad/s: beyond DIVERGED_RATE from the first step
    res = simulate_batch(_runs(s, "paper", dw0=dw0), ts=1.0, steps=20, full_series=True)
    ref = simulate_batch(_runs(s, "paper"), ts=1.0, steps=20, full_series=True)
    assert res.diverged.tolist() == [False, True, False]
    np.testing.assert_array_equal(res.x[[0, 2]], ref.x[[0, 2]])
    # full series: the true pointing error and |m| at every instant, consistent with the histories
    ang = np.degrees(2 * np.arctan2(np.linalg.norm(ref.q[..., 1:], axis=-1), np.abs(ref.q[..., 0])))
    np.testing.assert_allclose(ref.pointing_deg, ang, rtol=1e-9, atol=1e-9)  # asin vs atan2 form
    np.testing.assert_allclose(ref.m_norm, np.linalg.norm(ref.m, axis=-1), rtol=1e-12)


def test_environment_rows_match_the_single_run_table():
    """The compiled environment rows (batch_kernels.env_rows) against fullenv.environment_table (the
    numpy code of the single-run simulator) over one orbit on the RK4 stage grid (Ts = 1 s, 2 substeps):
    equal at the controller instants (nodes), and at the interpolated stages within the documented
    deviations. Bounds, relative to the largest norm of the vector (or value of the scalar): field 1e-8 (measured ~1e-9: the rounding
    jitter of jd0 + t/86400, ~4e-5 s of Earth rotation, that the numpy table carries point by point and
    the interpolation smooths out), density 1e-10 (measured 5e-12; exact where an interpolation window
    crosses a Harris-Priester table height, which this orbit does: its geodetic height spans 443-465 km,
    across the 460 km table height), everything else 1e-11 (measured 1e-13, last-bit differences amplified by the frame)."""
    from magtune_core.sim.batch_kernels import env_rows, igrf_arrays
    from magtune_core.sim.fullenv import _environment, environment_table

    env = _environment(FullEnvironmentOptions(epoch=datetime(2026, 3, 20)).environment_config(load_spacecraft(
        "config/spacecraft.yaml")))
    st, n = 4, 4 * 5700
    t = np.arange(n) * 0.25
    r, v = env.orbit.state(t)
    Y = np.ascontiguousarray(np.vstack((r.T, v.T)))
    out = np.zeros((n, 15))
    env_rows(Y, t, 0, st, 1 << 60, 0, n - 8 * st, env.jd0, *igrf_arrays(env.igrf), 10, 2, True, True, 6.0, out)
    ref = environment_table(env, t)
    m = n - 8 * st
    # scale: the largest norm of each 3-vector (w_oi, b, wind, unit Sun) and the largest value of each scalar
    scale = np.abs(ref[:m]).max(axis=0)
    for a in (0, 3, 8, 11):
        scale[a:a + 3] = np.linalg.norm(ref[:m, a:a + 3], axis=1).max()
    dev = np.abs(out[:m] - ref[:m]) / scale
    node = np.arange(m) % st == 0
    assert dev[node].max() < 1e-11
    assert dev[:, 3:6].max() < 1e-8
    assert dev[:, 7].max() < 1e-10 and np.all(out[:m, 7] > 0)
    assert np.delete(dev, [3, 4, 5, 7], axis=1).max() < 1e-11
    assert np.any(out[:m, 14] == 0) and np.any(out[:m, 14] > 0)  # the orbit sees eclipse and sunlight


@pytest.mark.slow
def test_half_orbit_full_environment_equals_simulate(setup):
    """Over half an orbit (2806 steps, the IGRF field along the orbit, two orbits propagated as one
    batched ephemeris): still equal to the single-run loop at 1e-9 (no growth of the differences)."""
    s = setup
    opts = [FullEnvironmentOptions(raan_deg=r, epoch=datetime(2026, m, 5)) for r, m in ((10.0, 2), (250.0, 8))]
    runs = _runs(s, "full", opts, inertia=s["inertia"][:2], residual_dipole=s["mres"][:2], dipole_limit=s["lim"][:2],
                 q0=s["q0"][:2], dw0=s["dw0"][:2])
    n = 2806
    res = simulate_batch(runs, ts=1.0, steps=n, record_every=1)
    for i in range(2):
        r = simulate(s["K"], replace(s["p"], inertia=s["inertia"][i]), ts=1.0, steps=n, dw0=s["dw0"][i], q0=s["q0"][i],
                     dipole_limit=s["lim"][i], residual_dipole=s["mres"][i], environment="full", env_options=opts[i])
        _assert_close(res.x[i], r.x)
        _assert_close(res.m[i], r.m, scale=50.0)


def test_batch_sensors_are_the_node_models_for_the_same_seed(setup):
    """The batch's measurements are design.sensors' for the seed's rows of normals (what the
    attitude_sensors node computes): Farrenkopf gyro over two noise blocks, magnetometer with a
    misalignment matrix, attitude. Gyro and attitude read back from the controller state x."""
    from magtune_core.design import sensors as sm
    from magtune_core.sim.batch import NOISE_CHUNK

    s = setup
    n = NOISE_CHUNK + 100  # the bias walk is carried across a block boundary
    M = np.eye(3) + 0.01 * np.arange(9.0).reshape(3, 3)
    sens = SensorNoise(np.full(1, 1e-7), np.array([[2e-7, 0.0, -1e-7]]), np.full(1, 1e-5),
                       np.array([[1e-4, -5e-5, 2e-5]]), np.full(1, 1e-3), [[3, 1]], gyro_arw=np.full(1, 2e-5),
                       gyro_rrw=np.full(1, 1e-6), mag_matrix=M[None])
    one = _runs(s, "paper", sensors=sens, inertia=s["inertia"][:1], residual_dipole=s["mres"][:1],
                dipole_limit=s["lim"][:1], q0=s["q0"][:1], dw0=s["dw0"][:1])
    res = simulate_batch(one, ts=1.0, steps=n)
    rows = sm.draw(np.random.default_rng([3, 1]), n + 1)
    gyro = sens.gyros(1.0)[0]
    wm, beta = sm.gyro(gyro, res.w[0], 1.0, gyro.bias, rows[:, sm.GYRO_V], rows[:, sm.GYRO_U])
    W0 = 2 * np.pi / res.orbit_period[0]
    meas = res.x[0, :, 3:] - np.array([0.0, 0.0, W0])
    np.testing.assert_array_equal(meas[:, :2], wm[:, :2])  # same operations in the same order
    np.testing.assert_allclose(meas[:, 2], wm[:, 2], rtol=0, atol=1e-17)  # + W0 - W0 rounding
    assert np.max(np.abs(beta[-1] - np.asarray(gyro.bias))) > 1e-6  # the bias did walk (sigma_u sqrt(t) ~ 3e-5)
    q = sm.noisy_attitude(res.q[0], 1e-3, rows[:, sm.ATT])
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    np.testing.assert_allclose(res.x[0, :, :3], q[:, 1:], rtol=0, atol=1e-15)  # numpy vs libm sin/cos
    # magnetometer at t = 0 through the flight law (b_meas enters only the dipole)
    b = sm.magnetometer(sm.Magnetometer(1e-7, (2e-7, 0.0, -1e-7), tuple(M.ravel())), res.b[0, 0], rows[0, sm.MAG])
    out = ProjectionController(s["K"], s["lim"][0])(res.x[0, 0], b)
    np.testing.assert_allclose(res.m[0, 0], out.m, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("environment", ["paper", "full"])
def test_torquer_coupling_and_duty_cycle_equal_the_single_run(setup, environment):
    """The torquers' field in the measured field (always on, then duty-cycled with a decaying field)
    and the compensated drive on the sub-step grid: every run of the batch equals ``simulate`` with
    the same Torquers, to the TOL of the plain loop."""
    from magtune_core.onboard.torquers import Torquers, dipole_coupling

    s = setup
    opts = ([FullEnvironmentOptions(raan_deg=r, epoch=datetime(2026, m, 5)) for r, m in ((0.0, 1), (40.0, 6), (200.0, 11))]
            if environment == "full" else None)
    C = tuple(dipole_coupling([0.5, 0.2, -0.1]).ravel())  # ~2e-6 T per A m^2: a strong coupling
    for tq in (Torquers(C), Torquers(C, off_time=0.2, decay_time=0.1)):
        res = simulate_batch(_runs(s, environment, opts), ts=1.0, steps=STEPS, torquers=tq)
        assert res.info["substeps"] == (5 if tq.off_time else 2)
        plain = simulate_batch(_runs(s, environment, opts), ts=1.0, steps=STEPS)
        assert np.max(np.abs(res.m - plain.m)) > 1e-3  # the torquers change the commands
        for i in range(s["B"]):
            r = simulate(s["K"], replace(s["p"], inertia=s["inertia"][i]), ts=1.0, steps=STEPS, dw0=s["dw0"][i],
                         q0=s["q0"][i], dipole_limit=s["lim"][i], residual_dipole=s["mres"][i],
                         environment=environment, env_options=opts[i] if opts else None, torquers=tq)
            _assert_close(res.q[i], r.q)
            _assert_close(res.w[i], r.w)
            _assert_close(res.m[i], r.m, scale=50.0)
            assert res.saturated_steps[i] == r.info["saturated_steps"]
