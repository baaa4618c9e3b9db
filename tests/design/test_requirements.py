"""The design spec (design/requirements.py): validation, the checked sample periods against a
dense scan, and an infeasible requirement set named correctly by the tuner."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from magtune_core.base.errors import ConfigError
from magtune_core.design.gains import load_gains
from magtune_core.design.model import AttitudeLTP
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
    screen (8 periods) says feasible exactly where a 150-period scan of [1, 20] s does; this is
    what makes 8 periods enough for these loops (the pipeline's 96-period scan is the guard)."""
    req = Requirements.from_mapping({"dipole": {"budget_fraction": 0}}, 50.0)
    screen = req.screen(model)
    K = load_gains(REPO / "config/gains/paper_method/sigma_60.yaml").K
    factors = np.geomspace(0.5, 4.0, 6)  # its margin at 20 s is 3.84: 2 x factor crosses it
    fast = screen(factors[:, None, None] * K)
    dense = np.array([scan_hold(model, f * K, req, points=150)[1].all() for f in factors])
    assert fast.any() and not fast.all()  # the family crosses the boundary
    np.testing.assert_array_equal(fast, dense)


def test_scan_uses_the_implemented_intervals(model):
    req = Requirements.from_mapping({}, 50.0)
    ts, ok = scan_hold(model, np.zeros((3, 6)), req, points=5)
    T = model.period
    np.testing.assert_allclose(ts, [T / round(T / t) for t in np.geomspace(1.0, 20.0, 5)])
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


def test_example_12u_spec_overrides_only_the_residual_dipole():
    """config/examples/cubesat12u/design.yaml: the paper spec's hold requirement, the 12U's own
    residual dipole (0.05 A m^2, its simulator section) and torquers (0.2 A m^2 -> budget 0.16)."""
    ex = REPO / "config/examples/cubesat12u"
    req = load_requirements(ex / "design.yaml", spacecraft_dipole_limit(ex / "spacecraft.yaml"))
    assert req.sampling == Requirements.from_mapping({}, 0.2).sampling
    assert np.allclose(req.dipole["residual_nominal"], 0.05) and req.dipole_budget == pytest.approx(0.16)
