"""Check that a parameter file is loadable by ROS 2 (rcl_yaml_param_parser), not only by PyYAML.

rcl rejects things PyYAML accepts: lists mixing types (``[1, 2.5]``: write ``[1.0, 2.5]``),
lists of lists or of mappings, lists holding null, and strings that YAML 1.1 reads as booleans
inside string lists (``[x, y]``: ``y`` is ``true``). A node handed such a file fails inside
``rclpy.init`` with a parser message; this check names the offending parameter instead.
"""
from __future__ import annotations

from .params import ConfigError, read_ros_params

#: Plain scalars that rcl (YAML 1.1 core) reads as booleans.
YAML11_BOOLS = {s for w in ("y", "yes", "n", "no", "true", "false", "on", "off")
                for s in (w, w.upper(), w.capitalize())}


def _kind(v):
    if isinstance(v, bool):
        return "bool"
    if isinstance(v, int):
        return "integer"
    if isinstance(v, float):
        return "double"
    if isinstance(v, str):
        return "bool" if v in YAML11_BOOLS else "string"
    if v is None:
        return "null"
    return "nested"


def _walk(prefix, params, path):
    for key, v in params.items():
        name = f"{prefix}{key}"
        if isinstance(v, dict):
            _walk(name + ".", v, path)
        elif isinstance(v, (list, tuple)):
            kinds = {_kind(x) for x in v}
            if "nested" in kinds:
                raise ConfigError(path, name, "lists of lists or of mappings are not ROS 2 parameters; flatten "
                                              "them (e.g. a row-major list of numbers)")
            if "null" in kinds:
                raise ConfigError(path, name, "a ROS 2 parameter list cannot hold null")
            if len(kinds) > 1:
                raise ConfigError(path, name, f"ROS 2 parameter lists must hold one type, got {sorted(kinds)} "
                                              "(write 1.0 rather than 1 in a list of numbers; quote 'y'/'n')")


def check_ros_params(path) -> dict:
    """Validate every node's ``ros__parameters`` of ``path``; return the merged parameters."""
    merged = read_ros_params(path)  # file, YAML and layout errors
    import yaml
    from pathlib import Path

    doc = yaml.safe_load(Path(path).read_text())
    for node, body in doc.items():
        _walk("", body["ros__parameters"], path)
    return merged
