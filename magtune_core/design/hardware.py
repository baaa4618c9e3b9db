"""The hardware file: the torquers' and sensors' datasheet figures, in the units a datasheet prints.

One schema per section (:data:`SECTIONS`: ``torquers``, ``magnetometer``, ``gyro``, ``sun_sensor``,
``gnss``), read by :func:`load_hardware` into a :class:`Hardware`, which converts the figures into the
node parameters our models take (SI units; :meth:`Hardware.node_parameters`): the simulator's and the
controller's torquers, the sensors node's models (``design/sensors.py``), the estimator's noise model
(``ESTIMATOR_FIELDS``), the design spec's dipole limit (:attr:`Hardware.dipole_limit`) and verify's
sensor and torquer dispersions (:meth:`Hardware.verify_dispersions`). Every section and every field
that is not required may be left out: it then sets nothing, and the node's own default (its schema)
applies; the hardware file never holds a default of its own. The conversions (each a function here,
unit-tested against hand calculations) and the map of every field to the parameter it feeds:
docs/hardware.md.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..base.errors import ConfigError
from ..base.paramfile import load_user_yaml, merge_ros_params
from ..base.schema import Field, check_names, parse
from .node_params import SIL_NODE_FIELDS

#: sqrt(2 ln 2 / pi): the Allan deviation's floor of a bias instability B is this times B (IEEE Std 952-1997,
#: Annex C, C.1.3; El-Sheimy, Hou & Niu 2008, IEEE Trans. Instrum. Meas. 57(1), Table 1).
ALLAN_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)

TORQUERS = (
    Field("max_dipole", "float[]", "rated (saturation) dipole of each rod, body x, y, z", size=3, positive=True,
          bounds=(1e-6, 1e4), unit="A m^2"),
    Field("residual_dipole", "float[]", "the spacecraft's residual (uncompensated) dipole, body axes", None, size=3,
          bounds=(-1e4, 1e4), unit="A m^2"),
    Field("scale_factor_error", "float", "scale-factor and linearity error of a rod: the weakest unit delivers "
          "(1 - this) of its rating", None, nonnegative=True, bounds=(0.0, 50.0), unit="%"),
    Field("coupling", "float[]", "field of the rods at the magnetometer per unit dipole, row-major 3x3, body axes",
          None, size=9, bounds=(-1e6, 1e6), unit="nT/(A m^2)"),
)
MAGNETOMETER = (
    Field("noise_std", "float", "white noise, 1 sigma per axis at the output (or noise_density and bandwidth)", None,
          positive=True, bounds=(1e-3, 1e4), unit="nT"),
    Field("noise_density", "float", "white noise density (with bandwidth; instead of noise_std)", None,
          positive=True, bounds=(1e-4, 1e4), unit="nT/sqrt(Hz)"),
    Field("bandwidth", "float", "noise-equivalent bandwidth of the output at the configured data rate (no "
          "filter: half the output data rate)", None, positive=True, bounds=(1e-3, 1e5), unit="Hz"),
    Field("range", "float", "full scale per axis (not modelled: the simulated magnetometer does not saturate; "
          "it must exceed the orbit's field)", None, positive=True, bounds=(1.0, 1e5), unit="uT"),
    Field("resolution", "float", "output step (LSB); 0: not quantized", None, nonnegative=True, bounds=(0.0, 1e4),
          unit="nT"),
    Field("bias", "float[]", "bias (offset) per body axis", None, size=3, bounds=(-1e5, 1e5), unit="nT"),
)
GYRO = (
    Field("angle_random_walk", "float", "angle random walk N", positive=True, bounds=(1e-5, 300.0), unit="deg/sqrt(h)"),
    Field("rate_random_walk", "float", "rate random walk K", None, nonnegative=True, bounds=(0.0, 1e4),
          unit="deg/h/sqrt(h)"),
    Field("bias_instability", "float", "bias instability B (used when rate_random_walk is not given)", None,
          nonnegative=True, bounds=(0.0, 1e4), unit="deg/h"),
    Field("bias_instability_time", "float", "averaging time of the Allan deviation's minimum (with "
          "bias_instability)", None, positive=True, bounds=(1.0, 1e6), unit="s"),
    Field("initial_bias", "float[]", "bias at switch-on per body axis", None, size=3, bounds=(-1e5, 1e5), unit="deg/h"),
)
SUN_SENSOR = (
    Field("accuracy", "float", "angle error per measured axis at accuracy_sigma", positive=True, bounds=(1e-4, 28.0),
          unit="deg"),
    Field("accuracy_sigma", "int", "the sigma level of accuracy as the datasheet states it (1: 1 sigma, 3: 3 sigma)",
          choices=(1, 2, 3)),
    Field("fov_half_angle", "float", "field-of-view half-angle (a +-60 deg sensor: 60; 180: the whole sphere)", None,
          positive=True, bounds=(0.06, 180.0), unit="deg"),
    Field("boresight", "float[]", "field-of-view axis, body axes", None, size=3, bounds=(-1e3, 1e3)),
)
GNSS = (
    Field("position_std", "float", "position error, 1 sigma per axis", nonnegative=True, bounds=(0.0, 1e5), unit="m"),
    Field("velocity_std", "float", "velocity error, 1 sigma per axis", None, nonnegative=True, bounds=(0.0, 1e3),
          unit="m/s"),
)
#: The hardware file's sections and their schemas.
SECTIONS = {"torquers": TORQUERS, "magnetometer": MAGNETOMETER, "gyro": GYRO, "sun_sensor": SUN_SENSOR, "gnss": GNSS}
#: The nodes the hardware file feeds.
NODES = ("simulator", "controller", "attitude_sensors", "attitude_estimator")


# ---------------------------------------------------------------- conversions (docs/hardware.md)
def nano_to_si(x) -> float:
    """nT (or nT/(A m^2)) -> T (T/(A m^2)): ``x / 1e9`` (a division by an exact power of ten: 100 nT is 1e-7 T
    bit for bit).

    Parameters
    ----------
    x : float
        Value in nano-units.

    Returns
    -------
    float
        Value in SI units.
    """
    return float(x) / 1e9


def arw_to_sigma_v(arw: float) -> float:
    """Angle random walk N [deg/sqrt(h)] -> the Farrenkopf sigma_v [rad/s^0.5]: N pi/180 / 60 (sqrt(1 h) = 60 sqrt(s)).

    Parameters
    ----------
    arw : float
        Angle random walk [deg/sqrt(h)].

    Returns
    -------
    float
        sigma_v [rad/s^0.5].
    """
    return math.radians(float(arw)) / 60.0


def rrw_to_sigma_u(rrw: float) -> float:
    """Rate random walk K [deg/h/sqrt(h)] -> the Farrenkopf sigma_u [rad/s^1.5]: K pi/180 / (3600 x 60).

    Parameters
    ----------
    rrw : float
        Rate random walk [deg/h/sqrt(h)].

    Returns
    -------
    float
        sigma_u [rad/s^1.5].
    """
    return math.radians(float(rrw)) / 216000.0


def deg_per_hour_to_rad_per_s(x: float) -> float:
    """deg/h -> rad/s: x pi/180 / 3600.

    Parameters
    ----------
    x : float
        Rate [deg/h].

    Returns
    -------
    float
        Rate [rad/s].
    """
    return math.radians(float(x)) / 3600.0


def bias_instability_to_sigma_u(b: float, tau: float) -> float:
    """Bias instability B [deg/h] -> a rate random walk sigma_u [rad/s^1.5] (the stated assumption).

    The Farrenkopf gyro has no flicker noise. Its bias walks with sigma_u, whose Allan deviation is
    sigma_u sqrt(tau/3) (IEEE Std 952-1997, Annex C, C.1.4); a bias instability has a flat Allan deviation
    of 0.664 B (:data:`ALLAN_FLOOR`, C.1.3). The walk chosen meets that floor at ``tau``, the averaging
    time of the datasheet's Allan minimum: sigma_u = 0.664 B sqrt(3 / tau). Beyond ``tau`` it drifts
    more than the datasheet's gyro (the filter's model errs on the side of a bias that moves).

    Parameters
    ----------
    b : float
        Bias instability [deg/h].
    tau : float
        Averaging time of the Allan deviation's minimum [s].

    Returns
    -------
    float
        sigma_u [rad/s^1.5].
    """
    return ALLAN_FLOOR * deg_per_hour_to_rad_per_s(b) * math.sqrt(3.0 / float(tau))


def noise_density_to_std(density: float, bandwidth: float) -> float:
    """White-noise density [unit/sqrt(Hz)] and noise-equivalent bandwidth [Hz] -> std of one sample: density
    sqrt(bandwidth) (one-sided density; without an output filter the bandwidth is half the data rate).

    Parameters
    ----------
    density : float
        Noise density [unit/sqrt(Hz)].
    bandwidth : float
        Noise-equivalent bandwidth [Hz].

    Returns
    -------
    float
        Std [unit].
    """
    return float(density) * math.sqrt(float(bandwidth))


def sigma_of_accuracy(accuracy_deg: float, level: int) -> float:
    """A datasheet's angle accuracy [deg] at ``level`` sigma -> 1 sigma [rad].

    Parameters
    ----------
    accuracy_deg : float
        Accuracy [deg] per measured axis.
    level : int
        Its sigma level (1, 2 or 3).

    Returns
    -------
    float
        1-sigma angle [rad].
    """
    return math.radians(float(accuracy_deg)) / int(level)


# ---------------------------------------------------------------- the file
def _vector(v) -> list:
    return [float(x) for x in np.asarray(v, dtype=float).ravel()]


def _check_section(name: str, v: dict, where) -> None:
    """The cross-field rules of one parsed section (ConfigError naming ``section.field``)."""
    if name == "magnetometer":
        if (v["noise_std"] is None) == (v["noise_density"] is None):
            raise ConfigError(where, "magnetometer.noise_std", "give either noise_std [nT] or noise_density "
                                                               "[nT/sqrt(Hz)] with bandwidth [Hz]")
        if v["noise_density"] is not None and v["bandwidth"] is None:
            raise ConfigError(where, "magnetometer.bandwidth", "missing (expected the noise-equivalent bandwidth [Hz] "
                                                               "of noise_density)")
        std = mag_std_nt(v)
        if not 1e-3 <= std <= 1e4:
            raise ConfigError(where, "magnetometer.noise_density", f"noise_density x sqrt(bandwidth) = {std:g} nT: "
                                                                   "expected a std in [0.001, 10000] nT")
    if name == "gyro" and v["rate_random_walk"] is None:
        if v["bias_instability"] is None:
            raise ConfigError(where, "gyro.rate_random_walk", "missing (expected the rate random walk [deg/h/sqrt(h)], "
                                                              "or bias_instability [deg/h] with bias_instability_time [s])")
        if v["bias_instability_time"] is None:
            raise ConfigError(where, "gyro.bias_instability_time", "missing (expected the averaging time [s] of the "
                                                                   "Allan deviation's minimum, to convert bias_instability)")
    if name == "sun_sensor" and v["boresight"] is not None and not np.any(v["boresight"]):
        raise ConfigError(where, "sun_sensor.boresight", "expected a nonzero vector")


def mag_std_nt(v: dict) -> float:
    """The magnetometer's white-noise std [nT] of its parsed section: ``noise_std``, or ``noise_density``
    sqrt(``bandwidth``).

    Parameters
    ----------
    v : dict
        Parsed ``magnetometer`` section.

    Returns
    -------
    float
        Std [nT] per axis.
    """
    if v["noise_std"] is not None:
        return float(v["noise_std"])
    return noise_density_to_std(v["noise_density"], v["bandwidth"])


@dataclass(frozen=True)
class Hardware:
    """A validated hardware file: ``sections`` section name -> parsed values (datasheet units; None: not given)."""

    sections: dict
    source: str = "hardware file"

    @classmethod
    def from_mapping(cls, doc, where="hardware file") -> "Hardware":
        """Validate a hardware file's mapping (sections of :data:`SECTIONS`); ConfigError naming ``section.field``.

        Parameters
        ----------
        doc : dict
            Section name -> mapping of fields (at least one section).
        where : str or Path
            The file, named in errors and kept as ``source``.

        Returns
        -------
        Hardware
            The parsed sections (those given).

        Raises
        ------
        ConfigError
            An empty file, a null section, an unknown section or field, a missing required field, a value out of its
            bounds, or a rule across fields (one line naming the file and ``section.field``).
        """
        if not doc or not isinstance(doc, dict):  # an empty file describes no hardware: nothing it would change
            raise ConfigError(where, None, f"expected a mapping with at least one of the sections {', '.join(SECTIONS)}")
        check_names(doc, (), where, allowed=tuple(SECTIONS))
        out = {}
        for name, body in doc.items():
            if body is None:
                raise ConfigError(where, name, "null: give the section's fields, or remove the section")
            if not isinstance(body, dict):
                raise ConfigError(where, name, f"expected a mapping of {', '.join(f.name for f in SECTIONS[name])}")
            try:
                v = parse(body, SECTIONS[name], where, allowed=())
            except ConfigError as exc:
                raise ConfigError(where, f"{name}.{exc.field}", exc.expected) from None
            _check_section(name, v, where)
            out[name] = v
        hw = cls(out, str(where))
        for node, params in hw.node_parameters().items():  # the nodes accept what the conversion gives
            parse(params, SIL_NODE_FIELDS[node], f"{where} (as {node} parameters)")
        return hw

    @property
    def dipole_limit(self) -> float | None:
        """The torquers' per-axis limit for the design spec: the weakest rod's rated dipole [A m^2] (None: no torquers).

        Returns
        -------
        float or None
            min(max_dipole).
        """
        t = self.sections.get("torquers")
        return None if t is None else float(np.min(t["max_dipole"]))

    def _torquer_parameters(self) -> dict:
        t = self.sections.get("torquers")
        if t is None:
            return {}
        out = {"dipole_limit": _vector(t["max_dipole"])}
        if t["coupling"] is not None:
            out["torquer_coupling"] = [nano_to_si(x) for x in t["coupling"]]
        return out

    def sensor_parameters(self) -> dict:
        """The sensors node's parameters (``SENSOR_FIELDS`` names, SI) of the sensor sections given.

        Returns
        -------
        dict
            Name -> value.
        """
        out = {}
        m, g, s, n = (self.sections.get(k) for k in ("magnetometer", "gyro", "sun_sensor", "gnss"))
        if m is not None:
            out["mag_noise_std"] = nano_to_si(mag_std_nt(m))
            if m["resolution"] is not None:
                out["mag_quantum"] = nano_to_si(m["resolution"])
            if m["bias"] is not None:
                out["mag_bias"] = [nano_to_si(x) for x in m["bias"]]
        if g is not None:
            out["gyro_arw"] = arw_to_sigma_v(g["angle_random_walk"])
            out["gyro_rrw"] = self.gyro_sigma_u()
            if g["initial_bias"] is not None:
                out["gyro_bias"] = [deg_per_hour_to_rad_per_s(x) for x in g["initial_bias"]]
        if s is not None:
            out["sun_noise_std"] = sigma_of_accuracy(s["accuracy"], s["accuracy_sigma"])
            if s["fov_half_angle"] is not None:
                out["sun_fov_half_angle"] = math.radians(s["fov_half_angle"])
            if s["boresight"] is not None:
                out["sun_boresight"] = _vector(s["boresight"])
        if n is not None:
            out["position_noise_std"] = float(n["position_std"])
            if n["velocity_std"] is not None:
                out["velocity_noise_std"] = float(n["velocity_std"])
        return out

    def gyro_sigma_u(self) -> float:
        """The gyro's sigma_u [rad/s^1.5]: its rate random walk, else its bias instability's walk
        (:func:`bias_instability_to_sigma_u`).

        Returns
        -------
        float
            sigma_u (0.0 without a gyro section).
        """
        g = self.sections.get("gyro")
        if g is None:
            return 0.0
        if g["rate_random_walk"] is not None:
            return rrw_to_sigma_u(g["rate_random_walk"])
        return bias_instability_to_sigma_u(g["bias_instability"], g["bias_instability_time"])

    def estimator_parameters(self) -> dict:
        """The estimator's noise model (``ESTIMATOR_FIELDS`` names): the filter matched to the sensors, as
        :meth:`magtune_core.onboard.estimator.FilterModel.of_suite` matches it (magnetometer variance noise^2 +
        resolution^2 / 12).

        Returns
        -------
        dict
            ``mag_noise_std``, ``gyro_arw``, ``gyro_rrw``, ``sun_noise_std`` of the sections given.
        """
        sp = self.sensor_parameters()
        out = {k: sp[k] for k in ("gyro_arw", "gyro_rrw", "sun_noise_std") if k in sp}
        if "mag_noise_std" in sp:
            q = sp.get("mag_quantum", 0.0)
            out["mag_noise_std"] = math.sqrt(sp["mag_noise_std"] ** 2 + q**2 / 12.0) if q else sp["mag_noise_std"]
        return out

    def node_parameters(self) -> dict:
        """Every parameter the file sets, per node (:data:`NODES`): torquers to the simulator, the controller and
        the sensors node (the coupling), the sensors to the sensors node, the noise model to the estimator.

        Returns
        -------
        dict
            Node -> {name: value} (plain floats and lists).
        """
        tq = self._torquer_parameters()
        t = self.sections.get("torquers")
        sim = dict(tq)
        if t is not None and t["residual_dipole"] is not None:
            sim["residual_dipole"] = _vector(t["residual_dipole"])
        sensors = dict(self.sensor_parameters())
        if "torquer_coupling" in tq:
            sensors["torquer_coupling"] = tq["torquer_coupling"]
        return {"simulator": sim, "controller": dict(tq), "attitude_sensors": sensors,
                "attitude_estimator": self.estimator_parameters()}

    def verify_dispersions(self, dipole_budget: float, dipole_limit: float) -> dict:
        """verify's campaign dispersions that are hardware figures (the campaign keeps the rest).

        Parameters
        ----------
        dipole_budget : float
            The design spec's dipole budget [A m^2] (0: none).
        dipole_limit : float
            The design spec's resolved per-axis limit [A m^2].

        Returns
        -------
        dict
            ``mag_noise_std``, ``gyro_noise_std`` (0: the gyro's white noise is its ARW), ``gyro_arw``, ``gyro_rrw``,
            ``sun_noise_std`` of the sections given, and the torquers' range ``dipole_limit_min`` (the lower of the
            budget and the weakest rod, limit x (1 - scale_factor_error)) to ``dipole_limit_max`` (the limit).
        """
        sp = self.sensor_parameters()
        out = {k: sp[k] for k in ("mag_noise_std", "gyro_arw", "gyro_rrw", "sun_noise_std") if k in sp}
        if "gyro_arw" in out:
            out["gyro_noise_std"] = 0.0
        t = self.sections.get("torquers")
        err = 0.0 if t is None or t["scale_factor_error"] is None else float(t["scale_factor_error"]) / 100.0
        weakest = dipole_limit * (1.0 - err)
        out["dipole_limit_min"] = float(min(dipole_budget or dipole_limit, weakest))
        out["dipole_limit_max"] = float(dipole_limit)
        return out


def _equal(a, b) -> bool:
    """Two parameter values are the same numbers (a malformed one never is)."""
    try:
        return bool(np.array_equal(np.asarray(a, dtype=float), np.asarray(b, dtype=float)))
    except (TypeError, ValueError):
        return False


def load_hardware(path) -> Hardware:
    """Read and validate a hardware file (ConfigError: one line naming the file and ``section.field``).

    Parameters
    ----------
    path : str or Path
        The hardware file (YAML).

    Returns
    -------
    Hardware
        The validated file.
    """
    doc = load_user_yaml(path, "expected a hardware YAML file (sections " + ", ".join(SECTIONS) + ")")
    return Hardware.from_mapping(doc, path)


def check_spacecraft_agrees(hw: Hardware, sc_doc: dict, where) -> None:
    """A spacecraft file's node sections may keep a hardware value only if it equals the hardware file's: the
    hardware file replaces them, and two different values of one parameter would leave the user guessing.

    Parameters
    ----------
    hw : Hardware
        The hardware file.
    sc_doc : dict
        The spacecraft parameter file as loaded (:func:`magtune_core.base.paramfile.load_ros_params`).
    where : str or Path
        The spacecraft file, named in the error.

    Raises
    ------
    ConfigError
        A node section of the spacecraft file sets a parameter of the hardware file to another value.
    """
    for node, params in hw.node_parameters().items():
        given = merge_ros_params(sc_doc, node)
        for name, value in params.items():
            if name in given and not _equal(given[name], value):
                raise ConfigError(where, name, f"{node}: {given[name]!r} differs from the hardware file {hw.source} "
                                               f"({value!r}); remove it from the spacecraft file (the hardware file "
                                               "replaces it)")
