"""Schemas of the SIL nodes' own parameters (besides the spacecraft and gains files).

One tuple of :class:`~magtune_core.base.schema.Field` per node: the node declares one ROS
parameter per field (type and description from here, ``magtune_ros.common.parse_fields``) and
validates the declared values once with :func:`~magtune_core.base.schema.parse`, with the same
messages as the CLI. A parameter file handed to every node (``config/spacecraft.yaml``, ``/**``)
may set any of these: :data:`NODE_PARAMETERS`, derived from the schemas, is what the CLI allows
besides the spacecraft fields.
"""
from __future__ import annotations

import math

from ..base.errors import ConfigError
from ..base.schema import Field
from .field import FIELD_MODELS

#: Default per-axis dipole limit [A m^2] (the paper gives none; typical 10-50 A m^2 small-sat rods).
DEFAULT_DIPOLE_LIMIT = 50.0
#: Below this field magnitude [T] the projection law is ill-conditioned: command zero dipole.
DEFAULT_MIN_FIELD = 1e-7

#: The paper's initial rate error dw(0) [rad/s] (section 5), the simulator's default.
INITIAL_RATE_ERROR = (1e-3, 2e-3, 0.0)

#: The controller sample period: every SIL node takes it (the gains file carries the design's).
SAMPLE_PERIOD = Field("ts", "float", "controller sample period Ts [s] (sim time)", 1.0, positive=True,
                      bounds=(1e-3, 3600.0), unit="s")
#: Per-axis dipole saturation of the torquers: real magnetorquers span 1e-6 to 1e4 A m^2.
DIPOLE_LIMIT = Field("dipole_limit", "float[]", "per-axis dipole saturation [A m^2]", (DEFAULT_DIPOLE_LIMIT,) * 3,
                     size=3, positive=True, bounds=(1e-6, 1e4), unit="A m^2")

#: The torquers as the magnetometer and the plant see them (design/torquers.py, docs/torquers.md): the
#: simulator, the sensors, the controller, scenario files and campaigns read this one schema. A coupling
#: entry of 1e-3 T/(A m^2) is a magnetometer 6 cm from the rods; decay times of real rods are ms.
TORQUER_FIELDS = (
    Field("torquer_coupling", "float[]", "field of the torquers at the magnetometer per unit dipole C "
          "[T/(A m^2)], row-major 3x3, body axes (zeros: none)", (0.0,) * 9, size=9, bounds=(-1e-3, 1e-3),
          unit="T/(A m^2)"),
    Field("torquer_off_time", "float", "torquers off for the last off_time of every period, the magnetometer "
          "sampling at its end [s] (0: always on; C2A's cycle at 1 s: 0.2)", 0.0, nonnegative=True,
          bounds=(0.0, 3600.0), unit="s"),
    Field("torquer_decay_time", "float", "time constant of the torquers' field after switch-off [s] (0: instant)",
          0.0, nonnegative=True, bounds=(0.0, 60.0), unit="s"),
    Field("duty_compensation", "bool", "drive the law's dipole / on fraction (saturated) so the period's mean "
          "is the law's", True),
)

#: The flight modes by id (magtune_interfaces/msg/Mode's constants; design/modes.py MODES is the same tuple).
MODE_NAMES = ("DETUMBLE", "ACQUISITION", "POINTING", "SAFE")

#: The controller node's own options (a gains file may set them too): the projection's
#: weak-field threshold lies below the geomagnetic field (at most 1e-3 T).
CONTROLLER_FIELDS = (
    DIPOLE_LIMIT,
    Field("min_field", "float", "below this |b| [T] the dipole is zero (projection ill-conditioned)",
          DEFAULT_MIN_FIELD, positive=True, bounds=(1e-12, 1e-3), unit="T"),
    Field("initial_mode", "str", "law until the mode manager publishes a mode (POINTING: the paper's run)",
          "POINTING", choices=MODE_NAMES),
)

#: The mode logic (design/modes.py) and the detumble law (design/bdot.py): one schema that the mode
#: manager node, the controller, the offline mode simulation and campaigns read. Rates are inertial
#: body rates from the gyro (a detumbled body turns at ~W0 = 1.1e-3 rad/s at 450 km: the default
#: thresholds are ~4 W0 and ~8 W0); times are sim time. docs/modes.md has the table and the reasons.
MODE_FIELDS = (
    Field("detumble_exit_rate", "float", "DETUMBLE ends when |w_gyro| stays below this [rad/s]", 4.5e-3,
          positive=True, bounds=(1e-5, 1.0), unit="rad/s"),
    Field("detumble_exit_bdot", "float", "... and the filtered |db/dt| below this [T/s]", 5e-7, positive=True,
          bounds=(1e-10, 1e-3), unit="T/s"),
    Field("detumble_exit_time", "float", "for this long [s] (persistence)", 600.0, nonnegative=True,
          bounds=(0.0, 1e6), unit="s"),
    Field("detumble_entry_rate", "float", "back to DETUMBLE when |w_gyro| stays above this [rad/s] "
          "(above detumble_exit_rate: hysteresis)", 9e-3, positive=True, bounds=(1e-5, 1.0), unit="rad/s"),
    Field("detumble_entry_time", "float", "for this long [s]", 60.0, nonnegative=True, bounds=(0.0, 1e6), unit="s"),
    Field("acquisition_abort_rate", "float", "ACQUISITION goes back to DETUMBLE above this |w_gyro| [rad/s] "
          "(eq. 17 spins the body up to 0.064 rad/s while capturing from large errors: docs/modes.md)", 0.09,
          positive=True, bounds=(1e-5, 1.0), unit="rad/s"),
    Field("acquisition", "bool", "fly ACQUISITION (eq. 17 capturing) between DETUMBLE and POINTING "
          "(false: straight to POINTING)", True),
    Field("handover_angle", "float", "ACQUISITION hands over to POINTING when the estimated pointing error stays "
          "below this [rad] (captured: docs/modes.md)", 0.087, positive=True, bounds=(1e-4, 3.1416), unit="rad"),
    Field("handover_time", "float", "for this long [s]", 600.0, nonnegative=True, bounds=(0.0, 1e6), unit="s"),
    Field("acquisition_entry_angle", "float", "POINTING falls back to ACQUISITION when the error stays above this "
          "[rad] (above handover_angle: hysteresis)", 0.26, positive=True, bounds=(1e-4, 3.1416), unit="rad"),
    Field("acquisition_entry_time", "float", "for this long [s]", 120.0, nonnegative=True, bounds=(0.0, 1e6),
          unit="s"),
    Field("safe_recovery_time", "float", "SAFE returns to DETUMBLE when the sensors stay fresh this long [s]", 10.0,
          nonnegative=True, bounds=(0.0, 1e6), unit="s"),
    Field("frozen_time", "float", "a magnetometer sample repeated bit for bit this long [s] is a frozen sensor "
          "-> SAFE", 30.0, positive=True, bounds=(1e-3, 1e6), unit="s"),
)

#: The detumble (B-dot) law's options (design/bdot.py).
BDOT_FIELDS = (
    Field("bdot_gain", "float", "normalized B-dot gain k [N m s]; 0 = the rule 2 W0 (1 + sin xi_m) J_min "
          "(Avanzini & Giulietti 2012)", 0.0, nonnegative=True, bounds=(0.0, 1e6), unit="N m s"),
    Field("bdot_cutoff", "float", "cut-off of the field-derivative filter [rad/s]", 0.2, positive=True,
          bounds=(1e-4, 1e3), unit="rad/s"),
)


def check_modes(v: dict, where: str) -> None:
    """The mode schema's rules across fields (``v``: parsed MODE_FIELDS): each entry threshold lies
    beyond its exit threshold (hysteresis), else the mode could chatter; ConfigError naming the field."""
    if not v["detumble_entry_rate"] > v["detumble_exit_rate"]:
        raise ConfigError(where, "detumble_entry_rate", f"expected more than detumble_exit_rate "
                                                        f"({v['detumble_exit_rate']:g} rad/s), got {v['detumble_entry_rate']:g}")
    if not v["acquisition_abort_rate"] >= v["detumble_entry_rate"]:
        raise ConfigError(where, "acquisition_abort_rate", f"expected at least detumble_entry_rate "
                                                           f"({v['detumble_entry_rate']:g} rad/s), got {v['acquisition_abort_rate']:g}")
    if not v["acquisition_entry_angle"] > v["handover_angle"]:
        raise ConfigError(where, "acquisition_entry_angle", f"expected more than handover_angle "
                                                            f"({v['handover_angle']:g} rad), got {v['acquisition_entry_angle']:g}")


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

#: attitude_estimator: the filter's model of the sensors (defaults: design.estimator.default_suite,
#: which ``magtune sil --attitude estimator`` also gives the sensors node), its on-board models and
#: its tuning (docs/estimation.md).
ESTIMATOR_FIELDS = (
    SAMPLE_PERIOD,
    Field("environment", "str", "on-board models: 'full' (IGRF at the position fix, Sun of date; needs "
          "sensors/position) or 'paper' (the environment's eq. 26 field, no Sun)", "paper", choices=("paper", "full")),
    Field("igrf_degree", "int", "on-board IGRF truncation degree (full environment)", 10, positive=True, bounds=(1, 13)),
    Field("time_origin_ns", "int", "stamp of sim time 0 [ns since 1970] (the simulator's)", 0, nonnegative=True),
    Field("mag_noise_std", "float", "filter model: magnetometer white noise std [T]", 100e-9, positive=True,
          bounds=(1e-12, 1e-5), unit="T"),
    Field("gyro_arw", "float", "filter model: gyro angle random walk sigma_v [rad/s^0.5]", 1e-4, positive=True,
          bounds=(1e-9, 0.1), unit="rad/s^0.5"),
    Field("gyro_rrw", "float", "filter model: gyro rate random walk sigma_u [rad/s^1.5]", 1e-6, nonnegative=True,
          bounds=(0.0, 1e-3), unit="rad/s^1.5"),
    Field("sun_noise_std", "float", "filter model: sun sensor angle error std per axis [rad]", math.radians(0.5),
          positive=True, bounds=(1e-6, 0.5), unit="rad"),
    Field("gate_probability", "float", "chi-square innovation gate: innovations beyond this quantile are "
          "rejected (1: no gating)", 0.9999, positive=True, bounds=(0.5, 1.0)),
    Field("initial_bias_std", "float", "initial gyro bias std per axis [rad/s] (bias prior 0)", 5e-4, positive=True,
          bounds=(1e-9, 0.1), unit="rad/s"),
    Field("init_angle", "float", "magnetometer-only coarse fix once the reference field turned by this [rad]",
          math.radians(10.0), positive=True, bounds=(1e-3, 3.0), unit="rad"),
    # default: design.mekf.MAG_BIAS_STD (tests/design/test_mekf_mag_bias.py pins them equal)
    Field("initial_mag_bias_std", "float", "initial magnetometer bias std per axis [T] (bias prior 0; the filter "
          "estimates the bias, states 7-9; 0: not estimated, the 6-state filter)", 3e-7, nonnegative=True,
          bounds=(0.0, 1e-5), unit="T"),
    Field("mag_bias_rw", "float", "magnetometer bias random walk std [T/s^0.5] (0: a constant bias)", 0.0,
          nonnegative=True, bounds=(0.0, 1e-7), unit="T/s^0.5"),
    Field("sun_wait", "float", "wall seconds to wait for a sun sample the on-board model predicts (lit) before "
          "the step goes on without it (counted as sun_missing)", 0.5, positive=True, bounds=(1e-3, 60.0), unit="s"),
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

#: Managed (lifecycle) nodes (controller, attitude_sensors): who drives the transitions.
AUTOSTART = Field("autostart", "bool", "configure and activate at start (false: wait for the mode manager's "
                  "lifecycle_msgs/ChangeState requests)", True)

#: mode_manager: the bring-up, the health monitor and the first mode (besides MODE_FIELDS).
MANAGER_FIELDS = (
    SAMPLE_PERIOD,
    Field("initial_mode", "str", "mode at start (DETUMBLE after deployment)", "DETUMBLE", choices=MODE_NAMES),
    Field("managed_nodes", "str[]", "lifecycle nodes brought up in this order (down in reverse)",
          ("attitude_sensors", "controller")),
    Field("heartbeat_timeout", "float", "a managed node whose /diagnostics heartbeat (1 Hz) is missing this long "
          "[s, steady wall-clock time] -> SAFE", 3.0, positive=True, bounds=(1.5, 3600.0), unit="s"),
    Field("stale_timeout", "float", "sensor data older than this [s, sim time] is stale -> SAFE", 3.0,
          positive=True, bounds=(1e-3, 1e6), unit="s"),
    Field("transition_timeout", "float", "wall seconds to wait for a node's lifecycle service", 30.0,
          positive=True, bounds=(0.1, 3600.0), unit="s"),
)

#: Injected faults (design/faults.py): the sensor faults for attitude_sensors, the torquer faults and the
#: sensors' kill for the simulator (``magtune sil --fault``, a scenario file's ``faults:``).
FAULTS = Field("faults", "str[]", "injected faults, each KIND@T[:DURATION][,axis=x|y|z][,value=V] "
               "(magtune_core/design/faults.py; docs/modes.md#faults)", ())

#: The SIL nodes' schemas by node name.
SIL_NODE_FIELDS = {"simulator": SIMULATOR_FIELDS + TORQUER_FIELDS + (FAULTS,),
                   "attitude_sensors": SENSOR_FIELDS + TORQUER_FIELDS + (AUTOSTART, FAULTS),
                   "controller": CONTROLLER_FIELDS + BDOT_FIELDS + TORQUER_FIELDS + (AUTOSTART,),
                   "attitude_estimator": ESTIMATOR_FIELDS + (AUTOSTART,),
                   "mode_manager": MANAGER_FIELDS + MODE_FIELDS + BDOT_FIELDS}
#: Parameters every node has (rclpy's own).
NODE_COMMON = ("use_sim_time",)
#: Every node parameter a file handed to all SIL nodes may set besides the spacecraft fields.
NODE_PARAMETERS = tuple(sorted({f.name for fields in SIL_NODE_FIELDS.values() for f in fields} | set(NODE_COMMON)))


def check_simulator(v: dict, where: str) -> None:
    """The simulator's rules across fields (``v``: its parsed values); ConfigError naming the field."""
    if sum(x * x for x in v["initial_quaternion"]) < 1e-18:
        raise ConfigError(where, "initial_quaternion", "expected a nonzero quaternion")
    if not v["lockstep"] and v["real_time_factor"] <= 0:
        raise ConfigError(where, "real_time_factor", "expected a positive number when lockstep is false")
    if v["environment"] == "full" and v["field_plugin"]:
        raise ConfigError(where, "field_plugin", "not available with environment 'full' (use env_field)")
    if v["field_file"] and (v["field_plugin"] or v["environment"] == "full"):
        raise ConfigError(where, "field_file", "only with environment 'paper' and without field_plugin")


def check_sensors(v: dict, where: str) -> None:
    """The sensors' rules across elements (``v``: parsed SENSOR_FIELDS); ConfigError naming the field."""
    if sum(x * x for x in v["sun_boresight"]) < 1e-18:
        raise ConfigError(where, "sun_boresight", "expected a nonzero vector")
