"""Robust (multi-model) design: the model set of a robust spec and worst-case figures of a gain.

A robust spec (``magtune tune|analyze --robust SPEC.yaml``) is a ROS 2-layout parameter file
(``/**: ros__parameters: {...}``, schema :data:`ROBUST_FIELDS`) describing a *finite* set of
LTP design models around the nominal one (the spacecraft file + ``--field``/``--field-model``):

* ``inertia_scale: [0.9, 1.1]``: multipliers of the principal moments; ``inertia_corners: true``
  takes every corner (2^3 combinations for two multipliers), else one moment at a time;
* ``wheel_speed_scale: [0.9, 1.1]``: multipliers of the nominal wheel speed;
* ``field_raan: [deg...]`` x ``field_epoch_offsets: [days...]``: IGRF fits
  (:func:`magtune_core.design.fitfield.fit_field`, ``field_harmonics`` harmonics, ``field_fit_days`` of
  orbit each) of the spacecraft's orbit with the RAAN and epoch (spacecraft epoch + offset)
  changed. A short fit (default 0.25 d, 4 orbits) sees only some longitudes: the spread of such
  fits is the orbit-to-orbit variation of the field that one periodic model cannot represent;
* ``combination: one_at_a_time`` (default): each variation alone, the others nominal
  (1 + corners + wheel + fields models); ``product``: every combination (grows fast).

The nominal model is always in the set (``include_nominal: false`` drops it; then the spec
must still yield at least one model). Physically impossible inertia corners (a principal moment
larger than the sum of the other two: not a rigid body) are left out and reported (the paper's
satellite, 35/17/25 kg m^2, loses the corner [1.1, 0.9, 0.9] of +-10 %).

Robust J = max over the models of J_k(K) (paper eq. 21 per model; inf if any closed loop is
unstable). :func:`tune_robust` minimizes it with the CMA-ES tuner on the batched objective
(:mod:`magtune_core.design.objective`, :mod:`magtune_core.design.cmaes`); this module builds the set
and reports per-model and worst-case figures (:func:`robust_figures`).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, replace
from datetime import timedelta

import numpy as np

from ..base.errors import ConfigError
from ..base.paramfile import read_ros_params
from ..base.schema import Field, parse
from ..ltp import DEFAULT_STEPS
from .fitfield import check_field, fit_field
from .model import AttitudeLTP
from .problem import Figures, figures

COMBINATIONS = ("one_at_a_time", "product")

#: The schema of a robust spec file.
ROBUST_FIELDS = (
    Field("inertia_scale", "float[]", "multipliers of each principal moment (e.g. [0.9, 1.1])", (), positive=True),
    Field("inertia_corners", "bool", "every combination of the multipliers over the 3 axes (else one axis at a time)",
          True),
    Field("wheel_speed_scale", "float[]", "multipliers of the nominal wheel speed (e.g. [0.9, 1.1])", (),
          positive=True),
    Field("field_raan", "float[]", "RAANs at epoch [deg] of the IGRF fits (empty: the spacecraft's, if epochs given)",
          ()),
    Field("field_epoch_offsets", "float[]", "epochs of the IGRF fits, days after the spacecraft epoch", (),
          nonnegative=True),
    Field("field_harmonics", "int", "harmonics of each IGRF fit", 2, positive=True),
    Field("field_fit_days", "float", "days of orbit each IGRF fit averages over", 0.25, positive=True),
    Field("combination", "str", "one_at_a_time (each variation alone) or product (every combination)",
          "one_at_a_time", choices=COMBINATIONS),
    Field("include_nominal", "bool", "keep the nominal model in the set", True),
)


@dataclass(frozen=True)
class RobustSpec:
    """A validated robust spec (see module docstring)."""

    inertia_scale: tuple = ()
    inertia_corners: bool = True
    wheel_speed_scale: tuple = ()
    field_raan: tuple = ()
    field_epoch_offsets: tuple = ()
    field_harmonics: int = 2
    field_fit_days: float = 0.25
    combination: str = "one_at_a_time"
    include_nominal: bool = True

    @classmethod
    def from_mapping(cls, params: dict, where="robust spec") -> "RobustSpec":
        """Validate a robust spec mapping against ``ROBUST_FIELDS`` (ConfigError naming the field).

        Parameters
        ----------
        params : dict
            Parameter name -> value of the spec.
        where : str or Path
            File or context named in error messages.

        Returns
        -------
        RobustSpec
            The validated spec, list fields as tuples of float.

        Raises
        ------
        ConfigError
            If a field is invalid, or none of inertia_scale, wheel_speed_scale, field_raan, field_epoch_offsets is given.
        """
        v = parse(params, ROBUST_FIELDS, where)
        spec = cls(**{k: (tuple(float(x) for x in val) if isinstance(val, np.ndarray) else val)
                      for k, val in v.items()})
        if not (spec.inertia_scale or spec.wheel_speed_scale or spec.field_raan or spec.field_epoch_offsets):
            raise ConfigError(where, "inertia_scale", "the spec defines no models: give at least one of "
                                                      "inertia_scale, wheel_speed_scale, field_raan, field_epoch_offsets")
        return spec


def load_robust_spec(path) -> RobustSpec:
    """Read and validate a robust spec file (ConfigError naming the file and field).

    Parameters
    ----------
    path : str or Path
        Robust spec file (ROS 2 parameter layout).

    Returns
    -------
    RobustSpec
        The validated spec.
    """
    return RobustSpec.from_mapping(read_ros_params(path), path)


@dataclass(frozen=True)
class NamedModel:
    """One model of the set and the variation it carries (``name`` as printed in reports)."""

    name: str
    model: AttitudeLTP


def _inertia_variants(spec: RobustSpec, inertia, skipped: list):
    if not spec.inertia_scale:
        return []
    scales = spec.inertia_scale
    if spec.inertia_corners:
        combos = list(itertools.product(scales, repeat=3))
    else:
        combos = [tuple(s if j == i else 1.0 for j in range(3)) for i in range(3) for s in scales]
    out = []
    for c in combos:
        inertia_k = np.asarray(inertia) * np.asarray(c)
        label = "inertia x[" + ", ".join(f"{x:g}" for x in c) + "]"
        if any(inertia_k[i] > inertia_k[(i + 1) % 3] + inertia_k[(i + 2) % 3] for i in range(3)):
            skipped.append(f"{label} (not a rigid body: {inertia_k.round(6).tolist()})")
            continue
        out.append((label, dict(inertia=inertia_k)))
    return out


def _field_variants(spec: RobustSpec, p):
    raans = spec.field_raan or ((p.raan_deg,) if spec.field_epoch_offsets else ())
    offsets = spec.field_epoch_offsets or ((0.0,) if spec.field_raan else ())
    return [(raan, off) for raan in raans for off in offsets]


def model_set(nominal: AttitudeLTP, spec: RobustSpec, where="robust spec", skipped: list | None = None) \
        -> list[NamedModel]:
    """The finite model set of ``spec`` around ``nominal`` (nominal first, if included).

    ``skipped``: if given, receives the names of the non-physical inertia corners left out.

    Parameters
    ----------
    nominal : AttitudeLTP
        Nominal design model (spacecraft parameters and field).
    spec : RobustSpec
        Variations and how they combine.
    where : str
        Context named in error messages.
    skipped : list or None
        Appended with a description of each inertia corner left out.

    Returns
    -------
    list of NamedModel
        Each variation of the spec applied to the nominal spacecraft parameters and field
        (``one_at_a_time`` or ``product`` combination). IGRF fits run here (~1 s each).

    Raises
    ------
    ConfigError
        If the spec yields no models, or a fitted field fails :func:`~.fitfield.check_field`.
    """
    p = nominal.params
    skipped = [] if skipped is None else skipped
    inertia = _inertia_variants(spec, p.inertia, skipped)
    wheel = [(f"wheel_speed x{s:g}", dict(wheel_speed=p.wheel_speed * s)) for s in spec.wheel_speed_scale]
    fields = []
    for raan, off in _field_variants(spec, p):
        f, _ = fit_field(p.altitude, p.inclination_deg, spec.field_harmonics, spec.field_fit_days,
                         epoch=p.epoch + timedelta(days=off), raan_deg=raan)
        check_field(f, f"{where}: fit raan={raan:g} epoch+{off:g} d")
        fields.append((f"IGRF fit raan {raan:g} deg, epoch+{off:g} d", f))
    models: list[NamedModel] = []
    if spec.include_nominal:
        models.append(NamedModel("nominal", nominal))

    def build(label, changes, fld):
        return NamedModel(label, AttitudeLTP(replace(p, **changes) if changes else p, fld or nominal.field))

    if spec.combination == "one_at_a_time":
        for label, ch in inertia + wheel:
            models.append(build(label, ch, None))
        for label, f in fields:
            models.append(build(label, {}, f))
    else:
        groups = [g for g in (inertia, wheel, [(lbl, f) for lbl, f in fields]) if g]
        for combo in itertools.product(*groups):
            changes, fld, labels = {}, None, []
            for label, item in combo:
                labels.append(label)
                if isinstance(item, dict):
                    changes.update(item)
                else:
                    fld = item
            models.append(build("; ".join(labels), changes, fld))
    if not models:
        raise ConfigError(where, "include_nominal", "the spec yields no models"
                          + (f" ({len(skipped)} non-physical inertia corners left out)" if skipped else ""))
    return models


@dataclass
class RobustFigures:
    """Per-model figures of one gain and the worst case over the set."""

    names: list
    figures: list  #: Figures per model, in ``names`` order

    @property
    def worst_index(self) -> int:
        """The model with the largest J (an unstable one first: J = inf, then the largest rho).

        Returns
        -------
        int
            Index into ``names`` / ``figures``.
        """
        J = np.array([f.J for f in self.figures])
        rho = np.array([f.rho for f in self.figures])
        return int(np.argmax(rho)) if not np.all(np.isfinite(J)) else int(np.argmax(J))

    @property
    def worst_name(self) -> str:
        """Name of the model with the largest J.

        Returns
        -------
        str
            ``names[worst_index]``.
        """
        return self.names[self.worst_index]

    def worst(self) -> dict:
        """Worst case of each figure over the set: max J, c1, c2, rho (each may come from a different model).

        Returns
        -------
        dict
            {"J", "c1", "c2", "rho": float}.
        """
        return {k: float(max(getattr(f, k) for f in self.figures)) for k in ("J", "c1", "c2", "rho")}

    def nominal(self) -> Figures | None:
        """Figures of the nominal model, None if the set has none.

        Returns
        -------
        Figures or None
            Figures of the model named "nominal".
        """
        return self.figures[self.names.index("nominal")] if "nominal" in self.names else None


def robust_figures(models, K, sigma: float, steps: int = DEFAULT_STEPS) -> RobustFigures:
    """J, c1, c2, rho (paper eqs. 21, 28-30) of gain K on every model of the set.

    Parameters
    ----------
    models : sequence of NamedModel
        The model set (:func:`model_set`).
    K : array_like (3, 6)
        Gain.
    sigma : float
        Weight of the torque in z (paper eq. 20).
    steps : int
        Magnus intervals per period.

    Returns
    -------
    RobustFigures
        Figures per model (``figures(model, K, sigma, steps)``), the worst case and the worst model.
    """
    return RobustFigures([m.name for m in models], [figures(m.model, K, sigma, steps=steps) for m in models])


def tune_robust(models, sigma: float, seed: int = 0, settings=None, progress=None, K0=None, hold=None, executor=None):
    """Minimize the worst J over ``models`` (a model set of :func:`model_set`) with the CMA-ES tuner.

    The objective is :class:`magtune_core.design.objective.HinfObjective` over every model of the set
    (batched over candidates and models), the optimizer :func:`magtune_core.design.cmaes.tune_cma`;
    the start gain (``K0``, default :func:`magtune_core.design.resolution.start_gain`) and the
    Magnus steps are resolved on the whole set. ``hold`` (design.sampled.HoldConstraint) makes
    the sample-and-hold gain margin a constraint on every model of the set. ``executor``: where the
    candidates are evaluated instead of ``settings.workers`` local processes (:class:`~.objective.HinfObjective`).

    Parameters
    ----------
    models : sequence of NamedModel
        The model set.
    sigma : float
        Weight of the torque in z (paper eq. 20).
    seed : int
        Seed of the tuner.
    settings : CmaSettings or None
        Tuner settings (``steps`` replaced by the resolved steps); None: defaults.
    progress : callable or None
        Progress callback of :func:`~.cmaes.tune_cma`.
    K0 : array_like (3, 6) or None
        Start gain; None: :func:`~.resolution.start_gain` on the set.
    hold : HoldConstraint or Requirements or None
        Hard requirement on every model; None: the paper's problem.
    executor : object or None
        Remote executor of the objective; None: local workers.

    Returns
    -------
    (TuneResult, float, int)
        The tuner's result (``K``, worst-case ``J``), the LQ weight of the start gain and the steps used.

    Raises
    ------
    ValueError
        If the given K0 (or every LQ start) does not stabilize every model, no scaling of the start meets
        ``hold``, or the start is not stabilizing for the tuner.
    """
    from .cmaes import CmaSettings, tune_cma  # the converging tuner (imported here: optional until it lands)
    from .objective import HinfObjective
    from .resolution import start_gain

    lt = [m.model for m in models]
    if K0 is None:
        K0, sigma0, steps, _ = start_gain(lt, sigma)
    else:  # a given start (e.g. the nominal gains): steps resolved on it, over the whole set
        from .resolution import resolved_steps

        K0, sigma0 = np.asarray(K0, dtype=float).reshape(3, 6), sigma
        steps, J0 = resolved_steps(lt, K0, sigma)
        if not np.isfinite(J0):
            raise ValueError("the start gain does not stabilize every model of the set")
    if hold is not None:
        from .sampled import feasible_start

        K0, _ = feasible_start(lt, K0, hold)  # scaled down until every model's held loop meets the margin
    s = replace(settings or CmaSettings(), steps=steps)
    with HinfObjective(lt, sigma, steps=steps, rtol=s.rtol, workers=s.workers, hold=hold, executor=executor) as objective:
        res = tune_cma(objective, K0, sigma, seed=seed, settings=s, progress=progress)
    return res, sigma0, steps
