"""Schemas of the ground side of a SIL run: the simulator, the simulated sensors, injected faults.

The flight nodes' schemas live in :mod:`magtune_core.onboard.params`; :data:`SIL_NODE_FIELDS` gathers
every node's. The simulator and the sensors node declare one ROS parameter per field (type, description,
bounds from here, ``magtune_ros.params.declare_fields``) and validate the declared values once with
:func:`~magtune_core.base.schema.parse`, with the same messages as the CLI. A parameter file handed to
every node (``config/spacecraft.yaml``, ``/**``) may set any of these: :data:`NODE_PARAMETERS`, derived
from the schemas, is what the CLI allows besides the spacecraft fields.
"""
from __future__ import annotations

import math

from ..base.errors import ConfigError
from ..base.schema import Field
from ..onboard.params import (
    AUTOSTART,
    BDOT_FIELDS,
    CONTROLLER_FIELDS,
    DIPOLE_LIMIT,
    ESTIMATOR_FIELDS,
    MANAGER_FIELDS,
    MODE_FIELDS,
    SAMPLE_PERIOD,
    TORQUER_FIELDS,
)
from .field import FIELD_MODELS

#: The paper's initial rate error dw(0) [rad/s] (section 5), the simulator's default.
INITIAL_RATE_ERROR = (1e-3, 2e-3, 0.0)

#: attitude_sensors: truth plus noise, bias and quantization (SI units).
SENSOR_FIELDS = (
    SAMPLE_PERIOD,
    Field("mag_noise_std", "float", "magnetometer white noise std [T]", 0.0, nonnegative=True, unit="T"),
    Field("mag_bias", "float[]", "magnetometer bias [T]", (0.0, 0.0, 0.0), size=3, unit="T"),
    Field("mag_quantum", "float", "magnetometer quantization step [T] (0 = none)", 0.0, nonnegative=True, unit="T"),
    Field("attitude_noise_std", "float", "attitude error std per axis [rad]", 0.0, nonnegative=True, unit="rad"),
    Field("gyro_noise_std", "float", "rate noise std [rad/s]", 0.0, nonnegative=True, unit="rad/s"),
    Field("gyro_bias", "float[]", "rate bias [rad/s]", (0.0, 0.0, 0.0), size=3, unit="rad/s"),
    Field("seed", "int", "random seed of the noise generators", 0, nonnegative=True),
    # docs/sensors.md: scale/misalignment, Farrenkopf gyro, sun sensor, position fix
    Field("mag_matrix", "float[]", "magnetometer scale factor and misalignment M (b_m = M b + ...), row-major",
          (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0), size=9, bounds=(-2.0, 2.0)),
    Field("gyro_arw", "float", "gyro angle random walk sigma_v [rad/s^0.5] (adds to gyro_noise_std^2 ts)", 0.0,
          nonnegative=True, bounds=(0.0, 0.1), unit="rad/s^0.5"),
    Field("gyro_rrw", "float", "gyro rate (bias) random walk sigma_u [rad/s^1.5]", 0.0, nonnegative=True,
          bounds=(0.0, 1e-3), unit="rad/s^1.5"),
    Field("sun_noise_std", "float", "sun sensor angle error std per axis [rad]", 0.0, nonnegative=True,
          bounds=(0.0, 0.5), unit="rad"),
    Field("sun_fov_half_angle", "float", "sun sensor field-of-view half-angle [rad] (pi: whole sphere)", math.pi,
          positive=True, bounds=(1e-3, math.pi), unit="rad"),
    Field("sun_boresight", "float[]", "sun sensor field-of-view axis, body axes", (1.0, 0.0, 0.0), size=3,
          bounds=(-1e3, 1e3)),
    Field("position_noise_std", "float", "position fix error std per axis [m] (ECI)", 0.0, nonnegative=True,
          bounds=(0.0, 1e5), unit="m"),
    Field("velocity_noise_std", "float", "position fix velocity error std per axis [m/s] (ECI)", 0.0,
          nonnegative=True, bounds=(0.0, 1e3), unit="m/s"),
)

#: simulator: run length, lockstep, initial state, plant options, environment, outputs.
SIMULATOR_FIELDS = (
    SAMPLE_PERIOD,
    Field("substeps", "int", "RK4 sub-steps per step (the fewest when max_substeps > substeps)", 2, positive=True,
          bounds=(1, 1000)),
    Field("max_substeps", "int", "the RK4 sub-steps the run's fastest rate needs: the sub-steps are re-chosen every "
          "step from the rate on the ladder substeps x 2^j up to the first level >= this (sim.substeps); "
          "0 = substeps throughout", 0, nonnegative=True, bounds=(0, 1000)),
    Field("orbits", "float", "run length [orbits] (used when steps = 0)", 1.0, positive=True),
    Field("steps", "int", "run length [steps]; 0 = use orbits", 0, nonnegative=True),
    Field("initial_rate_error", "float[]", "dw(0) [rad/s], body axes", INITIAL_RATE_ERROR, size=3, unit="rad/s"),
    Field("initial_quaternion", "float[]", "q(0) scalar-first, body w.r.t. orbital axes", (1.0, 0.0, 0.0, 0.0),
          size=4),
    DIPOLE_LIMIT,
    Field("residual_dipole", "float[]", "residual magnetic dipole [A m^2] (disturbance, paper eq. 32)",
          (1.0, 1.0, 1.0), size=3, unit="A m^2"),
    Field("lockstep", "bool", "advance only when the command for the step arrived", True),
    Field("lockstep_timeout", "float", "wall seconds to wait for a command before holding the last one", 1.0,
          positive=True, unit="s"),
    Field("startup_timeout", "float", "wall seconds to wait for subscribers/controller at start", 30.0,
          positive=True, unit="s"),
    Field("real_time_factor", "float", "pace sim time at this multiple of wall time; 0 = as fast as possible", 0.0,
          nonnegative=True),
    Field("results_path", "str", "write the run (.npz) here at the end; '' = none", ""),
    Field("publish_torques", "bool", "publish sim/*_torque topics", True),
    Field("wait_for_peers", "bool", "start when the sensors and controller are matched", True),
    Field("publish_tf", "bool", "publish /tf (orbital -> body; eci -> orbital)", True),
    Field("publish_markers", "bool", "publish sim/markers (body box, field and dipole arrows)", True),
    Field("time_origin_ns", "int", "stamp of step 0 [ns since 1970]; 0 = sim time from 0", 0, nonnegative=True),
    Field("min_truth_subscribers", "int", "subscribers of sim/truth required before starting (2 with a recorder)",
          1, positive=True),
    Field("environment", "str", "'paper': eq. 26 field, circular orbit, GG + residual dipole; 'full': J2 orbit, "
          "IGRF, GG with actual r, drag, SRP (magtune_core/sim/fullenv.py)", "paper", choices=("paper", "full")),
    Field("env_gravity_gradient", "bool", "full environment: gravity gradient", True),
    Field("env_drag", "bool", "full environment: Harris-Priester drag torque", True),
    Field("env_srp", "bool", "full environment: solar radiation pressure torque with eclipse", True),
    Field("env_field", "str", "full environment: 'igrf' or a periodic model of field.py", "igrf",
          choices=("igrf",) + tuple(FIELD_MODELS)),
    Field("igrf_degree", "int", "full environment: IGRF truncation degree", 10, positive=True),
    Field("field_plugin", "str", "'module:function' returning b_orb(t) [T, orbital axes] from SpacecraftParams; "
          "'' = field_model of the spacecraft parameters", ""),
    Field("field_file", "str", "paper environment: periodic field file (magtune fit-field output) as b_orb(t); "
          "'' = field_model of the spacecraft parameters", ""),
    Field("disturbance_plugins", "str[]", "'module:function' factories (SpacecraftParams -> torque(t, q, w, b) "
          "[N m]) added to gravity gradient and residual dipole", ()),
)

#: Injected faults (design/faults.py): the sensor faults for attitude_sensors, the torquer faults and the
#: sensors' kill for the simulator (``magtune sil --fault``, a scenario file's ``faults:``).
FAULTS = Field("faults", "str[]", "injected faults, each KIND@T[:DURATION][,axis=x|y|z][,value=V] "
               "(magtune_core/design/faults.py; docs/modes.md#faults)", ())

#: The SIL nodes' schemas by node name.
SIL_NODE_FIELDS = {"simulator": SIMULATOR_FIELDS + TORQUER_FIELDS + (FAULTS,),
                   "attitude_sensors": SENSOR_FIELDS + TORQUER_FIELDS + (AUTOSTART, FAULTS),
                   "controller": CONTROLLER_FIELDS + BDOT_FIELDS + TORQUER_FIELDS + (AUTOSTART,),
                   "attitude_estimator": ESTIMATOR_FIELDS + TORQUER_FIELDS + (AUTOSTART,),
                   "mode_manager": MANAGER_FIELDS + MODE_FIELDS + BDOT_FIELDS}
#: Parameters every node has (rclpy's own).
NODE_COMMON = ("use_sim_time",)
#: Every node parameter a file handed to all SIL nodes may set besides the spacecraft fields.
NODE_PARAMETERS = tuple(sorted({f.name for fields in SIL_NODE_FIELDS.values() for f in fields} | set(NODE_COMMON)))


def check_simulator(v: dict, where: str) -> None:
    """The simulator's rules across fields (``v``: its parsed values); ConfigError naming the field.

    Parameters
    ----------
    v : dict
        Parsed simulator parameters.
    where : str
        Context named in error messages.

    Raises
    ------
    ConfigError
        If the initial quaternion is zero, real_time_factor <= 0 without lockstep, field_plugin is used with
        environment "full", or field_file is combined with field_plugin or environment "full".
    """
    if sum(x * x for x in v["initial_quaternion"]) < 1e-18:
        raise ConfigError(where, "initial_quaternion", "expected a nonzero quaternion")
    if not v["lockstep"] and v["real_time_factor"] <= 0:
        raise ConfigError(where, "real_time_factor", "expected a positive number when lockstep is false")
    if v["environment"] == "full" and v["field_plugin"]:
        raise ConfigError(where, "field_plugin", "not available with environment 'full' (use env_field)")
    if v["field_file"] and (v["field_plugin"] or v["environment"] == "full"):
        raise ConfigError(where, "field_file", "only with environment 'paper' and without field_plugin")


def check_sensors(v: dict, where: str) -> None:
    """The sensors' rules across elements (``v``: parsed SENSOR_FIELDS); ConfigError naming the field.

    Parameters
    ----------
    v : dict
        Parsed sensor parameters.
    where : str
        Context named in error messages.

    Raises
    ------
    ConfigError
        If the sun sensor boresight is a zero vector.
    """
    if sum(x * x for x in v["sun_boresight"]) < 1e-18:
        raise ConfigError(where, "sun_boresight", "expected a nonzero vector")
