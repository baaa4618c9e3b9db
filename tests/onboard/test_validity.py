"""The estimate's validity monitor (onboard.validity): its NIS limit against a Monte Carlo of the average it
bounds, and its rules (fix, sigma, capped NIS average) on scripted samples."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from magtune_core.onboard.params import VALIDITY_FIELDS
from magtune_core.onboard.validity import ValidityMonitor, nis_limit


@pytest.mark.parametrize("tau", [10.0, 60.0])
def test_nis_limit_matches_a_monte_carlo_of_the_average(tau):
    """The two-moment chi-square approximation against 2e6 averaged chi-square(3) samples (seeded): the
    fraction above nis_limit(tau, 1, p) for p = 1e-2 and 1e-3 within 0.6-1.6 p (the tails of the true
    distribution of the average differ from the approximation's by tens of percent at most at these
    quantiles; the Monte Carlo's own error at 1e-3 of ~2e6 correlated samples is ~10 %)."""
    rng = np.random.default_rng(7)
    a = math.exp(-1.0 / tau)
    x = rng.chisquare(3, size=2_000_000)
    y = lfilter([1.0 - a], [1.0, -a], x, zi=[3.0 * a])[0][int(20 * tau):]  # started at the mean, transient dropped
    assert abs(np.mean(y) - 3.0) < 0.01
    for p in (1e-2, 1e-3):
        frac = float(np.mean(y > nis_limit(tau, 1.0, p)))
        assert 0.6 * p < frac < 1.6 * p, (tau, p, frac)


def test_default_limit_is_the_documented_quantile():
    """valid_nis_limit's default (4.6) is nis_limit(60 s, 1 s, 1e-9) rounded up (4.54): the schema's comment
    and docs/modes.md say so."""
    default = {f.name: f.default for f in VALIDITY_FIELDS}
    assert default["valid_nis_tau"] == 60.0
    q = nis_limit(60.0, 1.0, 1e-9)
    assert q <= default["valid_nis_limit"] < q + 0.1, q


def _monitor():
    return ValidityMonitor(ts=1.0, sigma=0.03, tau=60.0, limit=4.6, cap=21.1)


def test_rules_fix_sigma_and_average():
    """Not valid before the fix; valid with small sigma and NIS at its mean; a sigma above the limit on
    any axis is not valid; a run of large NIS makes the average cross the limit after the number of
    samples the recursion gives."""
    m, P = _monitor(), np.diag([1e-4] * 3 + [1e-8] * 6)
    assert not m.step(None, 3.0) and math.isnan(m.average)
    assert m.step(P, 3.0) and m.average == pytest.approx(3.0)
    big = P.copy()
    big[1, 1] = 0.031**2
    assert not m.step(big, 3.0)
    # NIS 10 from the mean: y_n = 10 - 7 a^n crosses 4.6 at n = ceil(ln(5.4/7)/ln a)
    a = math.exp(-1.0 / 60.0)
    n_expected = math.ceil(math.log((10.0 - 4.6) / 7.0) / math.log(a))
    m = _monitor()
    m.step(P, math.nan)  # the fix: average starts at 3, no update this sample (holds)
    n = next(k for k in range(1, 1000) if not m.step(P, 10.0))
    assert n == n_expected, (n, n_expected)


def test_one_outlier_moves_the_average_by_at_most_the_capped_share():
    """A rejected update (NIS 1e6) counts as the gate's value: the average moves by (1 - a) cap at most,
    so one outlier cannot make the estimate invalid."""
    m, P = _monitor(), np.diag([1e-4] * 3 + [1e-8] * 6)
    m.step(P, 3.0)
    before = m.average
    assert m.step(P, 1e6)
    a = math.exp(-1.0 / 60.0)
    assert m.average - before == pytest.approx((1.0 - a) * (21.1 - 3.0))


def test_reinit_due_after_its_time_not_valid_and_reset():
    """reinit_time 30 s at ts 1: due at the 30th sample in a row not valid after the fix, not before; a valid
    sample restarts the count; reset() returns the monitor to its state before a fix; 0 never."""
    m, P = ValidityMonitor(1.0, 0.03, 60.0, 4.6, 21.1, reinit=30.0), np.diag([1e-4] * 3 + [1e-8] * 6)
    big = np.diag([1.0] * 3 + [1e-8] * 6)
    for _ in range(29):
        m.step(big, 3.0)
    assert not m.reinit_due
    m.step(P, 3.0)  # valid: the count restarts
    for _ in range(29):
        m.step(big, 3.0)
    assert not m.reinit_due
    m.step(big, 3.0)
    assert m.reinit_due
    m.reset()
    assert math.isnan(m.average) and not m.reinit_due
    never = ValidityMonitor(1.0, 0.03, 60.0, 4.6, 21.1, reinit=0.0)
    for _ in range(1000):
        never.step(big, 3.0)
    assert not never.reinit_due
