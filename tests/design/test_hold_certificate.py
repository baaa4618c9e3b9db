"""The hold certificate (design/hold_certificate.py): its arithmetic against direct products and the
held loop of design/sampled.py, its grid and periods, that it finds the instability islands of the
gains shipped before it, and every shipped gains file against an independent held-loop scan."""
from pathlib import Path

import numpy as np
import pytest

from magtune_core.design import hold_certificate as hc
from magtune_core.design.fitfield import field_for_spacecraft
from magtune_core.design.gains import Gains, load_gains, save_gains
from magtune_core.design.model import AttitudeLTP
from magtune_core.design.params import SpacecraftParams, load_spacecraft
from magtune_core.design.requirements import claim_contradictions
from magtune_core.design.sampled import SampledLoop
from tests.support.held_scan import held_radii

REPO = Path(__file__).resolve().parents[2]

#: config/gains/sigma_120.yaml as shipped before the certificate (tuned on the margin's two ends): unstable
#: held at Ts = 30.03 s for 3.90-3.995 x K, stable at 4 x K (issue 55).
OLD_SIGMA_120 = np.array([
    0.00018918293173597882, -0.00875654532012588, 0.0027934164457624694, -0.12457865163893872, 0.008199509938723747,
    -0.43170286001837466, 0.010903356004581118, 0.005344288278131479, -0.00024736957576861095, -0.0147213045352408,
    -0.09672992835407475, -0.4275517909944291, -0.004087380202885957, -0.010026222506790168, -0.022143166417210678,
    -0.08981918689086199, 0.014173564978217208, -0.3993525312370993]).reshape(3, 6)


@pytest.fixture(scope="module")
def paper():
    return AttitudeLTP.from_params(SpacecraftParams())


def test_admissible_periods_and_scale_grid(paper):
    """The paper's orbit at 1-30 s: N = round(T / 30) .. round(T / 1), every one; the grid's step <= 0.005."""
    T = paper.period
    ns = hc.admissible_intervals(T, 1.0, 30.0)
    assert ns[0] == round(T / 30.0) == 187 and ns[-1] == round(T / 1.0) == 5615 and np.all(np.diff(ns) == 1)
    assert len(ns) == 5429
    ks = hc.scale_grid(4.0, 0.005, 0.005)
    assert ks[0] == 1.0 and ks[-1] == pytest.approx(4.02, abs=1e-12) and np.diff(ks).max() <= 0.005 + 1e-12
    assert len(hc.scale_grid(4.0, 0.0049, 0.0)) == 614  # ceil(3 / 0.0049) = 613 steps


@pytest.mark.parametrize("ts", [1.0, 7.0, 30.0])
def test_interval_maps_equal_the_held_loop(paper, ts):
    """The certificate's maps (eigendecomposition exponentials) are SampledLoop's (scipy's expm) to
    round-off: 1e-12 of the largest entry (measured 3e-14 for the exponentials, cond(V) ~300)."""
    n = int(round(paper.period / ts))
    Ad, Gamma = hc.interval_maps(paper, n)
    loop = SampledLoop.build(paper, ts)
    np.testing.assert_allclose(Ad, loop.Ad, rtol=0, atol=1e-12 * np.abs(loop.Ad).max())
    np.testing.assert_allclose(Gamma, loop.Gamma, rtol=0, atol=1e-12 * np.abs(loop.Gamma).max())


@pytest.mark.parametrize("ts", [1.0, 3.0, 30.0])
def test_block_products_equal_direct_products(paper, ts):
    """Polynomial blocks in k give the spectral radius of the direct product (SampledLoop's compiled one)
    at every scale: 1e-8 in log rho (measured 3e-12 at 1-3 s, 7e-9 at 30 s where rho reaches 1e4)."""
    loop = SampledLoop.build(paper, ts)
    ks = hc.scale_grid(4.0)[::20]
    ref = loop.spectral_radius(ks[:, None, None] * OLD_SIGMA_120)
    got = hc.scan_products(loop.Ad, loop.Gamma @ OLD_SIGMA_120, ks)
    np.testing.assert_allclose(np.log(got), np.log(ref), rtol=0, atol=1e-8)
    # the norm bound used where rho is far below 1 is an upper bound, never below the true radius
    bound = hc.scan_products(loop.Ad, loop.Gamma @ OLD_SIGMA_120, ks, exact_above=1e300)
    assert np.all(bound[1:] >= ref[1:] * (1 - 1e-9))


def test_certificate_finds_the_islands_of_the_old_gain(paper):
    """The old sigma = 120 gain met the two-ends rule (K and 4 K stable held at every checked period) but
    is unstable held at 30.03 s from 3.90 x K: the certificate must say so, name the period, and its
    unstable points must be unstable by an independent computation."""
    cert = hc.certify_hold(paper, OLD_SIGMA_120, 25.0, 30.0, 4.0)
    assert not cert.met
    assert cert.margin == pytest.approx(3.895, abs=1e-9)  # last stable grid scale before 3.900
    assert cert.periods[cert.tightest] == pytest.approx(paper.period / 187)
    loop = SampledLoop.build(paper, paper.period / 187)
    rho = loop.spectral_radius(np.array([3.85, 3.95, 4.0])[:, None, None] * OLD_SIGMA_120)
    assert rho[0] < 1.0 < rho[1] and rho[2] < 1.0  # an island: stable below, unstable inside, stable at 4
    for t, k in cert.unstable:
        n = int(round(paper.period / t))
        assert held_radii(paper, OLD_SIGMA_120, n, [k])[0] >= 1.0, (t, k)
    # the same gain with the requirement below its first crossing: met, nothing unstable
    low = hc.certify_hold(paper, OLD_SIGMA_120, 25.0, 30.0, 3.85, guard=0.0)
    assert low.met and low.margin == pytest.approx(3.85) and not low.unstable


def test_claims_that_contradict_their_figures():
    base = {"requirements_met": True, "hold_gain_margin_required": 4.0, "hold_margin_min": 4.02,
            "hold_rho_max": 0.07, "hold_certificate": {"periods": 5429}, "dipole_peak_proxy": 12.0, "dipole_budget": 40.0}
    assert claim_contradictions(base) == []
    assert claim_contradictions({**base, "requirements_met": False, "hold_margin_min": 3.0}) == []
    bad = claim_contradictions({**base, "hold_margin_min": 3.898})
    assert len(bad) == 1 and bad[0].startswith("hold_margin_min: 3.898")
    assert claim_contradictions({**base, "hold_rho_max": 80.0})[0].startswith("hold_rho_max")
    assert claim_contradictions({**base, "dipole_peak_proxy": 41.0})[0].startswith("dipole_peak_proxy")
    old = {k: v for k, v in base.items() if k != "hold_certificate"}
    assert claim_contradictions(old)[0].startswith("hold_certificate: missing")


def test_a_contradicted_claim_is_never_written(tmp_path):
    prov = {"requirements_met": True, "hold_gain_margin_required": 4.0, "hold_margin_min": 3.9,
            "hold_certificate": {"periods": 1}}
    with pytest.raises(ValueError, match="hold_margin_min"):
        save_gains(tmp_path / "g.yaml", Gains(OLD_SIGMA_120, 120.0, 1.0, prov))
    assert not (tmp_path / "g.yaml").exists()


#: (gains file, spacecraft file, design field file or None): as each was tuned
SHIPPED = [("config/gains/sigma_60.yaml", "config/spacecraft.yaml", None),
           ("config/gains/sigma_120.yaml", "config/spacecraft.yaml", None),
           ("config/gains/sigma_240.yaml", "config/spacecraft.yaml", None),
           ("config/examples/cubesat12u/gains_sigma120.yaml", "config/examples/cubesat12u/spacecraft.yaml",
            "config/examples/cubesat12u/field_model.yaml")]


@pytest.mark.parametrize("path", [p for p, *_ in SHIPPED] + sorted(
    str(p.relative_to(REPO)) for p in (REPO / "config/gains").rglob("*.yaml") if p.parent.name != "gains"))
def test_no_shipped_file_claims_what_its_figures_contradict(path):
    prov = load_gains(REPO / path).provenance
    assert claim_contradictions(prov) == []
    if path in {p for p, *_ in SHIPPED}:  # the spec-tuned gains carry a met certificate at the stated resolution
        assert prov["requirements_met"] is True
        cert = prov["hold_certificate"]
        assert cert["scale_step"] <= 0.005 and cert["scale_top"] >= 4.0 * 1.005 - 1e-9
        assert prov["hold_margin_min"] >= cert["scale_top"] - 1e-9 and prov["hold_rho_max"] < 1.0
        assert "hold_gain_margin" not in prov  # the margin at ts_min capped at 16 said nothing of the range


def _scan_periods(model, ts_min, ts_max):
    """30, 25 and 20 s (inside the range) and every period between the tuner's 8 check points'
    midpoints near the top of the range, where the islands live: the last 12 admissible N."""
    T = model.period
    ns = set(hc.admissible_intervals(T, ts_min, ts_max)[:12].tolist())
    ns |= {int(round(T / t)) for t in (30.0, 25.0, 20.0) if ts_min <= t <= ts_max}
    checks = np.geomspace(ts_min, ts_max, 8)
    ns |= {int(round(T / np.sqrt(a * b))) for a, b in zip(checks[:-1], checks[1:]) if np.sqrt(a * b) > 5.0}
    return sorted(ns)


@pytest.mark.slow
@pytest.mark.parametrize("path,spacecraft,field", SHIPPED)
def test_independent_scan_agrees_with_the_certificate(path, spacecraft, field):
    """An RK4 held-loop code (tests/support/held_scan.py) scans every shipped gain at k steps of 0.01 on
    [1, 4] at 30, 25 and 20 s, the periods between the tuner's check points above 5 s and the 12 longest
    admissible periods: stable everywhere, as its certificate says."""
    g = load_gains(REPO / path)
    p = load_spacecraft(REPO / spacecraft, warn=False)
    model = AttitudeLTP(p, field_for_spacecraft(REPO / field, p)) if field else AttitudeLTP.from_params(p)
    lo, hi = g.provenance["hold_ts_range"]
    need = g.provenance["hold_gain_margin_required"]
    ks = np.arange(1.0, need + 1e-9, 0.01)
    for n in _scan_periods(model, lo, hi):
        rho = held_radii(model, g.K, n, ks)
        assert rho.max() < 1.0, (path, model.period / n, ks[np.argmax(rho)], rho.max())


def test_constant_field_shortcut_equals_the_products():
    """A constant field repeats one interval map: rho(map)^N, equal to the block products' radius."""
    model = AttitudeLTP.from_params(SpacecraftParams(field_model="constant", constant_field=np.array([2e-5, 1e-5, 1.5e-5])))
    ks = hc.scale_grid(4.0)[::50]
    for n in (200, 1000):
        fast, _ = hc._scan_one(model, n, OLD_SIGMA_120, ks)
        Ad, Gamma = hc.interval_maps(model, n)
        # 1e-9 in log rho: N = 1000 powers of one eigenvalue against 1000 products (round-off of both)
        np.testing.assert_allclose(np.log(fast), np.log(hc.scan_products(Ad, Gamma @ OLD_SIGMA_120, ks)), atol=1e-9)


def test_power_radius_bound_and_exact():
    """rho(P)^n by binary powers: the norm where it proves the radius below the threshold (an upper bound,
    within the non-normality of P^n), the eigenvalues elsewhere; 1e-9 in log rho where exact."""
    rng = np.random.default_rng(3)
    P = rng.normal(size=(6, 6, 6)) * np.array([0.1, 0.2, 0.3, 0.16, 0.18, 0.5])[:, None, None]
    exact = np.abs(np.linalg.eigvals(P)).max(axis=-1) ** 37
    got = hc._power_radius(P, 37, 1e-2)
    assert got[0] == pytest.approx(exact[0], rel=1e-9)
    assert np.all(got >= exact * (1 - 1e-9))
    loose = hc._power_radius(P, 37, 0.0)  # every radius exact
    np.testing.assert_allclose(loose, exact, rtol=1e-9)


def _old_file(tmp_path):
    """The old sigma = 120 gain as a gains file of its day: requirements_met without a certificate."""
    prov = {"requirements_met": True, "hold_gain_margin_required": 4.0, "hold_gain_margin": 16.0,
            "hold_margin_min": 3.898, "hold_tightest_ts": 30.0257, "dipole_peak_proxy": 12.135, "dipole_budget": 40.0}
    path = tmp_path / "old120.yaml"
    text = (REPO / "config/gains/sigma_120.yaml").read_text().split("/**:")[0]  # the header comments
    path.write_text(text + "/**:\n  ros__parameters:\n    gain: [" + ", ".join(repr(float(v)) for v in OLD_SIGMA_120.ravel())
                    + "]\n    sigma: 120.0\n    ts: 1.0\n" + "".join(f"    {k}: {v}\n" for k, v in prov.items()))
    spec = tmp_path / "spec.yaml"
    spec.write_text("sampling: {ts_min: 25.0, ts_max: 30.0}\n")  # the islands' end of the range: 39 periods
    return path, spec


def test_analyze_exits_3_on_a_contradicted_claim_and_records_the_certificate(tmp_path, capsys):
    from magtune_core.cli import main

    path, spec = _old_file(tmp_path)
    before = path.read_text()
    assert main(["analyze", str(path), "--requirements", "--spec", str(spec)]) == 3
    out = capsys.readouterr().out
    assert "hold margin: FAILS: stable up to 3.895 x K only" in out
    assert "contradicted by hold_certificate: missing" in out and "contradicted by hold_margin_min: 3.898" in out
    assert path.read_text() == before  # nothing written without --record
    png = tmp_path / "m.png"
    assert main(["analyze", str(path), "--requirements", "--spec", str(spec), "--record", "--margin-plot", str(png)]) == 3
    capsys.readouterr()
    prov = load_gains(path).provenance
    assert prov["requirements_met"] is False and prov["hold_margin_min"] == pytest.approx(3.895)
    assert "hold_gain_margin" not in prov and prov["hold_certificate"]["periods"] == 39  # N = 187 .. 225
    assert claim_contradictions(prov) == [] and png.stat().st_size > 10000
    assert load_gains(path).K == pytest.approx(OLD_SIGMA_120)  # the gain itself untouched
    assert path.read_text().splitlines()[2] == before.splitlines()[2]  # and its header


@pytest.mark.parametrize("argv, name", [
    (["--record"], "--record"), (["--margin-plot", "x.png"], "--margin-plot"),
])
def test_record_and_plot_need_requirements(tmp_path, capsys, argv, name):
    from tests.support.cli_errors import one_line_exit2

    assert name in one_line_exit2(capsys, ["analyze", "config/gains/sigma_60.yaml", *argv])


def test_an_existing_margin_plot_is_kept(tmp_path, capsys):
    from tests.support.cli_errors import one_line_exit2

    png = tmp_path / "m.png"
    png.write_bytes(b"mine")
    assert str(png) in one_line_exit2(capsys, ["analyze", "config/gains/sigma_60.yaml", "--requirements",
                                               "--margin-plot", str(png)])
    assert png.read_bytes() == b"mine"
