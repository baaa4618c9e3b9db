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
    assert fl.kill_time(fl.from_list(["mag_stuck@1", "sensors_killed@9", "sensors_killed@4"])) == 4.0


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
