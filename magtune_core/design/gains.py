"""Controller gains as ROS 2 parameter files (``config/gains/sigma_*.yaml``): the gains schema.

Layout: ``/**: ros__parameters: {gain: [18 doubles, row-major 3x6], sigma, ts, ...}`` (the
wildcard section applies to the controller whatever its namespace or node name; older files
keyed ``controller:`` are still read)
plus read-only provenance (figures of merit, seed, tuner settings, field model) that
``magtune analyze`` recomputes and compares. The controller node declares the same
:attr:`Gains.FIELDS` and validates them with :meth:`Gains.from_mapping`.
"""
from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from ..base.atomic import atomic_write
from ..base.paramfile import read_ros_params
from ..base.schema import Field, parse
from ..onboard.params import CONTROLLER_FIELDS, SAMPLE_PERIOD, TS_DEFAULT
from .node_params import NODE_COMMON, NODE_PARAMETERS

#: The controller's default node name: what a gains file is read for (``load_gains``).
CONTROLLER_NODE = "controller"
#: Section key of written gains files: ``/**`` applies them to the node they are given to,
#: whatever its namespace or name (``-r __ns:=/sat1``, ``-r __node:=ctl``); files keyed
#: ``controller:`` (before 0.3) or ``/**/controller:`` are read too.
GAINS_SECTION = "/**"


@dataclass
class Gains:
    """Constant gain K (u = T_id = K x, paper eq. 19) and its provenance."""

    K: np.ndarray
    sigma: float
    ts: float = TS_DEFAULT
    provenance: dict = field(default_factory=dict)

    #: The schema of a gains file (the controller node's own parameters among them). Bounds:
    #: |K| entries up to 1e3 (paper gains are below 1: u = K x is a torque in N m for x in rad,
    #: rad/s); sigma over the paper's range with margin; Ts from 1 ms to 1 h (the nutation check
    #: against the spacecraft is :func:`magtune_core.design.params.check_sample_period`).
    FIELDS = (
        Field("gain", "float[]", "the 3x6 gain K, row-major (rows: torque axes; columns: [dq; dw])", size=18,
              bounds=(-1e3, 1e3)),
        Field("sigma", "float", "control-effort weight sigma of the design", positive=True, bounds=(1e-6, 1e9)),
        SAMPLE_PERIOD,
    )
    #: Read-only provenance a gains file may carry (``magtune tune`` writes these); any other
    #: key is rejected with a "did you mean" (a misspelled parameter is never silently kept).
    PROVENANCE = ("J", "c1", "c2", "rho", "J_initial", "seed", "iterations", "converged", "tuner", "design",
                  "method", "evaluations", "seeds",
                  "field_model", "design_field", "start", "analysis_steps", "tuned_steps", "stop", "tune_seconds", "written",
                  "robust_spec", "robust_models", "robust_worst_model", "worst_J", "worst_c1", "worst_c2", "worst_rho",
                  "hold_gain_margin_required", "hold_gain_margin",
                  "requirements", "requirements_source", "requirements_met", "hold_margin_min", "hold_tightest_ts",
                  "hold_multiplier_max", "hold_multiplier_ts", "hold_rho_max", "hold_certificate",
                  "hold_ts_range", "dipole_peak_proxy", "dipole_budget", "verification")

    @classmethod
    def from_mapping(cls, params: dict, where="gains") -> "Gains":
        """Validate a parameter mapping against :attr:`FIELDS`; the keys of :attr:`PROVENANCE`
        become provenance; the controller node's own options (:data:`CONTROLLER_FIELDS`) and
        ``use_sim_time`` are checked and allowed; any other key is rejected ("did you mean").

        Raises ConfigError naming ``where``, the field and what was expected.

        Parameters
        ----------
        params : dict
            Parameter name -> value (a gains file's or the controller node's parameters).
        where : str or Path
            File or context named in error messages.

        Returns
        -------
        Gains
            K (3, 6), sigma, ts [s] and the provenance keys found.

        Raises
        ------
        ConfigError
            If a field is missing or invalid, or a key is not allowed.
        """
        allowed = cls.PROVENANCE + tuple(f.name for f in CONTROLLER_FIELDS) + NODE_COMMON
        v = parse(params, cls.FIELDS, where, allowed=allowed + _spacecraft_names())
        parse({k: params[k] for k in params if k in {f.name for f in CONTROLLER_FIELDS}}, CONTROLLER_FIELDS, where)
        prov = {k: x for k, x in params.items() if k in cls.PROVENANCE}
        return cls(v["gain"].reshape(3, 6), v["sigma"], v["ts"], prov)


def _spacecraft_names() -> tuple:
    """A gains file's ``/**`` section may carry the spacecraft parameters and the node parameters."""
    from .params import SpacecraftParams

    return tuple(f.name for f in SpacecraftParams.FIELDS) + NODE_PARAMETERS


def load_gains(path) -> Gains:
    """Read a gains parameter file (the sections that apply to node ``/controller``: ``/**``,
    ``/**/controller``, ``controller``), validated by the schema.

    Parameters
    ----------
    path : str or Path
        Gains parameter file.

    Returns
    -------
    Gains
        The validated gains and provenance.
    """
    return Gains.from_mapping(read_ros_params(path, CONTROLLER_NODE), path)


def save_gains(path, gains: Gains, header: str = "") -> None:
    """Write a gains parameter file in the controller node's ROS 2 layout.

    Parameters
    ----------
    path : str or Path
        Output file (parent directories are created; written atomically).
    gains : Gains
        Gain, sigma, ts and provenance; ``written`` (UTC now) is added unless present.
    header : str
        Extra comment lines put after the standard header.

    Raises
    ------
    ValueError
        If a provenance key is not in :attr:`Gains.PROVENANCE`, or the provenance claims
        ``requirements_met`` against its own figures (:func:`.requirements.claim_contradictions`).
    """
    from .requirements import claim_contradictions

    bad = claim_contradictions(gains.provenance)
    if bad:  # a certificate that contradicts its own figures is never written
        raise ValueError(f"{path}: requirements_met contradicted by its figures: {'; '.join(bad)}")
    params = {
        "gain": [float(v) for v in np.asarray(gains.K).ravel()],
        "sigma": float(gains.sigma),
        "ts": float(gains.ts),
    }
    for k, v in gains.provenance.items():
        if k not in Gains.PROVENANCE:  # a program error: the file would not load again
            raise ValueError(f"provenance key {k!r} is not in Gains.PROVENANCE; add it there")
        params[k] = _plain(v)
    params.setdefault("written", _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"))
    text = yaml.safe_dump({GAINS_SECTION: {"ros__parameters": params}}, sort_keys=False, width=120)
    lines = ["# Projection-based magnetorquer controller gains (magtune). u = K x, m = S(b)^T u / |b|^2.",
             "# gain: 3x6 K, row-major; rows = torque axes (x yaw, y roll, z pitch), columns = [dq; dw]."]
    lines += [f"# {h}" for h in header.splitlines() if h]
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, "\n".join(lines) + "\n" + text)  # the old file survives a failed write


def update_provenance(path, updates: dict, drop=()) -> Gains:
    """Rewrite a gains file's provenance keys (``updates`` set, ``drop`` removed), K and the file's
    header comments kept; atomic, and refused like :func:`save_gains` when the claim would contradict
    its figures.

    Parameters
    ----------
    path : str or Path
        Gains parameter file.
    updates : dict
        Provenance keys to set.
    drop : iterable of str
        Provenance keys to remove.

    Returns
    -------
    Gains
        The gains as written.
    """
    g = load_gains(path)
    for k in drop:
        g.provenance.pop(k, None)
    g.provenance.update(updates)
    comments = [line[2:] for line in Path(path).read_text().splitlines() if line.startswith("# ")]
    save_gains(path, g, header="\n".join(comments[2:]))  # save_gains writes the first two (what K is) itself
    return g


def _plain(v):
    """Convert numpy scalars/arrays to YAML-plain Python values."""
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, np.ndarray)):
        return [_plain(x) for x in np.asarray(v).tolist()] if isinstance(v, np.ndarray) else [_plain(x) for x in v]
    if isinstance(v, np.generic):
        return v.item()
    return v
