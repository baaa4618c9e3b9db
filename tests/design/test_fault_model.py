"""The fault model (magtune_core.design.faults): the one schema and its two spellings, and what each
fault does to a sample or a dipole."""
import math

import numpy as np
import pytest

from magtune_core.base.errors import ConfigError
from magtune_core.design import faults as fl


def test_spec_and_mapping_are_one_schema():
    f = fl.parse_spec("mag_dropout@3000:30")
    assert f == fl.from_mapping({"kind": "mag_dropout", "t": 3000, "duration": 30})
    assert (f.kind, f.t, f.duration) == ("mag_dropout", 3000.0, 30.0)
    g = fl.parse_spec("gyro_bias@100.5,axis=z,value=0.02")
    assert (g.axis, g.value, g.duration) == (2, 0.02, math.inf)
    for spec in ("mag_stuck@10", "mag_spike@7,axis=y", "mag_bias@1:2,value=-1e-05", "torquer_dead@0,axis=z",
                 "torquer_stuck@5,axis=x", "torquer_stuck@5,axis=y,value=3.5", "sensors_killed@200"):
        f = fl.parse_spec(spec)
        assert fl.parse_spec(f.spec) == f, spec  # the nodes get the canonical spelling and read it back
    assert fl.parse_spec("mag_spike@7").value == 5e-4 and math.isnan(fl.parse_spec("torquer_stuck@5").value)
    assert fl.kill_time([fl.parse_spec(s) for s in ("mag_stuck@1", "sensors_killed@9", "sensors_killed@4")]) == 4.0
    with pytest.raises(ConfigError, match="overlaps sensors_killed@9.0"):  # a second kill of a dead process: refused
        fl.from_list(["mag_stuck@1", "sensors_killed@9", "sensors_killed@4"])


@pytest.mark.parametrize("spec, words", [
    ("mag_stuk@10", "field 'kind': expected one of mag_stuck"),
    ("mag_dropout@10", "field 'duration': required for mag_dropout"),
    ("mag_spike@10:5", "field 'duration': mag_spike takes no duration"),
    ("mag_bias@-1", "field 't': expected a non-negative number"),
    ("mag_bias@1,value=0.5", "field 'value': expected a nonzero number within +-0.001 T"),
    ("gyro_bias@1,axis=w", "field 'axis': expected one of x, y, z"),
    ("torquer_dead@1,value=2", "field 'value': torquer_dead takes no value"),
    ("mag_stuck@1,axis=x", "field 'axis': mag_stuck takes no axis"),
    ("gyro_bias@1,gain=2", "field 'gain': unknown parameter"),
    ("gyro_bias@soon", "field 't': expected a number, got 'soon'"),
    ("gyro_bias", "expected KIND@T[:DURATION]"),
])
def test_bad_specs_name_the_field(spec, words):
    with pytest.raises(ConfigError, match=None) as exc:
        fl.parse_spec(spec)
    assert words in str(exc.value) and str(exc.value).startswith(f"--fault {spec}: "), str(exc.value)


def test_measure_each_sensor_fault():
    b, w = np.array([2e-5, -1e-5, 3e-5]), np.array([0.0, 0.0, -1.1e-3])
    st = fl.FaultState()
    faults = fl.from_list(["mag_bias@10,axis=y,value=1e-6", "mag_spike@20,axis=z", "gyro_bias@10,axis=x,value=0.01",
                           "mag_stuck@30:5", "mag_dropout@40:2"])
    bo, wo, st = fl.measure(faults, 9.0, 1.0, b, w, st)
    assert np.array_equal(bo, b) and np.array_equal(wo, w)  # before every onset: the inputs bit for bit
    bo, wo, st = fl.measure(faults, 10.0, 1.0, b, w, st)
    assert np.array_equal(bo, b + [0.0, 1e-6, 0.0]) and np.array_equal(wo, w + [0.01, 0.0, 0.0])
    bo, _, st = fl.measure(faults, 20.0, 1.0, b, w, st)
    assert bo[2] == b[2] + 5e-4  # the spike: one sample [20, 21)
    bo, _, st = fl.measure(faults, 21.0, 1.0, b, w, st)
    assert bo[2] == b[2]
    bo29, _, st = fl.measure(faults, 29.0, 1.0, b * 2, w, st)
    for t in (30.0, 32.0, 34.0):  # stuck: the sample before 30 s, whatever the field does
        bo, _, st = fl.measure(faults, t, 1.0, b * t, w, st)
        assert np.array_equal(bo, bo29)
    bo, _, st = fl.measure(faults, 35.0, 1.0, b, w, st)
    assert not np.array_equal(bo, bo29)
    assert fl.measure(faults, 40.0, 1.0, b, w, st)[0] is None and fl.measure(faults, 41.5, 1.0, b, w, st)[0] is None
    assert fl.measure(faults, 42.0, 1.0, b, w, st)[0] is not None


def test_actuate_dead_and_stuck_torquers():
    st = fl.FaultState()
    faults = fl.from_list(["torquer_dead@10,axis=x", "torquer_stuck@10,axis=z", "torquer_stuck@20:5,axis=y,value=7"])
    m, st = fl.actuate(faults, 9.0, [1.0, 2.0, 3.0], st)
    assert m.tolist() == [1.0, 2.0, 3.0]
    for t in (10.0, 11.0, 15.0):
        m, st = fl.actuate(faults, t, [4.0, 5.0, 6.0 + t], st)
        assert m.tolist() == [0.0, 5.0, 3.0]  # x dead, z holds its dipole of the step before 10 s
    m, st = fl.actuate(faults, 20.0, [4.0, 5.0, 6.0], st)
    assert m.tolist() == [0.0, 7.0, 3.0]


def test_run_end_counts_steps_as_the_simulator():
    assert fl.run_end(1.0, steps=100) == 100.0
    assert fl.run_end(2.0, orbits=1.0, period=5.0) == 4.0  # int(round(2.5)) = 2 steps, as the simulator node
    assert fl.run_end(0.5, orbits=0.01, period=5677.0) == 57.0  # round(113.54) = 114 steps of 0.5 s


def test_a_fault_after_the_end_of_the_run_is_refused():
    """Issue 45: ``--fault mag_dropout@99999:30 --steps 100`` was accepted and the run said nothing of it."""
    end = fl.run_end(1.0, steps=100)
    fl.check_times(fl.from_list(["mag_dropout@99:30", "mag_bias@0", "torquer_dead@99.5,axis=x"]), end)  # fine
    for spec in ("mag_dropout@99999:30", "gyro_bias@100,axis=z"):
        with pytest.raises(ConfigError) as exc:
            fl.check_times(fl.from_list(["mag_bias@3", spec]), end, "--fault")
        msg = str(exc.value)
        assert msg.startswith(f"--fault {fl.parse_spec(spec).spec}: field 't': the fault starts at ")
        assert "at or after the end of the run (100 s)" in msg and "\n" not in msg, msg


def test_sil_fault_check_refuses_a_fault_after_the_end_before_any_node():
    """The SIL's fault check (ros.scenario.check_fault_arguments) with the run's length: by steps, by
    orbits (the simulator's rounding), several satellites (the longest run), a length it leaves to
    check_run_arguments."""
    from magtune_core.ros.scenario import check_fault_arguments

    late = ["mag_dropout@99999:30"]
    with pytest.raises(ConfigError, match=r"^--fault mag_dropout@99999.0:30.0: field 't': .* end of the run \(100 s\)"):
        check_fault_arguments(late, False, steps=100, ts=(1.0,))
    with pytest.raises(ConfigError, match=r"end of the run \(5677 s\)"):
        check_fault_arguments(late, False, orbits=1.0, period=5677.0, ts=(1.0,))
    with pytest.raises(ConfigError, match=r"end of the run \(200 s\)"):  # two satellites: 100 x 1 s, 100 x 2 s
        check_fault_arguments(["mag_bias@200"], False, steps=100, ts=(1.0, 2.0))
    assert len(check_fault_arguments(["mag_bias@150"], False, steps=100, ts=(1.0, 2.0))) == 1
    assert len(check_fault_arguments(late, False)) == 1  # no length given: the spec checks only
    assert len(check_fault_arguments(late, False, steps=-5, ts=(1.0,))) == 1  # a bad length is check_run_arguments'


def test_sil_scenario_refuses_a_fault_after_the_end():
    """``magtune sil --fault mag_dropout@99999:30 --steps 100``: one line, exit 2, before any node starts."""
    from magtune_core.ros.scenario import SilRequest, SilScenario

    with pytest.raises(ConfigError, match=r"mag_dropout@99999.0:30.0: field 't': .* end of the run \(100 s\)"):
        SilScenario.build({"": "config/gains/sigma_60.yaml"}, SilRequest(steps=100, faults=("mag_dropout@99999:30",)))


def test_reversed_and_gain_drop_torquers_and_sun_loss():
    """The kinds issue 44 added: a reversed axis flies minus its command, a gain drop value times it (default
    0.5; only a fraction in (0, 1) accepted), both from their onset and on their axis only; sun_loss is a
    whole-unit sensor fault (no axis, no value) that fl.sun_lost reports while it acts."""
    from magtune_core.design import faults as fl

    rev = fl.parse_spec("torquer_reversed@10,axis=y")
    gain = fl.parse_spec("torquer_gain@10:5,axis=z")
    assert gain.value == 0.5 and fl.parse_spec("torquer_gain@0,axis=x,value=0.25").value == 0.25
    m = [10.0, -20.0, 30.0]
    assert np.array_equal(fl.actuate([rev, gain], 9.0, m)[0], m)
    assert np.array_equal(fl.actuate([rev, gain], 10.0, m)[0], [10.0, 20.0, 15.0])
    assert np.array_equal(fl.actuate([rev, gain], 15.0, m)[0], [10.0, 20.0, 30.0])  # the gain drop ended
    for bad, field in (("torquer_gain@1,value=1.0", "value"), ("torquer_gain@1,value=0", "value"),
                       ("torquer_gain@1,value=-0.5", "value"), ("torquer_reversed@1,value=2", "value"),
                       ("sun_loss@1,axis=x", "axis"), ("sun_loss@1,value=1", "value")):
        with pytest.raises(ConfigError, match=f"field '{field}'"):
            fl.parse_spec(bad)
    for text in ("torquer_reversed@10.0,axis=y", "torquer_gain@10.0:5.0,axis=z,value=0.5", "sun_loss@100.0:50.0"):
        assert fl.parse_spec(text).spec == text  # what the nodes are given parses back
    sun = fl.parse_spec("sun_loss@100:50")
    assert sun.kind in fl.SENSOR_KINDS and sun.kind not in fl.TORQUER_KINDS
    assert [fl.sun_lost([sun], t) for t in (99.0, 100.0, 149.0, 150.0)] == [False, True, True, False]
