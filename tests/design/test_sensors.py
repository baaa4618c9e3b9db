"""Sensor models (magtune_core.design.sensors): statistics against the analytic values with
chi-square bands for the sample size, zero noise = truth bit for bit, step-by-step = block,
sun dropout exactly in the environment's eclipses, the parameters' schema."""
import math

import numpy as np
import pytest
from scipy.stats import chi2

from magtune_core.base.errors import ConfigError
from magtune_core.base.schema import parse
from magtune_core.design import sensors as s
from magtune_core.design.node_params import SENSOR_FIELDS, check_sensors
from magtune_core.env.environment import Environment
from magtune_core.env.orbit import eci_to_orbital
from magtune_core.env.sun import shadow_cylindrical

#: Two-sided probability of a false failure of one variance check (the seeds are fixed, so a
#: passing check stays passing; the band says how far off a correct model may land).
P_FALSE = 1e-3


def _variance_ok(x, var):
    """sum(x^2)/var ~ chi2(x.size) for zero-mean normal x of variance var: inside the band."""
    stat, k = float(np.sum(np.square(x)) / var), x.size
    return chi2.ppf(P_FALSE / 2, k) < stat < chi2.ppf(1 - P_FALSE / 2, k), stat / k


@pytest.fixture(scope="module")
def gyro_runs():
    """2000 independent gyros x 400 samples of 0.5 s, true rate 0 (the errors are the measurements)."""
    model = s.Gyro(arw=2e-4, rrw=3e-6, bias=(1e-4, -2e-4, 5e-5))
    M, N, dt = 2000, 400, 0.5
    n = s.draw(np.random.default_rng(11), M * N).reshape(M, N, s.NORMALS_PER_STEP)
    wm, beta = s.gyro(model, np.zeros((M, N, 3)), dt, model.bias, n[..., s.GYRO_V], n[..., s.GYRO_U])
    return model, dt, N * dt, wm, beta


def test_gyro_angle_error_variance_is_arw_plus_integrated_bias_walk(gyro_runs):
    """Integrated angle error minus the initial bias's drift: variance sigma_v^2 t + sigma_u^2 t^3/3
    (the exact discretization reproduces the continuous Farrenkopf model; docs/sensors.md)."""
    model, dt, t, wm, _ = gyro_runs
    theta = np.sum(wm, axis=1) * dt - np.asarray(model.bias) * t
    ok, ratio = _variance_ok(theta, model.arw**2 * t + model.rrw**2 * t**3 / 3)
    assert ok, ratio
    # can fail: the same runs against the angle random walk alone (the bias walk's t^3 term is 75 % here)
    assert not _variance_ok(theta, model.arw**2 * t)[0]


def test_gyro_bias_variance_is_rrw_squared_t(gyro_runs):
    model, _, t, _, beta = gyro_runs
    ok, ratio = _variance_ok(beta[:, -1] - np.asarray(model.bias), model.rrw**2 * t)
    assert ok, ratio


def test_gyro_white_part_without_bias_walk():
    """sigma_u = 0: w_m - w - beta_0 is white with variance sigma_v^2/dt; Allan variance at tau = dt
    equals it (the ARW slope), at tau = 16 dt one sixteenth."""
    model, dt = s.Gyro(arw=1e-3, bias=(0.0, 0.0, 0.0)), 0.2
    n = s.draw(np.random.default_rng(3), 200_000)
    wm, _ = s.gyro(model, np.zeros((200_000, 3)), dt, model.bias, n[:, s.GYRO_V], n[:, s.GYRO_U])
    assert _variance_ok(wm, model.arw**2 / dt)[0]
    for m in (1, 16):
        means = wm[: (len(wm) // m) * m].reshape(-1, m, 3).mean(axis=1)
        avar = 0.5 * np.mean(np.diff(means, axis=0) ** 2)
        # Allan variance of K cluster means: ~chi2 with ~K/2 dof per axis -> a few % at K >= 12,500
        assert avar == pytest.approx(model.arw**2 / (m * dt), rel=0.06)


def test_step_by_step_equals_one_block():
    """The node draws and runs one sample at a time, the batch a block: the same numbers, bit for bit."""
    model, dt = s.Gyro(arw=1e-4, rrw=1e-5, bias=(1e-3, 0.0, -1e-3)), 1.0
    w = np.random.default_rng(0).standard_normal((50, 3)) * 1e-3
    n = s.draw(np.random.default_rng(5), 50)
    wm, beta = s.gyro(model, w, dt, model.bias, n[:, s.GYRO_V], n[:, s.GYRO_U])
    rng, b = np.random.default_rng(5), np.asarray(model.bias)
    for k in range(50):
        row = s.draw(rng)
        assert np.array_equal(row, n[k])
        one, walk = s.gyro(model, w[k:k + 1], dt, b, row[None, s.GYRO_V], row[None, s.GYRO_U])
        b = walk[-1]
        assert np.array_equal(one[0], wm[k]) and np.array_equal(b, beta[k + 1])


def test_zero_noise_passes_the_truth_bit_for_bit():
    rng = np.random.default_rng(1)
    b, w, q = rng.standard_normal((20, 3)) * 3e-5, rng.standard_normal((20, 3)) * 1e-3, rng.standard_normal((20, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    r, v, sb = rng.standard_normal((20, 3)) * 7e6, rng.standard_normal((20, 3)) * 7e3, rng.standard_normal((20, 3))
    sb /= np.linalg.norm(sb, axis=-1, keepdims=True)
    n = rng.standard_normal((20, 12))
    suite = s.SensorSuite()
    assert not suite.noisy
    assert np.array_equal(s.magnetometer(suite.magnetometer, b, n[:, s.MAG]), b)
    assert np.array_equal(s.gyro(suite.gyro, w, 1.0, (0, 0, 0), n[:, s.GYRO_V], n[:, s.GYRO_U])[0], w)
    assert np.array_equal(s.noisy_attitude(q, 0.0, n[:, s.ATT]), q)
    sm, valid, _ = s.sun_sensor(suite.sun, sb, np.ones(20, bool), n[:, s.SUN])
    assert np.array_equal(sm, sb) and valid.all()
    rm, vm = s.position_fix(suite.position, r, v, n[:, s.FIX])
    assert np.array_equal(rm, r) and np.array_equal(vm, v)
    # a bias alone: truth + bias exactly, no noise added
    g = s.Gyro(bias=(1e-3, 2e-3, -1e-3))
    assert np.array_equal(s.gyro(g, w, 1.0, g.bias, n[:, s.GYRO_V], n[:, s.GYRO_U])[0], w + np.array(g.bias))


def test_magnetometer_noise_bias_matrix_quantization():
    M = np.eye(3) + np.array([[0.01, 0.002, 0.0], [-0.002, -0.005, 0.001], [0.0, 0.003, 0.02]])
    model = s.Magnetometer(2e-7, (1e-6, -2e-6, 5e-7), tuple(M.ravel()))
    b = np.random.default_rng(2).standard_normal((20_000, 3)) * 3e-5
    n = np.random.default_rng(4).standard_normal((20_000, 3))
    err = s.magnetometer(model, b, n) - b @ M.T - np.array(model.bias)
    assert _variance_ok(err, model.noise_std**2)[0]
    assert np.allclose(model.covariance, np.eye(3) * 4e-14, rtol=1e-12)
    q = s.Magnetometer(quantum=5e-9)
    bq = s.magnetometer(q, b, n)
    assert np.allclose(bq / 5e-9, np.rint(bq / 5e-9), rtol=0, atol=1e-6) and np.max(np.abs(bq - b)) <= 2.5e-9 + 1e-20
    assert q.covariance[0, 0] == pytest.approx(5e-9**2 / 12)


def test_sun_sensor_angle_error_and_covariance():
    """The small rotation std*n moves s by its two components across s: squared angle ~ std^2 chi2(2)."""
    model = s.SunSensor(noise_std=0.01)
    rng = np.random.default_rng(8)
    sb = rng.standard_normal((30_000, 3))
    sb /= np.linalg.norm(sb, axis=-1, keepdims=True)
    sm, valid, _ = s.sun_sensor(model, sb, np.ones(len(sb), bool), rng.standard_normal((30_000, 3)))
    assert np.allclose(np.linalg.norm(sm, axis=-1), 1.0, rtol=0, atol=1e-15) and valid.all()
    ang = np.arccos(np.clip(np.sum(sm * sb, axis=-1), -1, 1))
    ok, ratio = _variance_ok(np.stack([ang / math.sqrt(2)] * 2, -1), model.noise_std**2)  # 2 dof per sample
    assert ok, ratio
    c = model.covariance(sb[0])
    assert np.allclose(c @ sb[0], 0.0, atol=1e-18) and np.trace(c) == pytest.approx(2 * 1e-4)


def test_sun_field_of_view():
    model = s.SunSensor(fov_half_angle=math.radians(60), boresight=(0.0, 0.0, 2.0))
    a = np.radians([0.0, 59.9, 60.1, 120.0])
    sb = np.stack([np.sin(a), 0 * a, np.cos(a)], -1)
    _, valid, in_fov = s.sun_sensor(model, sb, np.array([True, True, True, False]), np.zeros((4, 3)))
    assert in_fov.tolist() == [True, True, False, False] and valid.tolist() == [True, True, False, False]


def test_sun_dropout_exactly_in_the_eclipses_of_the_environment():
    """Two orbits of the default (noon-midnight, 38 % in shadow) orbit at 10 s: the sensor is valid
    exactly where env.sun.shadow_cylindrical says lit, and the eclipses are two intervals."""
    env = Environment(orbit_duration=12_000.0)
    t = np.arange(0.0, 11_200.0, 10.0)
    r, v = env.orbit.state(t)
    sun = env.sun_eci(t)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))
    sb = s.sun_direction_body(q, r, v, sun)
    # attitude = orbital frame: the body vector is the orbital-axes direction of Sun - r
    d = np.einsum("...ij,...j->...i", eci_to_orbital(r, v), sun - r)
    assert np.allclose(sb, d / np.linalg.norm(d, axis=-1, keepdims=True), rtol=0, atol=1e-14)
    _, valid, _ = s.sun_sensor(s.SunSensor(noise_std=0.01), sb, s.illuminated(r, sun),
                               np.random.default_rng(0).standard_normal((len(t), 3)))
    lit = shadow_cylindrical(r, sun) == 1.0
    assert np.array_equal(valid, lit)
    entries = np.flatnonzero(lit[:-1] & ~lit[1:])
    assert len(entries) == 2 and 0.36 < 1 - lit.mean() < 0.40


def test_position_fix_noise():
    model = s.PositionFix(noise_std=5.0, velocity_noise_std=0.05)
    n = np.random.default_rng(9).standard_normal((10_000, 6))
    r, v = np.full((10_000, 3), 7e6), np.full((10_000, 3), 7.5e3)
    rm, vm = s.position_fix(model, r, v, n)
    assert _variance_ok(rm - r, 25.0)[0] and _variance_ok(vm - v, 0.05**2)[0]


def test_suite_from_the_schema_defaults_and_the_legacy_gyro_noise():
    v = parse({"gyro_noise_std": 1e-5, "ts": 4.0, "gyro_arw": 3e-5}, SENSOR_FIELDS, "test")
    suite = s.SensorSuite.from_values(v)
    # white std per sample = sqrt(std^2 + arw^2 / ts)
    assert suite.gyro.white_std(4.0) == pytest.approx(math.sqrt(1e-10 + 9e-10 / 4.0), rel=1e-14)
    assert suite.noisy and not s.SensorSuite.from_values(parse({}, SENSOR_FIELDS, "test")).noisy
    with pytest.raises(ConfigError, match="gyro_rrw"):
        parse({"gyro_rrw": 1.0}, SENSOR_FIELDS, "test")
    with pytest.raises(ConfigError, match="sun_boresight"):
        check_sensors(parse({"sun_boresight": [0.0, 0.0, 0.0]}, SENSOR_FIELDS, "test"), "test")
