"""The estimator in the batched closed loop (sim.batch.simulate_batch(estimator=...)): the compiled filter
of every run equals the Python MekfStream fed with the same measurements, rebuilt here from the run's
recorded truth, its seeds and the single-run environment; the controller flies the estimate."""
from __future__ import annotations

import math

import numpy as np
import pytest

from magtune_core.base.rotations import matrix_to_quat, rotation_matrix
from magtune_core.design.gains import load_gains
from magtune_core.design.params import load_spacecraft
from magtune_core.design.sensors import (
    AUX_NORMALS,
    GYRO_U,
    GYRO_V,
    MAG,
    SUN,
    Gyro,
    Magnetometer,
    SensorSuite,
    SunSensor,
    aux_rng,
    draw,
    gyro_bias_walk,
    sun_sensor,
)
from magtune_core.env.environment import Environment
from magtune_core.env.orbit import eci_to_orbital
from magtune_core.env.sun import shadow_cylindrical
from magtune_core.onboard.estimator import MekfStream
from magtune_core.onboard.mekf import MekfParams, attitude_error
from magtune_core.onboard.sensor_watch import MAG_FAULT, SensorWatch, SensorWatchParams
from magtune_core.onboard.validity import ValidityMonitor
from magtune_core.sim.batch import NOISE_CHUNK, BatchEstimator, BatchRuns, SensorNoise, simulate_batch
from magtune_core.sim.fullenv import FullEnvironmentOptions

STEPS = 900  # < NOISE_CHUNK: one block of normals per run
BIAS = np.deg2rad(np.array([40.0, -60.0, 30.0])) / 3600.0
MAG_BIAS = np.array([2e-7, -2e-7, 2e-7])  #: the campaigns' 200 nT per axis (the default filter estimates it)


def _fly(est: BatchEstimator, faults=()):
    """Two full-environment runs on different orbits (RAAN 0 and 40 deg: the batched ephemeris), default
    estimator, the default sensors (100 nT, sigma_v 1e-4, sigma_u 1e-6, bias (40, -60, 30) deg/h, 0.5 deg sun)
    and a 200 nT per-axis magnetometer bias."""
    g, p = load_gains("config/gains/sigma_120.yaml"), load_spacecraft("config/spacecraft.yaml")
    B = 2
    sens = SensorNoise(np.full(B, 1e-7), np.tile(MAG_BIAS, (B, 1)), np.zeros(B), np.tile(BIAS, (B, 1)), np.zeros(B),
                       [[7, i, 1] for i in range(B)], gyro_arw=np.full(B, 1e-4), gyro_rrw=np.full(B, 1e-6))
    opts = [FullEnvironmentOptions(raan_deg=40.0 * i) for i in range(B)]
    runs = BatchRuns(g.K, np.tile(np.asarray(p.inertia, dtype=float), (B, 1)), np.ones((B, 3)), np.full(B, 50.0),
                     np.tile([1.0, 0.0, 0.0, 0.0], (B, 1)), np.tile([1e-3, 2e-3, 0.0], (B, 1)), p, "full", opts, sens)
    res = simulate_batch(runs, ts=1.0, steps=STEPS, substeps=2, record_every=1, full_series=True, estimator=est,
                         faults=faults)
    return p, opts, sens, est, res


@pytest.fixture(scope="module")
def batch():
    """The default estimator (no validity gate)."""
    return _fly(BatchEstimator())


@pytest.mark.parametrize("reinit", [0.0, 15.0])
def test_validity_gate_equals_the_python_monitor_sample_for_sample(reinit):
    """With the validity gate (the full stack's), a run flies zero dipole exactly at the samples where
    onboard.validity.ValidityMonitor, fed by the Python MekfStream on the same measurements, says not
    valid, and restarts its filter at the same samples (reinit_time 15 s: several restarts). A tight gate
    (NIS averaged over 5 s, limit 3: a consistent filter's mean) makes it flip many times in 900 s; the
    two filters agree to ~1e-10 (above), far from any sample's margin."""
    p, opts, sens, est, res = _fly(BatchEstimator(validity_gate=True, valid_nis_tau=5.0, valid_nis_limit=3.0,
                                                  reinit_time=reinit))
    cap = MekfParams(1.0, 1.0, est.gate_probability).gate(3)
    for b in range(2):
        mon = ValidityMonitor(1.0, est.valid_sigma, est.valid_nis_tau, est.valid_nis_limit, cap, reinit)
        states, *_, valid, restarts = _python_filter(p, opts[b], sens, est, res, b, monitor=mon)
        invalid = ~valid
        assert (len(restarts) >= 2) == (reinit > 0), restarts  # restarts happened, and only with reinit_time
        switches = int(np.sum(invalid[1:] != invalid[:-1]))
        assert 100 < invalid.sum() < len(invalid) - 100 and switches > 20, (invalid.sum(), switches)
        assert res.no_attitude_steps[b] == invalid.sum()
        zero = np.all(res.m[b] == 0.0, axis=1)
        np.testing.assert_array_equal(zero[:STEPS], invalid[:STEPS])


def _python_filter(p, opt, sens, est, res, b, monitor=None, watch=None, jump=None):
    """MekfStream on run b's measurements: the batch's sensor models on its recorded truth (true q_bo, rate,
    body field) with the run's generators, reference vectors from the single-run Environment. ``watch``: a list
    that receives (sample, Verdict) of the node's sensor watch and recovery (attitude_estimator.watch_sensors);
    ``jump``: (onset sample, axis, T) a magnetometer bias jump (the injected mag_bias)."""
    t = res.t
    env = Environment(opt.environment_config(p), orbit_duration=float(t[-1]) + 60.0)
    r, v = env.orbit.state(t)
    R_oi = eci_to_orbital(r, v)
    sun = env.sun_eci(t)
    s_ref = (sun - r) / np.linalg.norm(sun - r, axis=-1, keepdims=True)
    lit = shadow_cylindrical(r, sun) > 0.5
    nrm = draw(np.random.default_rng(sens.seeds[b]), NOISE_CHUNK)[: t.size]
    aux = draw(aux_rng(sens.seeds[b]), NOISE_CHUNK, AUX_NORMALS)[: t.size]
    g = sens.gyros(1.0)[b]
    walk = gyro_bias_walk(g, 1.0, g.bias, nrm[:, GYRO_U])
    mag = res.b[b] + MAG_BIAS + 1e-7 * nrm[:, MAG]
    if jump is not None:
        mag[jump[0]:, jump[1]] += jump[2]
    w_m = res.w[b] + 0.5 * (walk[1:] + walk[:-1]) + g.white_std(1.0) * nrm[:, GYRO_V]
    R_bo = rotation_matrix(res.q[b])
    s_body = np.einsum("kji,kj->ki", R_bo, np.einsum("kij,kj->ki", R_oi, s_ref))  # R_bo^T R_oi s_eci
    s_m, ok, _ = sun_sensor(SunSensor(est.sun_sensor_std), s_body, lit, aux[:, SUN])
    suite = SensorSuite(1.0, Magnetometer(est.mag_noise_std), Gyro(est.gyro_arw, est.gyro_rrw), 0.0,
                        SunSensor(est.sun_noise_std))
    stream = MekfStream(suite)
    sw = SensorWatch(SensorWatchParams.of_stream(stream)) if watch is not None else None
    b_ref = env.magnetic_field_eci(t, r)
    out, valid, restarts = [], [], []
    for k in range(t.size):
        step = stream.step(w_m[k - 1] if k else None, mag[k], b_ref[k], *((s_m[k], s_ref[k]) if ok[k] else (None, None)))
        out.append(step.state)
        if monitor is not None:  # the node's order: the step, the validity, a restart when due
            valid.append(step.state is not None and monitor.step(step.state.P, step.nis_mag))
            if monitor.reinit_due:
                stream.reset()
                monitor.reset()
                restarts.append(k)
        if sw is not None and step.state is not None:  # then the watch (attitude_estimator.watch_sensors)
            st = step.state
            calm = np.linalg.norm(w_m[k] - st.b) < est.watch_arm_rate
            v = sw.step(step.nis_mag, step.nis_sun, step.sun_accepted, st.b, st.P[3:6, 3:6],
                        valid[-1] and (calm or sw.armed), step.started)
            if v is not None:
                watch.append((k, v))
                if v.status == "failed":
                    gyro = v.unit == "gyro"
                    stream.reopen(v.unit, est.recover_gyro_bias_std if gyro else est.recover_mag_bias_std,
                                  est.recover_attitude_std)
                    monitor.forgive()
    return out, R_oi, w_m, lit, np.array(valid), restarts


@pytest.mark.parametrize("b", [0, 1])
def test_batched_filter_equals_python_filter_on_the_same_measurements(batch, b):
    """Attitude within 1e-9 rad, gyro bias (of the prior 5e-4 rad/s) and P within 1e-9 relative, the
    magnetometer bias within 1e-9 of a 3e-5 T field at every step. The Python side rebuilds
    the measurements from the recorded truth, so both see the same inputs up to the rounding of the
    reference vectors: the batch rotates the table's orbital-axes field back with R_oi^T (~1e-16
    relative), the batched ephemeris differs from the single-run one by ~1e-5 m (~1e-12 rad of frame).
    The 6-state filter contracts these (each update weighs the new sample): ~2e-12 rad. The 9 states
    (200 nT bias, the default 300 nT prior) carry them ~60x further while the bias is weakly observed
    (t = 30-300 s): measured 1.3e-10 rad, 5e-10 (gyro bias), 3e-10 (P), 7e-11 (magnetometer bias); the
    kernel itself equals the Python filter on identical inputs to ~1e-13 (tests/onboard/test_mekf_kernel.py)."""
    p, opts, sens, est, res = batch
    states, R_oi, w_m, lit, *_ = _python_filter(p, opts[b], sens, est, res, b)
    assert lit.all() and res.est_k0[b] == 0 and res.no_attitude_steps[b] == 0  # lit at t = 0: the Davenport fix
    worst = np.zeros(4)
    for k, s in enumerate(states):
        worst = np.maximum(worst, [np.linalg.norm(attitude_error(s.q, res.est_q[b, k])),
                                   np.max(np.abs(res.est_bias[b, k] - s.b)) / 5e-4,
                                   np.max(np.abs(res.est_P[b, k] - s.P)) / np.max(np.abs(s.P)),
                                   np.max(np.abs(res.est_mag_bias[b, k] - s.m)) / 3e-5])
    assert np.all(worst < 1e-9), worst
    # the controller flew the estimate: x = [vector part of q_bo estimate; gyro - bias + W0 z]
    k = STEPS // 2
    q_bo = matrix_to_quat(R_oi[k] @ rotation_matrix(states[k].q))
    np.testing.assert_allclose(res.x[b, k, :3], q_bo[1:], atol=1e-9)
    w0 = 2 * np.pi / res.orbit_period[b]
    np.testing.assert_allclose(res.x[b, k, 3:], w_m[k] - states[k].b + [0.0, 0.0, w0], atol=1e-12)


def test_batched_estimation_error_inside_three_sigma(batch):
    """The estimate against the truth in the loop, from t = 300 s (the bias transient of the fix at t = 0;
    tests/ros/test_estimator_sil.py uses the same window): inside 3 sigma per axis for >= 95 % of the
    samples (99.7 % expected of a consistent filter), sub-degree RMS."""
    *_, res = batch
    e, s = res.est_error[:, 300:], res.est_sigma[:, 300:]
    inside = np.mean(np.abs(e) <= 3 * s, axis=1)
    assert np.all(inside >= 0.95), inside
    assert np.all(np.degrees(np.sqrt(np.mean(e.astype(float) ** 2, axis=1))) < 1.0)
    assert math.isfinite(float(np.mean(res.est_nees[:, 300:])))


def _closed_loop(B, steps, estimator, seed=3):
    g, p = load_gains("config/gains/sigma_120.yaml"), load_spacecraft("config/spacecraft.yaml")
    sens = SensorNoise(np.full(B, 1e-7), np.zeros((B, 3)), np.zeros(B), np.tile(BIAS, (B, 1)), np.zeros(B),
                       [[seed, i, 1] for i in range(B)], gyro_arw=np.full(B, 1e-4), gyro_rrw=np.full(B, 1e-6))
    runs = BatchRuns(g.K, np.tile(np.asarray(p.inertia, dtype=float), (B, 1)), np.ones((B, 3)), np.full(B, 50.0),
                     np.tile([1.0, 0.0, 0.0, 0.0], (B, 1)), np.tile([1e-3, 2e-3, 0.0], (B, 1)), p, "full",
                     [FullEnvironmentOptions(raan_deg=60.0 * i) for i in range(B)], sens)
    return simulate_batch(runs, ts=1.0, steps=steps, substeps=2, record_every=600, full_series=True, estimator=estimator)


#: NEES samples of a window are taken LAG s apart: in this closed loop the NEES autocorrelation at 100 s is
#: 0.02-0.10 (measured on these 6 runs), so the samples are close to independent, which the chi2(3N)/N band of
#: their mean assumes (consecutive 1 Hz samples are not: docs/estimation.md#consistency).
LAG, N = 100, 10


def _windows(res, start=600):
    from magtune_core.sim.estimation import nees_windows

    d = res.est_nees[:, start::LAG].astype(float)
    parts = [nees_windows(x, N) for x in d]
    means = np.concatenate([m for m, _, _ in parts])
    return d, means, parts[0][1], parts[0][2]


def test_closed_loop_nees_windows_inside_the_chi_square_band():
    """The estimator in the loop, white-noise sensors with the filter's own model (100 nT, Farrenkopf gyro
    sigma_v 1e-4 / sigma_u 1e-6, 0.5 deg sun), 6 runs x 4 orbits on six orbit planes, full environment. NEES
    window means (N = 10 samples LAG = 100 s apart, from 600 s) inside the 95 % band of chi2(3N)/N in >= 85 %
    of the 132 windows: for a consistent filter the count is Binomial(132, 0.95), P(< 85 %) < 1e-5 (measured
    94.7 %). The mean of all decimated samples inside the 99 % band of its chi2 mean (measured 3.03 in
    [2.83, 3.18]); the error inside 3 sigma in >= 99 % of the samples per axis and run (99.73 % expected;
    measured 99.69-99.95 %)."""
    from scipy.stats import binom, chi2

    res = _closed_loop(6, 4 * 5670, BatchEstimator())
    d, means, lo, hi = _windows(res)
    assert means.size == 132 and binom.cdf(int(0.85 * means.size), means.size, 0.95) < 1e-5
    inside = np.mean((means >= lo) & (means <= hi))
    assert inside >= 0.85, (inside, means)
    n = d.size
    assert chi2.ppf(0.005, 3 * n) / n <= d.mean() <= chi2.ppf(0.995, 3 * n) / n, d.mean()
    frac = np.mean(np.abs(res.est_error[:, 600:]) <= 3 * res.est_sigma[:, 600:], axis=1)
    assert np.all(frac >= 0.99), frac


def test_closed_loop_nees_check_fails_an_overconfident_filter():
    """The same check catches a filter that believes the magnetometer twice as good as it is (R 4x too small):
    most windows leave the band and the decimated mean is far above 3 (measured: 15 % of 20 windows inside, mean
    5.95). The check can fail."""
    res = _closed_loop(2, 2 * 5670, BatchEstimator(mag_noise_std=50e-9))
    d, means, lo, hi = _windows(res)
    assert np.mean((means >= lo) & (means <= hi)) < 0.5 and d.mean() > 4.5, (means, d.mean())


def test_sensor_watch_and_its_recovery_equal_the_node_sample_for_sample():
    """The batch's sensor watch (sim/batch_kernels._watch: the compiled watch_step, the node's arming on a calm body
    and its recovery) against SensorWatch and MekfStream.reopen run as the estimator node does on the same
    measurements: a 2000-nT magnetometer bias jump at 650 s (the watch armed at ~600 s of valid estimate) is named
    the magnetometer at the same sample by both, and after the recovery the filters still agree (the attitude
    within 1e-9 rad: the equality tests' tolerance, above) to the run's end; the jump costs no restart."""
    jump = (650, 0, 2e-6)
    p, opts, sens, est, res = _fly(BatchEstimator(validity_gate=True), faults=("mag_bias@650,axis=x,value=2e-6",))
    cap = MekfParams(1.0, 1.0, est.gate_probability).gate(3)
    for b in range(2):
        mon = ValidityMonitor(1.0, est.valid_sigma, est.valid_nis_tau, est.valid_nis_limit, cap, est.reinit_time)
        verdicts = []
        states, *_, valid, restarts = _python_filter(p, opts[b], sens, est, res, b, monitor=mon, watch=verdicts, jump=jump)
        assert [(k, v.unit) for k, v in verdicts] == [(res.fdir_time[b], "magnetometer")], verdicts
        assert res.fdir_code[b] == MAG_FAULT and res.fdir_count[b] == 1 and restarts == []
        assert 650 + 100 <= res.fdir_time[b] <= 650 + 600  # the 120-s confirmation after M's crossing
        err = max(np.linalg.norm(attitude_error(states[k].q, res.est_q[b, k])) for k in range(700, STEPS + 1))
        assert err < 1e-9, err
        assert res.no_attitude_steps[b] == np.sum(~valid)
