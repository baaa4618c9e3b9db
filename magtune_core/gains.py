"""Controller gains as ROS 2 parameter files (``config/gains/sigma_*.yaml``).

Layout: ``controller: ros__parameters: {gain: [18 doubles, row-major 3x6], sigma, ts, ...}``
plus read-only provenance (figures of merit, seed, tuner settings, field model) that
``magtune analyze`` recomputes and compares.
"""
from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from .params import ConfigError, get_float, read_ros_params

CONTROLLER_NODE = "controller"


@dataclass
class Gains:
    """Constant gain K (u = T_id = K x, paper eq. 19) and its provenance."""

    K: np.ndarray
    sigma: float
    ts: float = 1.0
    provenance: dict = field(default_factory=dict)


def validate_gain(K, where="gain") -> np.ndarray:
    """Return K as a (3, 6) float array; raise ValueError naming ``where`` otherwise."""
    arr = np.asarray(K, dtype=float)
    if arr.size != 18:
        raise ValueError(f"{where}: expected 18 numbers (3x6 gain, row-major), got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{where}: expected finite numbers, got NaN/Inf")
    return arr.reshape(3, 6)


def load_gains(path) -> Gains:
    """Read a gains parameter file, validating size and finiteness of the gain."""
    p = read_ros_params(path, CONTROLLER_NODE)
    if "gain" not in p:
        raise ConfigError(path, "gain", "missing (expected a list of 18 numbers: the 3x6 gain K, row-major)")
    raw = p["gain"]
    if not isinstance(raw, (list, tuple)) or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in raw):
        raise ConfigError(path, "gain", f"expected a list of 18 numbers, got {type(raw).__name__}")
    try:
        K = validate_gain(raw, "gain")
    except ValueError as exc:
        raise ConfigError(path, "gain", str(exc).split(": ", 1)[1]) from None
    sigma = get_float(p, "sigma", path, positive=True)
    ts = get_float(p, "ts", path, positive=True, default=1.0)
    prov = {k: v for k, v in p.items() if k not in ("gain", "sigma", "ts")}
    return Gains(K, sigma, ts, prov)


def save_gains(path, gains: Gains, header: str = "") -> None:
    """Write a gains parameter file in the controller node's ROS 2 layout."""
    params = {
        "gain": [float(v) for v in np.asarray(gains.K).ravel()],
        "sigma": float(gains.sigma),
        "ts": float(gains.ts),
    }
    for k, v in gains.provenance.items():
        params[k] = _plain(v)
    params.setdefault("written", _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"))
    text = yaml.safe_dump({CONTROLLER_NODE: {"ros__parameters": params}}, sort_keys=False, width=120)
    lines = ["# Projection-based magnetorquer controller gains (magtune). u = K x, m = S(b)^T u / |b|^2.",
             "# gain: 3x6 K, row-major; rows = torque axes (x yaw, y roll, z pitch), columns = [dq; dw]."]
    lines += [f"# {h}" for h in header.splitlines() if h]
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text("\n".join(lines) + "\n" + text)


def _plain(v):
    """Convert numpy scalars/arrays to YAML-plain Python values."""
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, np.ndarray)):
        return [_plain(x) for x in np.asarray(v).tolist()] if isinstance(v, np.ndarray) else [_plain(x) for x in v]
    if isinstance(v, np.generic):
        return v.item()
    return v
