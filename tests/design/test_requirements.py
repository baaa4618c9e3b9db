"""The design spec (design/requirements.py): validation, the checked sample periods against a
dense scan, and an infeasible requirement set named correctly by the tuner."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from magtune_core.base.errors import ConfigError
from magtune_core.design.gains import load_gains
from magtune_core.design.model import AttitudeLTP, skew_field
from magtune_core.design.params import SpacecraftParams
from magtune_core.design.pipeline import InfeasibleStart, tune_gains
from magtune_core.design.requirements import Requirements, load_requirements, scan_hold, spacecraft_dipole_limit
from magtune_core.design.sampled import SampledLoop

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def model():
    return AttitudeLTP.from_params(SpacecraftParams())


def test_shipped_spec_is_the_defaults():
    """config/design.yaml states the built-in defaults (one source of truth, a file users edit)."""
    limit = spacecraft_dipole_limit(REPO / "config/spacecraft.yaml")
    assert limit == 50.0
    shipped = load_requirements(REPO / "config/design.yaml", limit)
    default = Requirements.from_mapping({}, limit)
    assert (shipped.sampling, shipped.pointing) == (default.sampling, default.pointing)
    assert {k: np.asarray(v).tolist() for k, v in shipped.dipole.items()} == \
        {k: np.asarray(v).tolist() for k, v in default.dipole.items()}
    assert shipped.dipole_budget == pytest.approx(40.0)
    assert spacecraft_dipole_limit(REPO / "config/examples/cubesat12u/spacecraft.yaml") == 0.2


@pytest.mark.parametrize("raw, field", [
    ({"sampling": {"ts_max": 0.5}}, "sampling.ts_max"),
    ({"sampling": {"gain_margin": 0.5}}, "sampling.gain_margin"),
    ({"sampling": {"ts_mx": 20}}, "ts_mx"),
    ({"dipole": {"budget_fraction": -1}}, "budget_fraction"),
    ({"pointing": {"pass_fraction": 2}}, "pass_fraction"),
    ({"verify": {}}, "verify"),
])
def test_bad_spec_names_the_field(raw, field):
    with pytest.raises(ConfigError) as exc:
        Requirements.from_mapping(raw, 50.0, where="spec.yaml")
    assert field in str(exc.value) and str(exc.value).startswith("spec.yaml")


def test_checked_periods_agree_with_a_dense_scan(model):
    """A family of gains through the hold boundary (the paper-method gain scaled): the tuner's
    screen (8 periods) says feasible exactly where a 150-period scan of [1, 30] s does; this is
    what makes 8 periods enough for these loops (the pipeline's 96-period scan is the guard)."""
    req = Requirements.from_mapping({"dipole": {"budget_fraction": 0}}, 50.0)
    screen = req.screen(model)
    K = load_gains(REPO / "config/gains/paper_method/sigma_60.yaml").K
    factors = np.geomspace(0.5, 4.0, 6)  # its margin at 30 s is 2.54: the family crosses 4
    fast = screen(factors[:, None, None] * K)
    cache: dict = {}  # the 150 loops built once, flown by the 6 gains
    dense = np.array([scan_hold(model, f * K, req, points=150, cache=cache)[1].all() for f in factors])
    assert fast.any() and not fast.all()  # the family crosses the boundary
    np.testing.assert_array_equal(fast, dense)


def test_scan_uses_the_implemented_intervals(model):
    req = Requirements.from_mapping({}, 50.0)
    ts, ok = scan_hold(model, np.zeros((3, 6)), req, points=5)
    T = model.period
    np.testing.assert_allclose(ts, [T / round(T / t) for t in np.geomspace(1.0, 30.0, 5)])  # default 1-30 s
    assert len(ok) == 5


def test_infeasible_dipole_budget_is_named(model):
    """A budget below what the residual dipole alone needs: the tuner refuses before searching and
    names the dipole requirement (not the hold margin, which the start meets)."""
    req = Requirements.from_mapping({"dipole": {"limit": 0.5, "budget_fraction": 1.0}}, 50.0)
    with pytest.raises(InfeasibleStart) as exc:
        tune_gains(model, 120.0, requirements=req)
    msg = str(exc.value)
    assert "binding: peak |m_" in msg and "needs <= 0.5" in msg and "hold gain margin" not in msg.split("binding:")[1]


def test_infeasible_hold_range_is_named(model):
    """Holding gain margin 2 up to Ts = 120 s (beyond the nutation limit, ~38 s) is impossible."""
    req = Requirements.from_mapping({"sampling": {"ts_max": 120.0}, "dipole": {"budget_fraction": 0}}, 50.0)
    loop = SampledLoop.build(model, 120.0)
    assert loop.intervals == round(model.period / 120.0)
    with pytest.raises(InfeasibleStart) as exc:
        tune_gains(model, 120.0, requirements=req)
    assert "binding: hold gain margin at Ts = 1" in str(exc.value) and "unstable at every scaling" in str(exc.value)


def test_example_12u_spec_overrides_only_the_residual_dipole_and_the_range():
    """config/examples/cubesat12u/design.yaml: the paper spec's hold margin over the paper's 1-20 s
    (what its gains were tuned for), the 12U's own residual dipole (0.05 A m^2, its simulator
    section) and torquers (0.2 A m^2 -> budget 0.16)."""
    ex = REPO / "config/examples/cubesat12u"
    req = load_requirements(ex / "design.yaml", spacecraft_dipole_limit(ex / "spacecraft.yaml"))
    assert req.sampling == {**Requirements.from_mapping({}, 0.2).sampling, "ts_max": 20.0}
    assert np.allclose(req.dipole["residual_nominal"], 0.05) and req.dipole_budget == pytest.approx(0.16)


def test_held_loop_decay_requirement_against_a_simulated_held_loop(model):
    """The multiplier requirement (sampling.max_multiplier): the paper-method sigma = 240 gain meets
    the hold margin at 30 s (5.1 >= 4) but its held loop decays slowly there; the screen's
    |multiplier| equals the decay per orbit of the held loop integrated independently (scipy's
    solve_ivp on x' = A x + B^T S(b(t)) m, m held over each interval), and the screen rejects it
    at 0.05 while max_multiplier 1 (stability only, the default) accepts it."""
    from scipy.integrate import solve_ivp

    K = load_gains(REPO / "config/gains/paper_method/sigma_240.yaml").K
    req = Requirements.from_mapping({"sampling": {"ts_min": 30.0, "max_multiplier": 0.05},
                                     "dipole": {"budget_fraction": 0}}, 50.0)
    loop = SampledLoop.build(model, 30.0)
    check = [c for c in req.screen(model).checks(K) if c.name.startswith("held-loop |multiplier|")]
    assert len(check) == 1 and not check[0].ok and check[0].limit == 0.05
    rho = check[0].value
    assert 0.05 < rho < 1.0  # slow but stable (measured 0.378)
    loose = Requirements.from_mapping({"sampling": {"ts_min": 30.0, "max_multiplier": 1.0},
                                       "dipole": {"budget_fraction": 0}}, 50.0)
    assert not req.screen(model)(K[None])[0] and loose.screen(model)(K[None])[0]

    h, n = loop.ts, loop.intervals
    x = xd = np.random.default_rng(0).standard_normal(6) * 1e-3
    for k in range(2 * n):  # two orbits: the integrated held loop against the interval maps
        t0 = k * h
        b0 = model.field(np.array([t0]))[0]
        m = skew_field(b0[None])[0].T @ (K @ x) / (b0 @ b0)
        sol = solve_ivp(lambda t, y: model.A @ y + model.BT @ (skew_field(model.field(np.array([t]))[0][None])[0] @ m),
                        (t0, t0 + h), x, rtol=1e-10, atol=1e-16)
        x, xd = sol.y[:, -1], (loop.Ad + loop.Gamma[k % n] @ K) @ xd
    # both are the same held loop to the integrator's tolerance (measured 1e-8 relative)
    np.testing.assert_allclose(x, xd, rtol=1e-6, atol=1e-6 * np.abs(xd).max())
    # the decay per orbit of the maps, by power iteration (renormalized each orbit), is rho: the slowest
    # multiplier is a complex pair, so single-orbit ratios swing (0.28-0.50); the mean over 60 orbits
    # converges as (second / first multiplier)^60
    logs = []
    for _ in range(60):
        for k in range(n):
            xd = (loop.Ad + loop.Gamma[k] @ K) @ xd
        logs.append(np.log(np.linalg.norm(xd)))
        xd = xd / np.linalg.norm(xd)
    assert np.exp(np.mean(logs[10:])) == pytest.approx(rho, rel=0.02)
