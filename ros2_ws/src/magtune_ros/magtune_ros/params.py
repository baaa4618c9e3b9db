"""Node parameters from the core's schemas: one read-only ROS parameter per Field, validated once.

The descriptor carries the schema's type, description (with the unit), bounds (``FloatingPointRange``
/ ``IntegerRange``: what ``ros2 param describe`` shows) and ``read_only``; the values are validated
by :func:`magtune_core.base.schema.parse`, so a node and the CLI give the same one-line error.
"""
from __future__ import annotations

import array
import sys

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter

from magtune_core.base.errors import ConfigError
from magtune_core.base.schema import Field, parse, parse_value
from magtune_core.design.params import SpacecraftParams, check_sample_period


class ParamError(ValueError):
    """Invalid node parameter: the node prints one line naming it and exits with status 2."""

    def __init__(self, name: str, expected: str):
        self.name = name
        super().__init__(f"parameter '{name}': {expected}")


#: magtune_core.base.schema field kinds -> ROS 2 parameter types.
_ROS_TYPES = {
    "bool": Parameter.Type.BOOL,
    "int": Parameter.Type.INTEGER,
    "float": Parameter.Type.DOUBLE,
    "str": Parameter.Type.STRING,
    "float[]": Parameter.Type.DOUBLE_ARRAY,
    "str[]": Parameter.Type.STRING_ARRAY,
}
_TYPE_NAMES = {
    "bool": "a boolean",
    "int": "an integer",
    "float": "a floating-point number (write 1.0, not 1)",
    "str": "a string",
    "float[]": "a list of floating-point numbers (write 1.0, not 1)",
    "str[]": "a list of strings",
}


#: The largest int64: the open upper end of an IntegerRange (ROS parameters are int64).
INT64_MAX = 2**63 - 1


def descriptor(f: Field) -> ParameterDescriptor:
    """The ROS descriptor of a schema field: type, description with the unit, read-only, and the
    schema's bounds as ``floating_point_range`` / ``integer_range`` (``positive``/``nonnegative``
    without bounds: from 0 up), which ``ros2 param describe`` shows and rclpy enforces at declaration."""
    desc = ParameterDescriptor(name=f.name, type=_ROS_TYPES[f.kind].value, read_only=True,
                               description=f.description + (f" [{f.unit}]" if f.unit and f.unit not in f.description
                                                            else ""))
    if f.bounds is None and not (f.positive or f.nonnegative):
        return desc
    if f.kind == "float":
        lo, hi = f.bounds or (0.0, sys.float_info.max)
        desc.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
    elif f.kind == "int":
        lo, hi = f.bounds or (1 if f.positive else 0, INT64_MAX)
        desc.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
    return desc


def parameter_overrides(node: Node) -> dict:
    """The parameters the node was started with (parameter files, ``-p``), by name.

    rclpy keeps them in the private ``Node._parameter_overrides`` and has no public reader; the only
    public way, ``automatically_declare_parameters_from_overrides``, would declare every one untyped
    and writable before the schema's declaration. This is the one place that reads it
    (tests/ros/test_node_params.py fails if rclpy renames it)."""
    return dict(getattr(node, "_parameter_overrides", {}))


def _out_of_range(node: Node, f: Field, exc: Exception) -> "ParamError":
    """The schema's one line for a value rclpy refused against the descriptor's range."""
    given = parameter_overrides(node).get(f.name)
    try:
        if given is not None:
            parse_value(f, given.value, f"node '{node.get_name()}'")
    except ConfigError as err:
        return param_error(err)
    return ParamError(f.name, str(exc))


def declare_field(node: Node, f: Field):
    """Declare the schema field ``f`` as a read-only ROS parameter (:func:`descriptor`: type,
    description, bounds; default from the schema); return the value set, or None when unset and
    without default. The ROS type and range are checked here (ParamError, with the schema's message
    for a value out of range); the value is the schema's to validate."""
    desc = descriptor(f)
    default = None if f.required else (list(f.default) if isinstance(f.default, tuple) else f.default)
    if node.has_parameter(f.name):  # a managed node configured again (after cleanup): read it back
        value = node.get_parameter(f.name).value
        return list(value) if isinstance(value, (list, tuple, array.array)) or hasattr(value, "tolist") else value
    try:
        if default is None or default == []:
            # no default (an empty list would be typed BYTE_ARRAY): typed, set by a parameter file or not at all
            node.declare_parameter(f.name, _ROS_TYPES[f.kind], desc)
            value = node.get_parameter_or(f.name, None).value
        else:
            value = node.declare_parameter(f.name, default, desc).value
    except rclpy.exceptions.InvalidParameterTypeException:
        raise ParamError(f.name, f"expected {_TYPE_NAMES[f.kind]}") from None
    except rclpy.exceptions.InvalidParameterValueException as exc:
        raise _out_of_range(node, f, exc) from None
    except rclpy.exceptions.ParameterException as exc:
        raise ParamError(f.name, str(exc)) from None
    return list(value) if isinstance(value, (list, tuple, array.array)) or hasattr(value, "tolist") else value


def declare_fields(node: Node, fields) -> dict:
    """Declare every field of a schema; return the values set (unset fields left out)."""
    values = {}
    for f in fields:
        v = declare_field(node, f)
        if v is not None and not (v == [] and (f.required or not f.default)):
            values[f.name] = v
    return values


def param_error(exc: ConfigError) -> ParamError:
    """The schema's ConfigError as the node's ParamError (one line naming the parameter, exit 2)."""
    return ParamError(exc.field or "?", exc.expected)


def parse_fields(node: Node, fields) -> dict:
    """Declare a schema's parameters and validate them once (:func:`magtune_core.base.schema.parse`:
    the CLI's checks and messages); a ConfigError becomes ParamError (one line, exit status 2)."""
    try:
        return parse(declare_fields(node, fields), fields, f"node '{node.get_name()}'")
    except ConfigError as exc:
        raise param_error(exc) from None


def from_schema(node: Node, cls, **kw):
    """``cls.from_mapping`` (which validates) of the node's declared ``cls.FIELDS``; a ConfigError becomes ParamError."""
    values = declare_fields(node, cls.FIELDS)
    try:
        return cls.from_mapping(values, f"node '{node.get_name()}'", **kw)
    except ConfigError as exc:
        raise param_error(exc) from None


def check(rule, values: dict, node: Node) -> None:
    """Apply a schema's rule across fields (e.g. ``design.node_params.check_simulator``) as ParamError."""
    try:
        rule(values, f"node '{node.get_name()}'")
    except ConfigError as exc:
        raise param_error(exc) from None


def declare_overrides(node: Node, exclude=()):
    """Declare (read-only) every remaining parameter of the parameter files, e.g. gain provenance."""
    for name, param in parameter_overrides(node).items():
        if name in exclude or node.has_parameter(name):
            continue
        node.declare_parameter(name, param.value, ParameterDescriptor(
            name=name, description="provenance (not used by the node)", read_only=True, dynamic_typing=True))


def check_ts(ts: float, p: SpacecraftParams) -> None:
    """ParamError naming ``ts`` unless 0 < ts < half the spacecraft's nutation period (the check of
    ``magtune sil``, :func:`magtune_core.design.params.check_sample_period`, for a node started alone)."""
    try:
        check_sample_period(ts, p)
    except ConfigError as exc:
        raise ParamError("ts", exc.expected) from None
