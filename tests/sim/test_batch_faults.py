"""Injected faults in the batched simulation (sim/fault_kernels.py in sim/batch_kernels.closed_loop) against the
offline numpy mode loop (sim/modes_loop.simulate_modes) with the same faults."""
import numpy as np
import pytest

from magtune_core.design.gains import load_gains
from magtune_core.design.params import SpacecraftParams
from magtune_core.onboard.modes import MODES, POINTING, ModeParams
from magtune_core.sim.batch import BatchModes, BatchRuns, simulate_batch
from magtune_core.sim.fault_kernels import NOT_BATCHED, kernel_faults
from magtune_core.sim.modes_loop import simulate_modes

#: As tests/sim/test_batch_modes.py: the same dynamics, RK4 steps and held dipoles, differing by the association
#: of a few sums (~1e-16 per step); 1e-9 would still catch a fault applied a step early or on the wrong axis.
TOL = 1e-9
#: One run per fault list, each from POINTING (paper environment, perfect sensors): every batched kind, on
#: different axes, with and without an end.
CASES = (("torquer_dead@300,axis=y",), ("torquer_stuck@250,axis=x", "mag_spike@400,axis=z,value=2e-4"),
         ("torquer_reversed@200:300,axis=z", "gyro_bias@350,axis=x,value=0.002"),
         ("torquer_gain@100,axis=x,value=0.5", "mag_bias@500:200,axis=y,value=3e-5", "torquer_stuck@600,axis=y,value=3.0"))


@pytest.mark.parametrize("faults", CASES, ids=lambda c: "+".join(f.split("@")[0] for f in c))
def test_batched_faults_equal_the_numpy_mode_loop(faults):
    """Same modes at every step and the same trajectory (TOL) as simulate_modes flying the same faults; and the
    faults do act (the trajectory differs from the fault-free batch by far more than TOL)."""
    p = SpacecraftParams()
    K = load_gains("config/gains/sigma_60.yaml").K
    q0, dw0 = (1.0, 0.0, 0.0, 0.0), (1e-3, 2e-3, 0.0)
    orbits = 1000.0 / p.orbit_period
    mp = ModeParams()
    ref = simulate_modes(K, p, q0=q0, dw0=dw0, orbits=orbits, initial_mode=POINTING, faults=faults, mode_params=mp)
    runs = BatchRuns(K=K, inertia=p.inertia[None], residual_dipole=np.ones((1, 3)), dipole_limit=np.full(1, 50.0),
                     q0=np.array([q0]), dw0=np.array([dw0]), p=p, environment="paper")
    kw = dict(ts=1.0, steps=len(ref.t) - 1, substeps=ref.substeps, full_series=True,
              modes=BatchModes(mp, initial_mode=POINTING))
    res = simulate_batch(runs, faults=faults, **kw)
    clean = simulate_batch(runs, **kw)
    assert [MODES[c] for c in res.mode[0]] == list(ref.mode)
    assert np.abs(res.q[0] - ref.q).max() <= TOL and np.abs(res.w[0] - ref.w).max() <= TOL
    assert np.abs(res.w[0] - clean.w[0]).max() > 1e3 * TOL


def test_kinds_the_batch_does_not_fly_are_named():
    """mag_stuck, mag_dropout and sensors_killed need the SIL's or the offline loop's memory: refused, named."""
    assert set(NOT_BATCHED) == {"mag_stuck", "mag_dropout", "sensors_killed"}
    with pytest.raises(ValueError, match="mag_dropout is flown by magtune sil"):
        kernel_faults(["mag_dropout@10:5"], 1.0)


def test_campaign_faults_section(tmp_path):
    """A campaign's faults section: flown by every run (kept in the spec, the spec strings in campaign.json); a kind
    the batch does not fly is one line naming the entry's kind field; a fault after the run's end is refused."""
    from magtune_core.base.errors import ConfigError
    from magtune_core.studies.campaign import load_spec

    head = ("campaign:\n  name: t\n  seed: 1\n  gains: config/gains/sigma_60.yaml\n  spacecraft: config/spacecraft.yaml\n"
            "  environment: paper\n  orbits: 1\n")
    spec = tmp_path / "c.yaml"
    spec.write_text(head + "faults:\n  - torquer_reversed@1000,axis=z\n  - {kind: mag_bias, t: 2000, axis: y, value: 2.0e-6}\n")
    s = load_spec(spec)
    assert [f.spec for f in s.faults] == ["torquer_reversed@1000.0,axis=z", "mag_bias@2000.0,axis=y,value=2e-06"]
    spec.write_text(head + "faults:\n  - mag_dropout@100:5\n")
    with pytest.raises(ConfigError, match=r"faults\[0\]\.kind.*mag_dropout is flown by magtune sil"):
        load_spec(spec)
    spec.write_text(head + "faults:\n  - gyro_bias@9000\n")
    with pytest.raises(ConfigError, match="at or after the end of the run"):
        load_spec(spec)
