"""Tuning and analysis as library calls (magtune_core.design.pipeline): what `magtune tune` and
`magtune analyze` run, without argparse."""
from __future__ import annotations

import numpy as np
import pytest

from magtune_core.base.ament import ROOT
from magtune_core.design.gains import Gains, load_gains
from magtune_core.design.model import AttitudeLTP
from magtune_core.design.params import SpacecraftParams
from magtune_core.design.pipeline import InfeasibleStart, analyze_gains, tune_gains
from magtune_core.design.problem import figures
from magtune_core.design.tuner import TunerSettings

MODEL = AttitudeLTP.from_params(SpacecraftParams())


def test_tune_gains_returns_gains_with_their_provenance():
    out = tune_gains(MODEL, 120.0, method="paper", seed=1, ts=2.0, paper=TunerSettings(samples=20, max_iter=2))
    g = out.gains
    assert isinstance(g, Gains) and g.sigma == 120.0 and g.ts == 2.0 and np.array_equal(g.K, out.result.K)
    # the provenance's figures are the gain's, at the analysis resolution (recomputed independently here)
    ref = figures(MODEL, g.K, 120.0, steps=out.analysis_steps)
    assert g.provenance["J"] == ref.J and g.provenance["c2"] == ref.c2
    assert g.provenance["J"] <= out.result.J0 * (1 + 1e-3)  # the search never ends above its start (1e-3: steps)
    assert g.provenance["start"] == "LQ start" and g.provenance["method"] == "paper"
    assert out.state == "NOT certified (budget reached)" and not out.interrupted


def test_analyze_gains_reproduces_the_shipped_figures():
    g = load_gains(ROOT / "config" / "gains" / "sigma_60.yaml")
    # at the file's own analysis steps: equal to the norm's accuracy (figures' rtol 1e-7; measured 1.5e-8)
    a = analyze_gains(MODEL, g, steps=int(g.provenance["analysis_steps"]))
    assert a.steps == g.provenance["analysis_steps"] and a.figures.J == pytest.approx(g.provenance["J"], rel=1e-7)
    # at the default resolution: within the resolution rule's 1e-3 (doubling until J agrees to it)
    d = analyze_gains(MODEL, g)
    assert d.figures.J == pytest.approx(g.provenance["J"], rel=1e-3) and d.figures.stable
    # the first crossing at the file's Ts (hold_gain_margin's 1e-3 accuracy) lies above the certified [1, 4.02]
    assert d.hold_gain_margin >= g.provenance["hold_certificate"]["scale_top"] * (1 - 1e-3) and d.sensitivity is None


def test_infeasible_start_is_its_own_error():
    # the J-alone optimum, unstable held at 20 s even scaled down 100x (feasible_start's range)
    K = load_gains(ROOT / "config" / "gains" / "unconstrained" / "sigma_60.yaml").K * 40.0
    with pytest.raises(InfeasibleStart):
        tune_gains(MODEL, 60.0, start_K=K, ts=20.0, gain_margin=2.0)
