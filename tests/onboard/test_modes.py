"""The mode machine (magtune_core.onboard.modes) on scripted measurement sequences: persistence,
hysteresis, SAFE on stale sensors and its recovery, the reasons, and the one schema's errors."""
import math
from dataclasses import replace

import pytest

from magtune_core.base.errors import ConfigError
from magtune_core.onboard.modes import ACQUISITION, DETUMBLE, POINTING, SAFE, Measurements, ModeLogic, ModeParams, ModeState
from magtune_core.onboard.params import MODE_FIELDS

P = ModeParams(detumble_exit_rate=4e-3, detumble_exit_time=100.0, detumble_entry_rate=8e-3, detumble_entry_time=20.0, acquisition_abort_rate=1.2e-2,
               handover_angle=0.1, handover_time=50.0, acquisition_entry_angle=0.3, acquisition_entry_time=30.0,
               safe_recovery_time=10.0, detumble_exit_bdot=5e-7)


def fly(logic, state, script, t0=0.0, dt=1.0):
    """Feed ``script`` (a list of Measurements, one per dt) and collect the transitions."""
    out, t = [], t0
    for m in script:
        state, tr = logic.step(state, m, t)
        if tr is not None:
            out.append(tr)
        t += dt
    return state, out, t


def test_defaults_are_the_schema_s():
    assert ModeParams() == ModeParams.from_mapping({})
    assert {f.name for f in MODE_FIELDS} == set(ModeParams.__dataclass_fields__)


def test_detumble_exit_needs_persistence_and_a_calm_bdot():
    logic = ModeLogic(P)
    calm = Measurements(rate=3e-3, bdot=1e-7)
    # 99 s calm, one spike above the exit rate (not above the entry rate) resets the timer
    state, trs, t = fly(logic, ModeState(), [calm] * 99 + [Measurements(rate=5e-3, bdot=1e-7)] + [calm] * 101)
    assert [(tr.target, tr.t) for tr in trs] == [(ACQUISITION, 100.0 + 100.0)]  # timer restarted at 100 s
    assert "|w| < 0.004 rad/s" in trs[0].reason and "100 s" in trs[0].reason
    # a slow rate with a large |db/dt| is not calm (the field still turns fast in the body)
    state, trs, _ = fly(logic, ModeState(), [Measurements(rate=3e-3, bdot=1e-6)] * 300)
    assert trs == [] and state.mode == DETUMBLE
    # no field derivative (nan): the rate guard alone decides, after exactly the persistence time
    _, trs, _ = fly(logic, ModeState(), [Measurements(rate=3e-3)] * 101)
    assert [tr.t for tr in trs] == [100.0]


def test_hysteresis_between_the_rate_thresholds():
    """In POINTING a rate between the exit (4e-3) and the entry (8e-3) threshold changes nothing;
    above the entry threshold for 20 s it goes back to DETUMBLE. ACQUISITION tolerates up to its
    abort rate (1.2e-2 here: the capture transient)."""
    logic = ModeLogic(P)
    s0 = ModeState(POINTING, 0.0, "test")
    state, trs, t = fly(logic, s0, [Measurements(rate=7e-3, pointing_error=0.01)] * 500)
    assert trs == [] and state.mode == POINTING
    state, trs, _ = fly(logic, state, [Measurements(rate=9e-3, pointing_error=0.01)] * 19
                        + [Measurements(rate=7e-3, pointing_error=0.01)]
                        + [Measurements(rate=9e-3, pointing_error=0.01)] * 21, t0=t)
    assert [(tr.source, tr.target, tr.t - t) for tr in trs] == [(POINTING, DETUMBLE, 40.0)]
    assert trs[0].reason == "|w| > 0.008 rad/s for 20 s"
    state, trs, _ = fly(logic, ModeState(ACQUISITION, 0.0, "test"), [Measurements(rate=1.1e-2, pointing_error=1.0)] * 300)
    assert trs == [] and state.mode == ACQUISITION
    state, trs, _ = fly(logic, state, [Measurements(rate=1.3e-2, pointing_error=1.0)] * 21, t0=300.0)
    assert [(tr.target, tr.t) for tr in trs] == [(DETUMBLE, 320.0)]


def test_handover_and_fallback_by_pointing_error():
    logic = ModeLogic(P)
    s0 = ModeState(ACQUISITION, 0.0, "test")
    m_in, m_mid, m_out = (Measurements(rate=1e-3, pointing_error=e) for e in (0.05, 0.2, 0.5))
    state, trs, t = fly(logic, s0, [m_in] * 51)
    assert [(tr.target, tr.t) for tr in trs] == [(POINTING, 50.0)] and state.since == 50.0
    # between the hand-over (0.1) and the fall-back (0.3) angle: stays in POINTING
    state, trs, t = fly(logic, state, [m_mid] * 200, t0=t)
    assert trs == [] and state.mode == POINTING
    state, trs, _ = fly(logic, state, [m_out] * 31, t0=t)
    assert [(tr.target, tr.t - t) for tr in trs] == [(ACQUISITION, 30.0)]
    # no attitude estimate (nan): never hands over
    state, trs, _ = fly(logic, s0, [Measurements(rate=1e-3)] * 300)
    assert trs == [] and state.mode == ACQUISITION


def test_without_acquisition_detumble_goes_to_pointing():
    logic = ModeLogic(ModeParams(acquisition=False, detumble_exit_time=0.0))
    state, trs, _ = fly(logic, ModeState(), [Measurements(rate=1e-3, bdot=1e-8, pointing_error=2.0)] * 10)
    assert [tr.target for tr in trs] == [POINTING] and state.mode == POINTING  # no fall-back without acquisition


@pytest.mark.parametrize("rate, known, target", [(1e-3, True, ACQUISITION), (1e-2, True, DETUMBLE),
                                                  (1e-3, False, DETUMBLE)])
def test_stale_sensors_go_safe_at_once_and_recover(rate, known, target):
    """SAFE at once on stale data; fresh for safe_recovery_time -> ACQUISITION when the body is calm (|w| below
    detumble_exit_rate) and the attitude valid at that instant (a short outage: nothing to detumble), else
    DETUMBLE."""
    logic = ModeLogic(P)
    good = Measurements(rate=rate, pointing_error=0.01, attitude_known=known)
    state, trs, t = fly(logic, ModeState(POINTING, 0.0, "test"),
                        [Measurements(rate=1e-3, pointing_error=0.01)] * 5 + [Measurements(rate=math.nan, stale=True)] * 30)
    assert [(tr.target, tr.t, tr.reason) for tr in trs] == [(SAFE, 5.0, "sensor data stale")]
    # fresh again, but a stale blip at 5 s restarts the recovery timer
    state, trs, t2 = fly(logic, state, [good] * 5 + [Measurements(rate=1e-3, stale=True)] + [good] * 11, t0=t)
    assert [(tr.source, tr.target, tr.t - t) for tr in trs] == [(SAFE, target, 16.0)]
    assert "fresh for 10 s" in trs[0].reason and (("attitude valid" in trs[0].reason) == (target == ACQUISITION))
    no_acq = ModeLogic(replace(P, acquisition=False))  # without ACQUISITION a calm recovery goes to POINTING
    state, _ = no_acq.request(ModeState(POINTING, 0.0, "test"), SAFE, 0.0, "stale", hold=False)
    _, trs, _ = fly(no_acq, state, [good] * 11, t0=1.0)
    assert [tr.target for tr in trs] == [POINTING if target == ACQUISITION else DETUMBLE]


def test_request_and_bad_values():
    logic = ModeLogic(P)
    state, tr = logic.request(ModeState(), SAFE, 3.0, "operator")
    assert (state.mode, tr.source, tr.reason) == (SAFE, DETUMBLE, "operator")
    with pytest.raises(ConfigError, match="field 'mode'"):
        logic.request(state, "SLEEP", 3.0)
    with pytest.raises(ConfigError, match=r"mode parameters: field 'detumble_exit_rate': expected a number in"):
        ModeParams.from_mapping({"detumble_exit_rate": 5.0})
    with pytest.raises(ConfigError, match="field 'detumble_entry_rate': expected more than detumble_exit_rate"):
        ModeParams.from_mapping({"detumble_entry_rate": 1e-3})
    with pytest.raises(ConfigError, match="field 'acquisition_entry_angle'"):
        ModeParams.from_mapping({"handover_angle": 0.5})
    with pytest.raises(ConfigError, match="field 'handover_time': expected a finite number"):
        ModeParams.from_mapping({"handover_time": "long"})


def test_commanded_safe_is_sticky_and_a_lost_heartbeat_is_not():
    """A commanded SAFE (set_mode) stays while the sensors are fresh, until another mode is commanded
    (docs/decisions.md); the manager's own SAFE on a lost heartbeat (hold=False) recovers as a stale one."""
    logic = ModeLogic(P)
    good = Measurements(rate=1e-3, pointing_error=0.01, field_step=1e-8)
    state, _ = logic.request(ModeState(POINTING, 0.0, "test"), SAFE, 5.0, "commanded: operator")
    assert state.held
    state, trs, t = fly(logic, state, [good] * 1000, t0=6.0)
    assert trs == [] and state.mode == SAFE
    state, tr = logic.request(state, DETUMBLE, t, "commanded: out of safe")
    assert not state.held and tr.source == SAFE
    state, _ = logic.request(ModeState(POINTING, 0.0, "test"), SAFE, 5.0, "heartbeat lost", hold=False)
    _, trs, _ = fly(logic, state, [good] * 11, t0=6.0)
    assert [(tr.target, tr.t) for tr in trs] == [(ACQUISITION, 16.0)]  # calm and the attitude valid


def test_frozen_magnetometer_goes_safe_after_its_persistence():
    """field_step == 0 (the sample repeated bit for bit) for frozen_time -> SAFE; a moving sample restarts the
    timer; nan (no previous sample) is never frozen; in SAFE a frozen sample is not fresh."""
    logic = ModeLogic(ModeParams(frozen_time=5.0))
    frozen, moving = (Measurements(rate=1e-3, pointing_error=0.01, field_step=s) for s in (0.0, 1e-9))
    s0 = ModeState(POINTING, 0.0, "test")
    _, trs, _ = fly(logic, s0, [frozen] * 4 + [moving] + [frozen] * 6)
    assert [(tr.target, tr.t) for tr in trs] == [(SAFE, 10.0)]
    assert trs[0].reason == "magnetometer frozen (sample repeated) for 5 s"
    _, trs, _ = fly(logic, s0, [Measurements(rate=1e-3, pointing_error=0.01)] * 20)
    assert trs == []
    state, _ = logic.request(s0, SAFE, 0.0, "x", hold=False)
    _, trs, _ = fly(logic, state, [frozen] * 30)
    assert trs == []


def test_the_compiled_twin_refuses_a_field_it_lacks():
    """kernel_params copies ModeParams by name: a field added on one side only must fail loudly (the
    compiled mode machine would otherwise ignore a new threshold while the Python one used it)."""
    from dataclasses import dataclass

    from magtune_core.onboard.modes_kernel import kernel_params

    kernel_params(ModeParams())  # the shipped pair matches

    @dataclass(frozen=True)
    class Extended(ModeParams):
        new_threshold: float = 1.0

    with pytest.raises(ValueError, match="new_threshold"):
        kernel_params(Extended())


def test_an_attitude_not_known_holds_detumble_and_leaves_pointing_after_its_persistence():
    """The full stack's estimate validity (Measurements.attitude_known): DETUMBLE ends only after
    detumble_exit_time of calm *and* a valid estimate; ACQUISITION and POINTING fall back to DETUMBLE
    (B-dot needs no attitude) after attitude_loss_time without one, and a short gap is ridden through."""
    p = ModeParams(**{**P.__dict__, "attitude_loss_time": 40.0})
    logic = ModeLogic(p)
    unknown = Measurements(rate=3e-3, bdot=1e-7, attitude_known=False)
    calm = Measurements(rate=3e-3, bdot=1e-7, pointing_error=0.05)
    state, trs, t = fly(logic, ModeState(), [unknown] * 300 + [calm] * 101)
    assert [(tr.target, tr.t) for tr in trs] == [(ACQUISITION, 400.0)]  # the calm timer starts at 300 s
    assert "attitude valid" in trs[0].reason
    for mode in (ACQUISITION, POINTING):
        gap = Measurements(rate=3e-3, bdot=1e-7, attitude_known=False)
        state, trs, _ = fly(logic, ModeState(mode), [gap] * 39 + [calm] + [gap] * 41)
        assert [(tr.target, tr.t) for tr in trs] == [(DETUMBLE, 80.0)], (mode, trs)
        assert trs[0].reason == "attitude estimate not valid for 40 s"
