"""The compiled MEKF (onboard/mekf_kernel.py, what the batched simulation flies) equals the Python
filter (onboard.estimator.MekfStream on onboard.mekf) on the same measurements, sample by sample."""
from __future__ import annotations

import math

import numpy as np
import pytest
from kinematic import b_ref, wobble_rate  # tests/support

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
    gyro,
    magnetometer,
    sun_sensor,
)
from magtune_core.onboard import mekf_kernel as MK
from magtune_core.onboard.estimator import MekfStream
from magtune_core.sim import estimation as E


def _measurements(truth, suite, seed):
    """The sensors of run_mekf on ``truth`` (same generators and order)."""
    n1 = len(truth.t)
    nrm = draw(np.random.default_rng(seed), n1)
    aux = draw(aux_rng(seed), n1, AUX_NORMALS)
    mag = magnetometer(suite.magnetometer, truth.b_body, nrm[:, MAG])
    w_m, _ = gyro(suite.gyro, truth.w, truth.ts, suite.gyro.bias, nrm[:-1, GYRO_V], nrm[:-1, GYRO_U])
    s_m, s_ok, _ = sun_sensor(suite.sun, truth.sun_body, truth.lit, aux[:, SUN])
    return mag, w_m, s_m, s_ok


MAG_BIAS = (2e-7, -2e-7, 2e-7)  #: the campaigns' 200 nT per axis (estimated by the default 9-state filter)


def _run(n: int, eclipse_start: bool):
    """The equality tests' run: n samples, gyro bias (40, -60, 30) deg/h, MAG_BIAS, sun lost from 1000 to
    1600 s (and over the first 400 s with ``eclipse_start``); (truth, suite, measurements of seed 7)."""
    lit = np.ones(n + 1, dtype=bool)
    lit[1000:1600] = False
    if eclipse_start:
        lit[:400] = False
    truth = E.kinematic_truth(n, 1.0, wobble_rate, b_ref, sun_ref=(1.0, 1.0, 0.3), lit=lit)
    bias = tuple(np.deg2rad(np.array([40.0, -60.0, 30.0])) / 3600.0)
    suite = SensorSuite(1.0, Magnetometer(100e-9, MAG_BIAS), Gyro(1e-4, 1e-6, bias), 0.0, SunSensor(math.radians(0.5)))
    return truth, suite, _measurements(truth, suite, 7)


@pytest.mark.parametrize("mag_bias_std", [3e-7, 0.0])
@pytest.mark.parametrize("eclipse_start", [False, True])
def test_compiled_filter_equals_python_filter(eclipse_start, mag_bias_std):
    """3000 samples, bias (40, -60, 30) deg/h, magnetometer bias 200 nT per axis estimated (prior 300 nT,
    the 9 states) or not (prior 0), sun lost from 1000 to 1600 s; a start in sunlight
    (Davenport of magnetometer and Sun at t = 0) or in eclipse (the magnetometer carried by the gyro
    until the field turned by 10 deg). Same float64 formulas in both; the only differences are the
    order of a few sums and LAPACK calls (eigh, solve) on 3x3/4x4 matrices: a few ulp per step,
    which the filter's contraction keeps from growing. Bound 1e-10 rad on the attitude (the error
    itself is ~1e-3 rad), 1e-10 of the prior's 5e-4 rad/s on the bias and of 3e-7 T on the magnetometer
    bias, 1e-10 relative on P (measured with 6 states: ~1e-15 / 1e-14 from the sunlit start; ~1e-12 /
    5e-12 from the eclipse start, whose carried-vector fix starts from an ill-conditioned P, sigma
    ~0.1 rad about the field)."""
    n = 3000
    truth, suite, (mag, w_m, s_m, s_ok) = _run(n, eclipse_start)
    stream = MekfStream(suite, mag_bias_std=mag_bias_std)
    km = MK.kernel_state(1, 1.0, arw=1e-4, rrw=1e-6, mag_cov=suite.magnetometer.covariance, sun_std=math.radians(0.5),
                         mag_bias_std=mag_bias_std)
    worst = np.zeros(4)
    started = None
    for k in range(n + 1):
        out = stream.step(w_m[k - 1] if k else None, mag[k], truth.b_ref[k], *((s_m[k], truth.sun_ref[k]) if s_ok[k]
                                                                               else (None, None)))
        nis_m, nis_s = MK.stream_step(km, 0, mag[k], truth.b_ref[k], bool(s_ok[k]), s_m[k], truth.sun_ref[k])
        if k < n:
            km.w_prev[0] = w_m[k]
        assert (out.state is not None) == bool(km.started[0]), k
        if out.state is None:
            continue
        started = k if started is None else started
        s = out.state
        assert s.P.shape == km.P[0].shape == (9, 9)
        worst = np.maximum(worst, [np.linalg.norm(E.attitude_error(s.q, km.q[0])),
                                   np.max(np.abs(km.b[0] - s.b)) / 5e-4,  # of the bias prior's scale
                                   np.max(np.abs(km.P[0] - s.P)) / np.max(np.abs(s.P)),
                                   np.max(np.abs(km.mb[0] - s.m)) / 3e-7])
        assert math.isclose(nis_m, out.nis_mag, rel_tol=1e-9), (k, nis_m, out.nis_mag)
        assert (math.isnan(nis_s) and math.isnan(out.nis_sun)) or math.isclose(nis_s, out.nis_sun, rel_tol=1e-9)
    assert started == int(km.k0[0]) and (started > 0) == eclipse_start, (started, km.k0)
    assert np.all(worst < 1e-10), worst
    print(f"worst differences (attitude rad, bias, P rel, mag bias): {worst}")
    if mag_bias_std == 0:
        assert np.all(km.mb[0] == 0) and np.all(km.P[0, 6:] == 0)
    else:  # the 9 states do estimate: 3000 s, a half orbit, bring the bias from 200 nT to within ~3 sigma
        sm = np.sqrt(np.diag(km.P[0, 6:, 6:]))
        assert np.all(np.abs(np.array(MAG_BIAS) - km.mb[0]) <= 3 * sm) and np.all(sm < 0.5 * mag_bias_std), sm
    assert km.counts[0, 0] + km.counts[0, 1] == n + 1 - started


#: Magnetometer gaps (dropouts: MekfStream.step with mag None): a few samples before the fix with
#: eclipse_start (the magnetometer-only fix waits for the field to turn), 60 s in sunlight, 60 s in eclipse.
GAPS = (range(3, 8), range(700, 760), range(1200, 1260))


@pytest.mark.parametrize("eclipse_start", [False, True])
def test_compiled_stream_equals_python_stream(eclipse_start):
    """MekfStream(compiled=True) (the attitude_estimator node's: the kernel's propagate and update
    after the Python coarse fix) against MekfStream on the run above (9 states, the default prior, the
    200 nT magnetometer bias), with the magnetometer gaps of GAPS: the same fix sample, NIS to 1e-9
    relative, attitude and biases within 1e-10 (rad, of the priors), P within 1e-10 relative. Through a gap
    no magnetometer update is made (NIS nan, no decision) and the attitude error at its end stays within
    the propagated covariance (NEES)."""
    n = 3000
    truth, suite, (mag, w_m, s_m, s_ok) = _run(n, eclipse_start)
    ref, fast = MekfStream(suite), MekfStream(suite, compiled=True)
    worst, accepted = np.zeros(4), [0, 0]
    gap = {k for g in GAPS for k in g}
    for k in range(n + 1):
        args = (w_m[k - 1] if k else None, None if k in gap else mag[k], truth.b_ref[k],
                *((s_m[k], truth.sun_ref[k]) if s_ok[k] else (None, None)))
        a, b = ref.step(*args), fast.step(*args)
        assert (a.state is None) == (b.state is None) and a.started == b.started, k
        if a.state is None:
            continue
        assert (a.mag_accepted, a.sun_accepted) == (b.mag_accepted, b.sun_accepted), k
        if k in gap:
            assert a.mag_accepted is None and math.isnan(a.nis_mag) and math.isnan(b.nis_mag), k
            if k + 1 not in gap:  # the gap's end: the gyro carried the attitude within its covariance (NEES
                # below chi2(3)'s 0.9999 quantile, 21.1: a consistent filter fails it once in 10^4 gap ends)
                err = E.attitude_error(truth.q[k], a.state.q)
                assert err @ np.linalg.solve(a.state.P[:3, :3], err) < 21.1, (k, err)
            continue
        accepted[0] += a.mag_accepted
        accepted[1] += bool(a.sun_accepted)
        assert math.isclose(a.nis_mag, b.nis_mag, rel_tol=1e-9), (k, a.nis_mag, b.nis_mag)
        assert (math.isnan(a.nis_sun) and math.isnan(b.nis_sun)) or math.isclose(a.nis_sun, b.nis_sun, rel_tol=1e-9)
        worst = np.maximum(worst, [np.linalg.norm(E.attitude_error(a.state.q, b.state.q)),
                                   np.max(np.abs(a.state.b - b.state.b)) / 5e-4,
                                   np.max(np.abs(a.state.P - b.state.P)) / np.max(np.abs(a.state.P)),
                                   np.max(np.abs(a.state.m - b.state.m)) / 3e-7])
    assert np.all(worst < 1e-10), worst
    print(f"worst differences (attitude rad, bias, P rel, mag bias): {worst}")
    assert accepted[0] > 2400 and accepted[1] > 1400, accepted
