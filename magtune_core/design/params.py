"""Spacecraft and orbit parameters (paper section 5): the schema of ``config/spacecraft.yaml``.

Parameter files use the standard ROS 2 layout ``node_name: {ros__parameters: {...}}``;
``/**`` applies to every node. Every loader error names the file, the field and what was
expected, so a user can fix the file without reading code.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..base.errors import ConfigError
from ..base.paramfile import read_ros_params
from ..base.schema import Field, parse
from .field import FIELD_MODELS, FourierField, paper_field


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

    #: The schema of ``config/spacecraft.yaml``: CLI and nodes (magtune_ros.common) declare and
    #: validate exactly these parameters. The physical data are required; the orbit geometry
    #: and field model default to the paper's section 5.
    FIELDS = (
        # bounds: physically possible values (a typo or a unit error falls outside): a 1 g cubesat
        # to a space station; wheels up to 1e4 rad/s; orbits from grazing LEO (~5000 s) to beyond
        # GEO; |b| at most 1e-3 T per axis (the geomagnetic field is below 7e-5 T)
        Field("inertia", "float[]", "principal moments Ixx, Iyy, Izz [kg m^2]", size=3, positive=True,
              bounds=(1e-6, 1e8), unit="kg m^2"),
        Field("wheel_inertia", "float", "pitch wheel inertia J [kg m^2]", positive=True, bounds=(1e-9, 1e4),
              unit="kg m^2"),
        Field("wheel_speed", "float", "nominal wheel speed Wwheel [rad/s]", bounds=(-1e4, 1e4), unit="rad/s"),
        Field("orbit_period", "float", "circular orbit period T [s]", positive=True, bounds=(1e3, 1e7), unit="s"),
        Field("altitude", "float", "orbit altitude [m]", 450e3, positive=True, bounds=(1e4, 1e9), unit="m"),
        Field("inclination", "float", "orbit inclination [deg]", 87.0, bounds=(-180.0, 180.0), unit="deg"),
        Field("field_model", "str", "geomagnetic field model in orbital axes", "eq26", choices=FIELD_MODELS),
        Field("constant_field", "float[]", "field [T] in orbital axes for field_model = constant",
              (2e-5, 0.0, 1e-5), size=3, bounds=(-1e-3, 1e-3), unit="T"),
    )

    @classmethod
    def from_mapping(cls, params: dict, where="spacecraft parameters", strict: bool = False) -> "SpacecraftParams":
        """Validate a parameter mapping (file or declared node parameters) against :attr:`FIELDS`.

        ``strict``: any other key is an error with a "did you mean" (the CLI reading
        ``config/spacecraft.yaml``). Raises ConfigError naming ``where``, the field and what was expected.
        """
        v = parse(params, cls.FIELDS, where, allowed=() if strict else None)
        return cls(inertia=v["inertia"], wheel_inertia=v["wheel_inertia"], wheel_speed=v["wheel_speed"],
                   orbit_period=v["orbit_period"], altitude=v["altitude"], inclination_deg=v["inclination"],
                   field_model=v["field_model"], constant_field=v["constant_field"])

    @property
    def orbit_rate(self) -> float:
        """W0 = 2 pi / T [rad/s]."""
        return 2.0 * np.pi / self.orbit_period

    @property
    def wheel_momentum(self) -> np.ndarray:
        """Wheel angular momentum in body axes, h = [0, 0, -J Wwheel] (SPEC.md sign check)."""
        return np.array([0.0, 0.0, -self.wheel_inertia * self.wheel_speed])

    @property
    def nutation_period(self) -> float:
        """Nutation period 2 pi sqrt(Ixx Iyy) / h [s] of the momentum-biased body (wheel momentum
        h = J |Wwheel| along the pitch axis, transverse axes x, y); inf without wheel momentum.
        The fastest natural motion of the attitude: a sample period must resolve it."""
        h = abs(self.wheel_inertia * self.wheel_speed)
        return float(2.0 * np.pi * np.sqrt(self.inertia[0] * self.inertia[1]) / h) if h > 0 else float("inf")

    def field(self, model: str | None = None) -> FourierField:
        return paper_field(self.orbit_rate, model or self.field_model, self.constant_field)


def check_sample_period(ts: float, p: SpacecraftParams, where="ts") -> None:
    """ConfigError unless ``0 < ts < nutation period / 2`` (Nyquist: the sampled controller must
    resolve the nutation; beyond it the loop cannot damp it and RK4 at 2 sub-steps goes unstable,
    e.g. ts = 100 s for the paper's spacecraft, whose nutation period is 76.6 s)."""
    if not (isinstance(ts, (int, float)) and np.isfinite(ts) and ts > 0):
        raise ConfigError(where, None, f"expected a positive finite sample period in s, got {ts!r}")
    limit = p.nutation_period / 2.0
    if ts >= limit:
        raise ConfigError(where, None, f"sample period {ts:g} s does not resolve the nutation period "
                                       f"{p.nutation_period:.1f} s; use ts < {limit:.1f} s")


def load_spacecraft(path) -> SpacecraftParams:
    """Read ``config/spacecraft.yaml`` (every node section merged) into SpacecraftParams."""
    return SpacecraftParams.from_mapping(read_ros_params(path), path, strict=True)
