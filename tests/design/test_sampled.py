"""The sample-and-hold loop (design/sampled.py) against independent references: scipy's ZOH
discretization (constant field), a dense RK4 integration of the held loop (periodic field), the
continuous-time limit, and the hold constraint inside the tuning objective."""
import numpy as np
import pytest
from scipy.signal import cont2discrete

from magtune_core.design.lq import lq_gain
from magtune_core.design.model import AttitudeLTP, skew_field
from magtune_core.design.objective import HinfObjective
from magtune_core.design.params import SpacecraftParams
from magtune_core.design.problem import attitude_system
from magtune_core.design.sampled import HoldConstraint, SampledLoop, _held_products, feasible_start, hold_gain_margin
from magtune_core.ltp import spectral_radius


@pytest.fixture(scope="module")
def paper():
    model = AttitudeLTP.from_params(SpacecraftParams())
    return model, lq_gain(model, 60.0)


def test_constant_field_equals_scipy_zoh():
    """Constant b: Gamma_k is the textbook ZOH input matrix of (A, B_T P) for every k."""
    model = AttitudeLTP.from_params(SpacecraftParams(field_model="constant", constant_field=np.array([2e-5, 1e-5, 1.5e-5])))
    loop = SampledLoop.build(model, 10.0)
    Bp = model.B(np.array([0.0]))[0]
    Ad, Bd, *_ = cont2discrete((model.A, Bp, np.eye(6), np.zeros((6, 3))), loop.ts, method="zoh")
    np.testing.assert_allclose(loop.Ad, Ad, rtol=0, atol=1e-12)
    # composite Gauss-Legendre (2.5 s panels) on e^{A s}: error ~(0.08 x 2.5)^8 / 8! ~ 1e-10 of |Bd| at
    # most (a single 10 s panel measured 6e-10); 1e-9 leaves room
    np.testing.assert_allclose(loop.Gamma, np.broadcast_to(Bd, loop.Gamma.shape), rtol=0, atol=1e-9 * np.abs(Bd).max())
    K = lq_gain(model, 60.0)
    step = np.abs(np.linalg.eigvals(Ad + Bd @ K)).max()
    # rho over one period = (per-step radius)^N for an LTI loop; 1e-8 relative: round-off of N products
    np.testing.assert_allclose(loop.spectral_radius(K[None])[0], step**loop.intervals, rtol=1e-8)


def _rk4_monodromy(model, K, loop, sub=200):
    """Dense RK4 (h/sub steps) of x' = A x + B_T S(b(t)) m_k, m_k = S(b_k)^T K x_k / |b_k|^2 held."""
    A, BT, h = model.A, model.BT, loop.ts
    X = np.eye(6)
    dt = h / sub
    for k in range(loop.intervals):
        tk = k * h
        bk = model.field(np.array([tk]))[0]
        m = skew_field(bk).T @ K @ X / (bk @ bk)  # (3, 6): held dipole per column

        def f(t, Y):
            return A @ Y + BT @ skew_field(model.field(np.array([t]))[0]) @ m

        Y = X
        for j in range(sub):
            t = tk + j * dt
            k1 = f(t, Y)
            k2 = f(t + dt / 2, Y + dt / 2 * k1)
            k3 = f(t + dt / 2, Y + dt / 2 * k2)
            k4 = f(t + dt, Y + dt * k3)
            Y = Y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        X = Y
    return X


def test_periodic_field_equals_dense_integration(paper):
    """Paper field, Ts = 60 s (the largest interval of the sampling study: Gauss-Legendre's hardest
    case): the product of interval maps equals the monodromy of a dense RK4 integration."""
    model, K = paper
    loop = SampledLoop.build(model, 60.0)
    X = _rk4_monodromy(model, 0.2 * K, loop, sub=400)
    M = np.eye(6)
    for k in range(loop.intervals):
        M = (loop.Ad + loop.Gamma[k] @ (0.2 * K)) @ M
    # the reference's own error: RK4 at dt = 0.15 s is 9e-8 of max|X| (2.4e-5 / 1.5e-6 / 9e-8 at
    # 100 / 200 / 400 sub-steps: 16x per halving, so it is RK4's, not the product's); 5e-7 bound
    np.testing.assert_allclose(M, X, rtol=0, atol=5e-7 * np.abs(X).max())
    ev = np.abs(np.linalg.eigvals(X)).max()
    np.testing.assert_allclose(loop.spectral_radius(0.2 * K[None])[0], ev, rtol=1e-6)
    # the compiled product (renormalized every 32 intervals) is the numpy product to round-off
    P, logscale = _held_products(loop.Ad, loop.Gamma, np.ascontiguousarray(0.2 * K[None]))
    np.testing.assert_allclose(P[0] * np.exp(logscale[0]), M, rtol=0, atol=1e-12 * np.abs(M).max())


def test_fast_sampling_tends_to_the_continuous_loop(paper):
    """Ts -> 0: the held loop's multipliers tend to the continuous-time ones (error O(Ts))."""
    model, K = paper
    rho_c = spectral_radius(attitude_system(model, K[None]), 512)[0]
    errs = []
    for ts in (4.0, 1.0, 0.25):
        rho_s = SampledLoop.build(model, ts).spectral_radius(K[None])[0]
        errs.append(abs(np.log(rho_s) - np.log(rho_c)))
    # first order in Ts: the error falls ~4x per 4x shorter period (2.5x allows for the O(Ts^2) term)
    assert errs[0] > 2.5 * errs[1] > 6.25 * errs[2]
    assert errs[2] < 0.01 * abs(np.log(rho_c))


def test_gain_margin_brackets_the_stability_boundary(paper):
    model, K = paper
    K = 10.0 * K  # the LQ gain itself has a margin beyond the search's upper end (16); 10x: ~7.7
    loop = SampledLoop.build(model, 1.0)
    g = hold_gain_margin(loop, K)
    assert 1.0 < g < 16.0
    rho = loop.spectral_radius(np.stack([g * K, 1.01 * g * K]))
    assert rho[0] < 1.0 <= rho[1]  # the bracket is 1e-3 wide, so 1 % above is unstable


def test_objective_rejects_gains_that_fail_the_margin(paper):
    """A gain stable in continuous time but whose held loop fails the margin gets J = inf."""
    model, K = paper
    loop = SampledLoop.build(model, 1.0)
    Ks = np.stack([K, 10.0 * K])  # hold gain margins >= 16 and ~7.7
    g = hold_gain_margin(loop, Ks[1])
    hold = HoldConstraint(1.0, 10.0)
    free = HinfObjective(model, 60.0, steps=64, rtol=1e-6)(Ks)
    held = HinfObjective(model, 60.0, steps=64, rtol=1e-6, hold=hold)(Ks)
    assert np.all(np.isfinite(free)) and g < 10.0
    assert held[1] == np.inf
    np.testing.assert_allclose(held[0], free[0], rtol=1e-6)  # same gain, the bisection's bracket 1e-6
    # the screen alone (what the tuner's first coordinates are scaled with) agrees with J's finiteness,
    # also for a gain unstable in continuous time
    with HinfObjective(model, 60.0, steps=64, hold=hold) as obj:
        assert obj.feasible(np.stack([K, 10.0 * K, -K])).tolist() == [True, False, False]
    with HinfObjective(model, 60.0, steps=64, hold=hold, workers=2) as obj:  # split over worker processes
        assert obj.feasible(np.stack([K, 10.0 * K, -K, K])).tolist() == [True, False, False, True]
    K1, note = feasible_start(model, Ks[1], hold)
    assert note.startswith("scaled by") and hold_gain_margin(loop, K1) >= 10.0


def test_hold_constraint_validates():
    with pytest.raises(ValueError, match="gain_margin"):
        HoldConstraint(1.0, 0.5)
    with pytest.raises(ValueError, match="ts"):
        HoldConstraint(float("nan"), 2.0)


def test_feasible_start_over_a_model_set(paper):
    """A robust model set: the start is scaled until every model's held loop meets the margin, checked
    together (a lighter satellite, half the inertia, is the binding model here)."""
    model, K = paper
    light = AttitudeLTP.from_params(SpacecraftParams(inertia=0.5 * np.array([35.0, 17.0, 25.0])))
    hold = HoldConstraint(1.0, 10.0)
    K_set, note = feasible_start([model, light], 10.0 * K, hold)
    K_light, _ = feasible_start(light, 10.0 * K, hold)
    K_nom, _ = feasible_start(model, 10.0 * K, hold)
    assert note.startswith("scaled by")
    for m in (model, light):  # the margin's own accuracy is ~1e-3 (hold_gain_margin)
        assert hold_gain_margin(SampledLoop.build(m, 1.0), K_set) >= 10.0 * (1 - 1e-3)
    # the set's scaling is the stricter of the two (the lighter model's), not the nominal one's
    np.testing.assert_array_equal(K_set, K_light)
    assert np.abs(K_light).max() < np.abs(K_nom).max()


def test_shipped_optima_start_where_they_are(paper):
    """The shipped gains sit on the constraint (margin 2 +- 1e-3), where the check can fail by round-off
    (the sigma = 120 gain, tuned with the numpy product, fails the compiled one). As a start
    (`magtune tune --start`, `magtune front --start`) each keeps at least 0.999 of itself, so its J."""
    from pathlib import Path

    from magtune_core.design.gains import load_gains

    model, _ = paper
    hold = HoldConstraint(1.0, 2.0)
    for sigma in (60, 120, 240):
        K = load_gains(Path(__file__).resolve().parents[2] / f"config/gains/sigma_{sigma}.yaml").K
        K1, note = feasible_start(model, K, hold)
        factor = float(np.abs(K1).max() / np.abs(K).max())
        assert factor >= 0.999, (sigma, note)
