"""One schema per parameter file: typed fields with defaults, limits and a description.

The same :class:`Field` tuple drives the command line (values read from the YAML file with
:func:`magtune_core.base.paramfile.read_ros_params`) and the ROS 2 nodes (which declare one
parameter per field, with its description, and hand the declared values back to
:func:`parse`), so a file the CLI rejects is rejected by the nodes with the same message, and
the defaults are the same everywhere.
"""
from __future__ import annotations

import array
import difflib
import math
from dataclasses import dataclass

import numpy as np

from .errors import ConfigError

#: Marks a field without default: it must be given.
REQUIRED = object()
#: Field kinds and the ROS 2 parameter type they map to (see magtune_ros.params.declare_field).
KINDS = ("float", "int", "bool", "str", "float[]", "str[]")
_SEQUENCES = (list, tuple, np.ndarray, array.array)


@dataclass(frozen=True)
class Field:
    """One parameter: name, kind (one of :data:`KINDS`), description and constraints."""

    name: str
    kind: str
    description: str
    default: object = REQUIRED
    size: int | None = None
    positive: bool = False
    nonnegative: bool = False
    choices: tuple | None = None
    #: physical bounds (inclusive) of the value, or of every element of a list: what a real
    #: spacecraft can have; a value outside is a typo or a unit error (e.g. nT written as T)
    bounds: tuple[float, float] | None = None
    unit: str = ""
    #: null (YAML ``~``) has a stated meaning for this field (its description says which) and is taken as None;
    #: for every other field a null is refused (:func:`parse`)
    nullable: bool = False

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"Field {self.name}: kind {self.kind!r} not in {KINDS}")

    @property
    def required(self) -> bool:
        return self.default is REQUIRED


def _number(v) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float, np.integer, np.floating))


def _yaml_text_hint(v) -> str:
    """Why a number arrived as text: YAML 1.1 (PyYAML, rclpy's parameter files) reads ``1e2`` or ``1.e-3`` as a string,
    a number only with a dot and a signed exponent (``1.0e+2``); '' when ``v`` is not such a string."""
    if isinstance(v, str):
        try:
            x = float(v)
        except ValueError:
            return ""
        if math.isfinite(x):
            return f" (YAML reads {v} as text: write {x!r})"
    return ""


def parse_value(f: Field, v, where):
    """Validate one value against its field; return it as float / int / bool / str / ndarray."""
    if f.kind == "float[]":
        n = f"{f.size} " if f.size else ""
        if isinstance(v, str) or not isinstance(v, _SEQUENCES) or (f.size and len(v) != f.size) \
                or any(not _number(x) for x in v):
            raise ConfigError(where, f.name, f"expected a list of {n}numbers, got {_show(v)}")
        arr = np.asarray(list(v), dtype=float)
        if not np.all(np.isfinite(arr)):
            raise ConfigError(where, f.name, f"expected finite numbers, got {_show(v)}")
        if f.positive and np.any(arr <= 0):
            raise ConfigError(where, f.name, f"expected positive numbers, got {_show(v)}")
        if f.nonnegative and np.any(arr < 0):
            raise ConfigError(where, f.name, f"expected non-negative numbers, got {_show(v)}")
        if f.bounds is not None and np.any((arr < f.bounds[0]) | (arr > f.bounds[1])):
            raise ConfigError(where, f.name, f"expected numbers in {_range(f)}, got {_show(v)}")
        return arr
    if f.kind == "str[]":
        if isinstance(v, str) or not isinstance(v, _SEQUENCES) or any(not isinstance(x, str) for x in v):
            raise ConfigError(where, f.name, f"expected a list of strings, got {_show(v)}")
        return tuple(v)
    if f.kind in ("float", "int"):
        if not _number(v) or (f.kind == "int" and float(v) != int(v)):
            what = "an integer" if f.kind == "int" else "a finite number"
            raise ConfigError(where, f.name, f"expected {what}, got {v!r}" + _yaml_text_hint(v))
        if not math.isfinite(v):
            raise ConfigError(where, f.name, f"expected a finite number, got {v!r}")
        if f.positive and v <= 0:
            raise ConfigError(where, f.name, f"expected a positive number, got {v!r}")
        if f.nonnegative and v < 0:
            raise ConfigError(where, f.name, f"expected a non-negative number, got {v!r}")
        if f.bounds is not None and not f.bounds[0] <= v <= f.bounds[1]:
            raise ConfigError(where, f.name, f"expected a number in {_range(f)}, got {v!r}")
        v = int(v) if f.kind == "int" else float(v)
    elif f.kind == "bool":
        if not isinstance(v, bool):
            raise ConfigError(where, f.name, f"expected true or false, got {v!r}")
    elif f.kind == "str":
        if not isinstance(v, str):
            raise ConfigError(where, f.name, f"expected a string, got {v!r}")
    if f.choices is not None and v not in f.choices:
        raise ConfigError(where, f.name, f"expected one of {', '.join(map(str, f.choices))}, got {v!r}")
    return v


def check_names(mapping: dict, fields, where, allowed=()) -> None:
    """Reject a key of ``mapping`` that is neither a field nor in ``allowed`` (an explicit list,
    e.g. a gains file's provenance keys), with the closest known name as a suggestion: a
    misspelled parameter (``min_feild``) must not be silently ignored."""
    known = [f.name for f in fields] + list(allowed)
    for key in mapping:
        if key not in known:
            close = difflib.get_close_matches(str(key), known, n=1, cutoff=0.6)
            hint = f"did you mean '{close[0]}'?" if close else f"known names: {', '.join(sorted(known))}"
            raise ConfigError(where, str(key), f"unknown parameter; {hint}")


def parse(mapping: dict, fields, where, allowed=None) -> dict:
    """Validate ``mapping`` against ``fields``; return ``{name: value}`` with defaults filled in.

    With ``allowed`` (a sequence, possibly empty) every other key of ``mapping`` must be a field
    or listed there (:func:`check_names`); with None other keys are ignored here (the caller
    decides, e.g. other nodes' parameters). A missing required field raises ConfigError naming it; so does a
    null (YAML ``~``, an empty value) of a field that is not ``nullable``: a user's null never means a default
    silently (a spacecraft file's ``tle_file: null`` flew the default circular orbit).
    """
    if allowed is not None:
        check_names(mapping, fields, where, allowed)
    out = {}
    for f in fields:
        if f.name in mapping and mapping[f.name] is None and not f.nullable:
            raise ConfigError(where, f.name, "null: give it a value" + ("" if f.required else
                                                                        ", or remove the key for its default"))
        if f.name in mapping and mapping[f.name] is not None:
            out[f.name] = parse_value(f, mapping[f.name], where)
        elif f.required:
            what = {"float[]": f"a list of {f.size} numbers" if f.size else "a list of numbers",
                    "str[]": "a list of strings", "float": "a number",
                    "int": "an integer", "bool": "true or false", "str": "a string"}[f.kind]
            raise ConfigError(where, f.name, f"missing (expected {what}{': ' + f.description if f.description else ''})")
        else:
            out[f.name] = parse_value(f, f.default, where) if f.default is not None else None
    return out


def _range(f: Field) -> str:
    lo, hi = f.bounds
    return f"[{lo:g}, {hi:g}]" + (f" {f.unit}" if f.unit else "")


def _show(v) -> str:
    if isinstance(v, (np.ndarray, array.array)):
        v = list(v)
    text = repr(v)
    return text if len(text) <= 80 else text[:77] + "..."
