"""Spacecraft and orbit parameters (paper section 5) and the ROS 2 parameter-file reader.

Parameter files use the standard ROS 2 layout ``node_name: {ros__parameters: {...}}``;
``/**`` applies to every node. Every loader error names the file, the field and what was
expected, so a user can fix the file without reading code.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from .field import FIELD_MODELS, FourierField, paper_field


class ConfigError(ValueError):
    """A parameter file is missing, malformed, or holds an invalid value."""

    def __init__(self, path, field_name: str | None, expected: str):
        self.path, self.field, self.expected = str(path), field_name, expected
        where = f"{self.path}: " + (f"field '{field_name}': " if field_name else "")
        super().__init__(where + expected)


def read_ros_params(path, node: str | None = None) -> dict:
    """Merge the ``ros__parameters`` of ``/**`` and of ``node`` (or of every node if None)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(path, None, "file not found (expected a ROS 2 parameter YAML file)")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise ConfigError(path, None, f"malformed YAML{at}: {getattr(exc, 'problem', exc)}") from None
    if not isinstance(doc, dict) or not doc:
        raise ConfigError(path, None, "expected a mapping 'node_name: {ros__parameters: {...}}'")
    merged: dict = {}
    for name, body in doc.items():
        if node is not None and name not in ("/**", node, "/" + node.lstrip("/")):
            continue
        if not isinstance(body, dict) or not isinstance(body.get("ros__parameters"), dict):
            raise ConfigError(path, f"{name}.ros__parameters", "expected a mapping of parameters under 'ros__parameters'")
        merged.update(body["ros__parameters"])
    return merged


def get_float(params: dict, key: str, path, *, positive=False, default=None) -> float:
    if key not in params:
        if default is not None:
            return float(default)
        raise ConfigError(path, key, "missing (expected a number)")
    v = params[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise ConfigError(path, key, f"expected a finite number, got {v!r}")
    if positive and v <= 0:
        raise ConfigError(path, key, f"expected a positive number, got {v!r}")
    return float(v)


def get_vector(params: dict, key: str, path, size: int, *, positive=False, default=None) -> np.ndarray:
    if key not in params:
        if default is not None:
            return np.asarray(default, dtype=float)
        raise ConfigError(path, key, f"missing (expected a list of {size} numbers)")
    v = params[key]
    if (not isinstance(v, (list, tuple)) or len(v) != size
            or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in v)):
        raise ConfigError(path, key, f"expected a list of {size} numbers, got {v!r}")
    arr = np.asarray(v, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ConfigError(path, key, f"expected finite numbers, got {v!r}")
    if positive and np.any(arr <= 0):
        raise ConfigError(path, key, f"expected positive numbers, got {v!r}")
    return arr


@dataclass(frozen=True)
class SpacecraftParams:
    """Inertia, wheel and circular-orbit data of paper section 5 (SI units)."""

    inertia: np.ndarray = field(default_factory=lambda: np.array([35.0, 17.0, 25.0]))
    wheel_inertia: float = 0.01
    wheel_speed: float = -200.0
    orbit_period: float = 5614.8
    altitude: float = 450e3
    inclination_deg: float = 87.0
    field_model: str = "eq26"
    constant_field: np.ndarray = field(default_factory=lambda: np.array([2e-5, 0.0, 1e-5]))

    @property
    def orbit_rate(self) -> float:
        """W0 = 2 pi / T [rad/s]."""
        return 2.0 * np.pi / self.orbit_period

    @property
    def wheel_momentum(self) -> np.ndarray:
        """Wheel angular momentum in body axes, h = [0, 0, -J Wwheel] (SPEC.md sign check)."""
        return np.array([0.0, 0.0, -self.wheel_inertia * self.wheel_speed])

    def field(self, model: str | None = None) -> FourierField:
        return paper_field(self.orbit_rate, model or self.field_model, self.constant_field)


def load_spacecraft(path) -> SpacecraftParams:
    """Read ``config/spacecraft.yaml`` into SpacecraftParams, validating every field."""
    p = read_ros_params(path)
    model = p.get("field_model", "eq26")
    if model not in FIELD_MODELS:
        raise ConfigError(path, "field_model", f"expected one of {', '.join(FIELD_MODELS)}, got {model!r}")
    return SpacecraftParams(
        inertia=get_vector(p, "inertia", path, 3, positive=True),
        wheel_inertia=get_float(p, "wheel_inertia", path, positive=True),
        wheel_speed=get_float(p, "wheel_speed", path),
        orbit_period=get_float(p, "orbit_period", path, positive=True),
        altitude=get_float(p, "altitude", path, positive=True, default=450e3),
        inclination_deg=get_float(p, "inclination", path, default=87.0),
        field_model=model,
        constant_field=get_vector(p, "constant_field", path, 3, default=[2e-5, 0.0, 1e-5]),
    )
