"""Phase 1 (design/feasibility.py): the requirements' violation is zero exactly where the screen
says feasible, and CMA-ES on it turns the LQ start, which no scaling makes feasible under a
1-30 s spec with a decay bound, into a feasible start."""
from __future__ import annotations

import numpy as np
import pytest

from magtune_core.design.feasibility import restore, violation
from magtune_core.design.model import AttitudeLTP
from magtune_core.design.params import SpacecraftParams
from magtune_core.design.pipeline import start_gain
from magtune_core.design.requirements import Requirements
from magtune_core.design.sampled import feasible_start


@pytest.fixture(scope="module")
def setup():
    model = AttitudeLTP.from_params(SpacecraftParams())
    # the defaults (margin 4 over 1-30 s, 40 A m^2) with the held loop decaying 20x per orbit: scaling the
    # LQ start down buys margin but slows the decay, so no scaling meets both at 30 s
    req = Requirements.from_mapping({"sampling": {"max_multiplier": 0.05}}, 50.0)
    return model, req, req.screen(model), start_gain(model, 60.0)[0]


def test_violation_is_zero_exactly_where_the_screen_accepts(setup):
    model, req, screen, K0 = setup
    rng = np.random.default_rng(0)
    # gains around the LQ start, scaled 0.2-2x with 30 % entry noise: both sides of every requirement
    Ks = K0 * rng.uniform(0.2, 2.0, (40, 1, 1)) * (1 + 0.3 * rng.standard_normal((40, 3, 6)))
    v, ok = violation(screen, Ks), screen(Ks)
    assert ok.any() or (v > 0).all()
    np.testing.assert_array_equal(v == 0, ok)
    # and each violated requirement shows in checks(): a gain with v > 0 fails at least one check
    for K in Ks[v > 0][:5]:
        assert not all(c.ok for c in screen.checks(K))


def test_phase_1_finds_a_feasible_start_where_no_scaling_does(setup):
    model, req, screen, K0 = setup
    assert violation(screen, K0[None])[0] > 0
    with pytest.raises(ValueError, match="no scaling of the start gain"):
        feasible_start(model, K0, req)
    K, evals = restore([screen], K0, seed=0)
    assert K is not None and screen(K[None])[0] and violation(screen, K[None])[0] == 0
    assert evals <= 4000
    assert all(c.ok for c in screen.checks(K))
