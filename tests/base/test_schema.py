"""The parameter schema (magtune_core.base.schema) and the two schemas built on it."""
import math

import numpy as np
import pytest

from magtune_core.base.errors import ConfigError
from magtune_core.base.schema import Field, parse
from magtune_core.design.gains import Gains
from magtune_core.design.params import SpacecraftParams

FIELDS = (
    Field("mass", "float", "mass [kg]", positive=True),
    Field("axes", "float[]", "three numbers", (1.0, 2.0, 3.0), size=3),
    Field("mode", "str", "a mode", "a", choices=("a", "b")),
    Field("count", "int", "a count", 4, nonnegative=True),
)


def test_defaults_and_types():
    v = parse({"mass": 2}, FIELDS, "f.yaml")
    assert v["mass"] == 2.0 and isinstance(v["mass"], float)
    assert np.array_equal(v["axes"], [1.0, 2.0, 3.0]) and v["mode"] == "a" and v["count"] == 4


@pytest.mark.parametrize("mapping, field, words", [
    ({}, "mass", "missing (expected a number: mass [kg])"),
    ({"mass": -1.0}, "mass", "expected a positive number, got -1.0"),
    ({"mass": math.nan}, "mass", "expected a finite number, got nan"),
    ({"mass": 1e400}, "mass", "expected a finite number, got inf"),
    ({"mass": True}, "mass", "expected a finite number, got True"),
    ({"mass": "2"}, "mass", "expected a finite number, got '2' (YAML reads 2 as text: write 2.0)"),
    ({"mass": "1e2"}, "mass", "got '1e2' (YAML reads 1e2 as text: write 100.0)"),  # YAML 1.1: no dot, no sign
    ({"mass": 1.0, "axes": [1.0, 2.0]}, "axes", "expected a list of 3 numbers, got [1.0, 2.0]"),
    ({"mass": 1.0, "axes": [1.0, math.inf, 2.0]}, "axes", "expected finite numbers"),
    ({"mass": 1.0, "mode": "c"}, "mode", "expected one of a, b, got 'c'"),
    ({"mass": 1.0, "count": 2.5}, "count", "expected an integer, got 2.5"),
    ({"mass": 1.0, "count": -1}, "count", "expected a non-negative number, got -1"),
    # a null never means the default silently (issue 57: tle_file null flew the default orbit)
    ({"mass": None}, "mass", "null: give it a value"),
    ({"mass": 1.0, "mode": None}, "mode", "null: give it a value, or remove the key for its default"),
])
def test_errors_name_the_field_and_the_fix(mapping, field, words):
    with pytest.raises(ConfigError) as err:
        parse(mapping, FIELDS, "f.yaml")
    assert err.value.field == field and words in err.value.expected
    assert str(err.value).startswith(f"f.yaml: field '{field}': ")


def test_spacecraft_schema_requires_physical_data_and_defaults_the_orbit():
    base = {"inertia": [35.0, 17.0, 25.0], "wheel_inertia": 0.01, "wheel_speed": -200.0, "orbit_period": 5614.8}
    p = SpacecraftParams.from_mapping(base)
    assert np.array_equal(p.inertia, [35.0, 17.0, 25.0]) and p.orbit_period == 5614.8
    assert p.altitude == 450e3 and p.inclination_deg == 87.0 and p.field_model == "eq26"
    for key in ("inertia", "wheel_inertia", "wheel_speed"):
        with pytest.raises(ConfigError, match=f"field '{key}': missing"):
            SpacecraftParams.from_mapping({k: v for k, v in base.items() if k != key})
    # orbit_period is optional: derived from the orbit (Keplerian period of 450 km by default)
    p = SpacecraftParams.from_mapping({k: v for k, v in base.items() if k != "orbit_period"})
    assert p.orbit_period == pytest.approx(5615.19, abs=0.01)


def test_gains_schema_keeps_provenance():
    g = Gains.from_mapping({"gain": [0.5] * 18, "sigma": 60.0, "J": 270.1, "seed": 3}, "g.yaml")
    assert g.K.shape == (3, 6) and g.ts == 1.0 and g.provenance == {"J": 270.1, "seed": 3}
    with pytest.raises(ConfigError, match="field 'gain': expected a list of 18 numbers"):
        Gains.from_mapping({"gain": [0.5] * 17, "sigma": 60.0})
    with pytest.raises(ConfigError, match="field 'sigma': missing"):
        Gains.from_mapping({"gain": [0.5] * 18})


def test_a_nullable_field_takes_null_as_none():
    """Only a field whose null has a stated meaning (the design spec's dipole limit: the spacecraft file's) takes it."""
    fields = (Field("limit", "float", "per-axis limit (null: the spacecraft file's)", None, positive=True, nullable=True),)
    assert parse({"limit": None}, fields, "f.yaml") == {"limit": None}
    assert parse({"limit": 2.0}, fields, "f.yaml") == {"limit": 2.0}
