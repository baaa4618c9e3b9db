"""The flight modes in the batched simulation (onboard/modes_kernel.py in sim/batch_kernels.closed_loop)
against the Python ModeLogic and the offline numpy mode loop (sim/modes_loop.simulate_modes)."""
import math

import numpy as np
import pytest

from magtune_core.design.gains import load_gains
from magtune_core.design.params import SpacecraftParams
from magtune_core.onboard.modes import MODES, SAFE, Measurements, ModeLogic, ModeParams, ModeState
from magtune_core.onboard.modes_kernel import GUARDS, MODE_CODE, kernel_params, mode_step
from magtune_core.sim.batch import BatchModes, BatchRuns, simulate_batch
from magtune_core.sim.initial import initial_conditions
from magtune_core.sim.modes_loop import simulate_modes
from magtune_core.sim.substeps import Substeps

#: Trajectory equality with the numpy loop: both integrate the same dynamics with the same RK4 steps and the
#: same held dipoles; they differ by the association of a few sums and numpy's BLAS dot products (~1e-16 per
#: step). Over 2.2 orbits through B-dot saturation switches and the capture that stays ~1e-13 in q (measured
#: 3.5e-14); 1e-9 leaves four orders of margin and would still catch a different law or a step off by one.
TOL = 1e-9


def _transitions(mode_codes, ts=1.0):
    """(t, from, to) of a batched run's mode series."""
    k = np.nonzero(mode_codes[1:] != mode_codes[:-1])[0] + 1
    return [(float(i) * ts, MODES[mode_codes[i - 1]], MODES[mode_codes[i]]) for i in k]


def test_kernel_machine_equals_mode_logic_on_random_measurements():
    """Every guard of the machine (stale, frozen, fresh, calm, tumbling, unknown, inside, outside, with and without
    ACQUISITION) and the sticky commanded SAFE on seeded random measurement sequences that cross every
    threshold: same mode and same pending timers as ModeLogic at every step (exact: the same comparisons on
    the same floats)."""
    rng = np.random.default_rng(30)
    for acquisition in (True, False):
        p = ModeParams(detumble_exit_time=20.0, detumble_entry_time=5.0, handover_time=15.0, acquisition_entry_time=8.0,
                       safe_recovery_time=4.0, acquisition=acquisition, frozen_time=6.0, attitude_loss_time=7.0)
        logic, kp = ModeLogic(p), kernel_params(p)
        state, code, pending = ModeState(), MODE_CODE["DETUMBLE"], np.full(len(GUARDS), np.nan)
        seen, frozen_left, unknown_left, fired = set(), 0, 0, set()
        # slowly varying levels (a random walk in log space) so that guards hold for their persistence times
        lr, le, lb = math.log(5e-3), math.log(0.1), math.log(5e-7)
        for k in range(20000):
            t = float(k)
            if rng.uniform() < 0.0005:  # a commanded SAFE (sticky), commanded out again later
                state, _ = logic.request(state, SAFE, t, "test")
                code, pending[:] = MODE_CODE[SAFE], np.nan
            elif state.held and rng.uniform() < 0.02:
                state, _ = logic.request(state, "DETUMBLE", t, "test")
                code, pending[:] = MODE_CODE["DETUMBLE"], np.nan
            lr = min(max(lr + 0.1 * rng.standard_normal(), math.log(1e-3)), math.log(0.2))
            le = min(max(le + 0.1 * rng.standard_normal(), math.log(0.01)), math.log(1.0))
            lb = min(max(lb + 0.1 * rng.standard_normal(), math.log(1e-8)), math.log(1e-5))
            bdot = math.nan if rng.uniform() < 0.005 else math.exp(lb)
            err = math.nan if rng.uniform() < 0.005 else math.exp(le)
            stale = bool(rng.uniform() < 0.002) or (state.mode == SAFE and rng.uniform() < 0.1)
            if frozen_left == 0 and rng.uniform() < 0.003:  # a frozen streak of 1-12 samples
                frozen_left = int(rng.integers(1, 13))
            step = 0.0 if frozen_left else (math.nan if rng.uniform() < 0.01 else 1e-7)
            frozen_left = max(frozen_left - 1, 0)
            if unknown_left == 0 and rng.uniform() < 0.002:  # the estimate not valid for 1-15 samples
                unknown_left = int(rng.integers(1, 16))
            known, unknown_left = unknown_left == 0, max(unknown_left - 1, 0)
            m = Measurements(math.exp(lr), bdot, err, stale, step, known)
            before = state.mode
            state, tr = logic.step(state, m, t)
            code = mode_step(code, pending, m.rate, m.bdot, m.pointing_error, m.stale, t, kp, m.field_step,
                             state.held, m.attitude_known)
            assert MODES[code] == state.mode, k
            held = {g: s for g, s in state.pending}
            assert {GUARDS[i]: pending[i] for i in range(len(GUARDS)) if not math.isnan(pending[i])} == held, k
            seen.add(state.mode)
            if tr is not None:
                fired.add((before, tr.reason.split(" ")[0]))
        assert seen == (set(MODES) if acquisition else set(MODES) - {"ACQUISITION"})
        assert any(r == "magnetometer" for _, r in fired), fired  # the frozen guard fired
        assert any(r == "attitude" for _, r in fired), fired  # the unknown-attitude guard fired


@pytest.fixture(scope="module")
def deployments():
    """Two tumbling deployments flown by the numpy loop and, together, by the batched engine (paper
    environment, perfect sensors, sigma_60, 50 A m^2, the default mode parameters and B-dot rule)."""
    p = SpacecraftParams()
    K = load_gains("config/gains/sigma_60.yaml").K
    cases = [((-100.0, 40.0, 90.0), (-4.0, 2.0, 5.0)), ((150.0, 10.0, -60.0), (5.0, -5.0, 1.0))]
    orbits = 2.2
    refs = [simulate_modes(K, p, q0=q0, dw0=dw0, orbits=orbits) for q0, dw0 in (initial_conditions(*c) for c in cases)]
    assert {r.substeps for r in refs} == {4}  # both rates need 3 RK4 sub-steps (|w| h <= 0.05 rad): the ladder's 4
    for r in refs:  # and both drop to 2 while detumbling: the batch follows the per-step choice
        used = {Substeps(1.0, 2, 4).at(np.r_[q, w]) for q, w in zip(r.q, r.w)}
        assert used == {2, 4}, used
    qs, ws = zip(*[initial_conditions(*c) for c in cases])
    runs = BatchRuns(K=K, inertia=np.tile(p.inertia, (2, 1)), residual_dipole=np.ones((2, 3)), dipole_limit=np.full(2, 50.0),
                     q0=np.array(qs), dw0=np.array(ws), p=p, environment="paper")
    res = simulate_batch(runs, ts=1.0, steps=len(refs[0].t) - 1, substeps=2, max_substeps=4, full_series=True,
                         modes=BatchModes())
    return refs, res


def test_batched_modes_equal_the_numpy_mode_loop(deployments):
    refs, res = deployments
    for b, ref in enumerate(refs):
        # the same transitions, to the sample (integers of Ts: compared exactly)
        assert _transitions(res.mode[b]) == [(tr.t, tr.source, tr.target) for tr in ref.transitions]
        assert [tr.target for tr in ref.transitions] == ["ACQUISITION", "POINTING"]  # a full deployment
        assert res.transitions[b] == 2 and res.detumble_time[b] == ref.transitions[0].t
        assert res.pointing_time[b] == ref.transitions[1].t and MODES[res.final_mode[b]] == "POINTING"
        assert [MODES[c] for c in res.mode[b]] == list(ref.mode)
        # the same trajectory and dipoles (TOL above; the dipole scaled by its 50 A m^2 limit)
        assert np.abs(res.q[b] - ref.q).max() <= TOL and np.abs(res.w[b] - ref.w).max() <= TOL
        assert np.abs(res.m[b] - ref.m).max() <= TOL * 50.0


def test_modes_off_is_the_batch_without_modes(deployments):
    """BatchModes absent: the projection law throughout, bit for bit what simulate_batch computed before
    (tests/sim/test_batch.py checks that against simulate); here: differs from the modes run at once."""
    _, res = deployments
    p = SpacecraftParams()
    K = load_gains("config/gains/sigma_60.yaml").K
    q0, dw0 = initial_conditions((-100.0, 40.0, 90.0), (-4.0, 2.0, 5.0))
    runs = BatchRuns(K=K, inertia=p.inertia[None], residual_dipole=np.ones((1, 3)), dipole_limit=np.full(1, 50.0),
                     q0=q0[None], dw0=dw0[None], p=p, environment="paper")
    off = simulate_batch(runs, ts=1.0, steps=200, substeps=3, full_series=True)
    assert off.mode is None and off.transitions is None
    assert not np.allclose(off.m[0, :200], res.m[0, :200])  # B-dot flew in the modes run, eq. 17 here
