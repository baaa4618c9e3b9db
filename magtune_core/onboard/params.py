"""Schemas of the on-board software's parameters: one tuple of Field per flight node.

The controller (projection law, B-dot, torquer duty cycle), the mode manager (mode machine) and the
attitude estimator declare one read-only ROS parameter per field (type, description, bounds and default
from here) and validate the declared values once with :func:`~magtune_core.base.schema.parse`, with the
same messages as the CLI. The ground side (simulator, simulated sensors, injected faults, the SIL's
table of every node's schema) lives in :mod:`magtune_core.design.node_params`.
"""
from __future__ import annotations

import math

from ..base.errors import ConfigError
from ..base.schema import Field

#: Default per-axis dipole limit [A m^2] (the paper gives none; typical 10-50 A m^2 small-sat rods).
DEFAULT_DIPOLE_LIMIT = 50.0
#: Below this field magnitude [T] the projection law is ill-conditioned: command zero dipole.
DEFAULT_MIN_FIELD = 1e-7

#: The controller sample period: every SIL node takes it (the gains file carries the design's). Its
#: default, :data:`TS_DEFAULT`, is the one default sample period of the package.
SAMPLE_PERIOD = Field("ts", "float", "controller sample period Ts [s] (sim time)", 1.0, positive=True,
                      bounds=(1e-3, 3600.0), unit="s")
#: The default sample period [s] (paper section 5): every ``ts=`` default of the package is this.
TS_DEFAULT = SAMPLE_PERIOD.default
#: Per-axis dipole saturation of the torquers: real magnetorquers span 1e-6 to 1e4 A m^2.
DIPOLE_LIMIT = Field("dipole_limit", "float[]", "per-axis dipole saturation [A m^2]", (DEFAULT_DIPOLE_LIMIT,) * 3,
                     size=3, positive=True, bounds=(1e-6, 1e4), unit="A m^2")

#: The torquers as the magnetometer and the plant see them (onboard/torquers.py, docs/torquers.md): the
#: simulator, the sensors, the controller, the estimator (its torquer watch), scenario files and campaigns read
#: this one schema. A coupling entry of 1e-3 T/(A m^2) is a magnetometer 6 cm from the rods; decay times of real
#: rods are ms.
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

#: The flight modes by id (magtune_interfaces/msg/Mode's constants; onboard/modes.py MODES is the same tuple).
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

#: The mode logic (onboard/modes.py) and the detumble law (onboard/bdot.py): one schema that the mode
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
    Field("attitude_loss_time", "float", "ACQUISITION and POINTING fall back to DETUMBLE (a law that needs no "
          "attitude) when the attitude estimate stays not valid this long [s]; DETUMBLE ends only on a valid one "
          "(default: above the sensor watch's 120-s confirmation of a magnetometer fault, during which the estimate "
          "is not valid)", 180.0, nonnegative=True, bounds=(0.0, 1e6), unit="s"),
)

#: The detumble (B-dot) law's options (onboard/bdot.py).
BDOT_FIELDS = (
    Field("bdot_gain", "float", "normalized B-dot gain k [N m s]; 0 = the rule 2 W0 (1 + sin xi_m) J_min "
          "(Avanzini & Giulietti 2012)", 0.0, nonnegative=True, bounds=(0.0, 1e6), unit="N m s"),
    Field("bdot_cutoff", "float", "cut-off of the field-derivative filter [rad/s]", 0.2, positive=True,
          bounds=(1e-4, 1e3), unit="rad/s"),
)


def check_modes(v: dict, where: str) -> None:
    """The mode schema's rules across fields (``v``: parsed MODE_FIELDS): each entry threshold lies
    beyond its exit threshold (hysteresis), else the mode could chatter; ConfigError naming the field.

    Parameters
    ----------
    v : dict
        Parsed :data:`MODE_FIELDS` values, by field name.
    where : str
        Where the values came from (file or node), named in the error.

    Raises
    ------
    ConfigError
        Unless detumble_entry_rate > detumble_exit_rate, acquisition_abort_rate >= detumble_entry_rate
        and acquisition_entry_angle > handover_angle (naming the first field that fails).
    """
    if not v["detumble_entry_rate"] > v["detumble_exit_rate"]:
        raise ConfigError(where, "detumble_entry_rate", f"expected more than detumble_exit_rate "
                                                        f"({v['detumble_exit_rate']:g} rad/s), got {v['detumble_entry_rate']:g}")
    if not v["acquisition_abort_rate"] >= v["detumble_entry_rate"]:
        raise ConfigError(where, "acquisition_abort_rate", f"expected at least detumble_entry_rate "
                                                           f"({v['detumble_entry_rate']:g} rad/s), got {v['acquisition_abort_rate']:g}")
    if not v["acquisition_entry_angle"] > v["handover_angle"]:
        raise ConfigError(where, "acquisition_entry_angle", f"expected more than handover_angle "
                                                            f"({v['handover_angle']:g} rad), got {v['acquisition_entry_angle']:g}")


#: The estimate's validity (onboard/estimator.py ValidityMonitor): the estimator publishes an estimate as
#: valid only while its covariance and its innovations are consistent (docs/modes.md, how the defaults
#: were derived). Off without the flight modes: the estimate is then published as soon as it exists.
VALIDITY_FIELDS = (
    Field("validity_gate", "bool", "publish the estimate as not known (orientation_covariance[0] = -1) while "
          "it is not valid (``magtune sil --modes`` sets it)", False),
    Field("valid_sigma", "float", "the estimate is valid only while every axis' attitude sigma is below this "
          "[rad] (default: handover_angle / 3, so a valid estimate resolves the hand-over angle at 3 sigma)",
          0.029, positive=True, bounds=(1e-5, 1.0), unit="rad"),
    Field("valid_nis_tau", "float", "time constant of the averaged magnetometer NIS [s]", 60.0, positive=True,
          bounds=(1.0, 1e5), unit="s"),
    Field("valid_nis_limit", "float", "... valid only while that average stays below this (3 when consistent; "
          "the default is the 1e-9 quantile of its distribution for tau = 60 s, docs/modes.md)", 4.6,
          positive=True, bounds=(3.0, 1e3)),
    Field("reinit_time", "float", "an estimate not valid this long after the fix is dropped and the filter starts "
          "again from a coarse fix [s] (a diverged filter gates every update and does not come back by itself; "
          "0: never)", 300.0, nonnegative=True, bounds=(0.0, 1e6), unit="s"),
)

#: The sensor watch (onboard/sensor_watch.py, run by the estimator): detection thresholds are derived from the
#: filter's own statistics at a false-alarm probability (docs/modes.md); these fields say what to do on a
#: verdict: re-estimate the failed unit's bias from the other sensors (0: detect and report only).
WATCH_FIELDS = (
    Field("sensor_watch", "bool", "watch the magnetometer and gyro from the filter's innovations and bias "
          "estimate (WARN 'magnetometer' / 'gyro' on /diagnostics at detection)", True),
    Field("watch_arm_rate", "float", "the watch arms only after the estimate has been valid with |w| (gyro minus "
          "the estimated bias) below this for its arm time [rad/s] (a tumbling filter's 1-s propagation is its "
          "weakest: inhibited through DETUMBLE; default: the mode logic's detumble_exit_rate)", 4.5e-3,
          positive=True, bounds=(1e-5, 10.0), unit="rad/s"),
    Field("recover_mag_bias_std", "float", "on a magnetometer verdict the magnetometer-bias covariance is "
          "reopened to this 1-sigma per axis [T], so the filter re-estimates the bias (0: report only)", 1e-5,
          nonnegative=True, bounds=(0.0, 1e-3), unit="T"),
    Field("recover_gyro_bias_std", "float", "on a gyro verdict the gyro-bias covariance is reopened to this "
          "1-sigma per axis [rad/s] (0: report only)", 2e-3, nonnegative=True, bounds=(0.0, 1.0), unit="rad/s"),
    Field("recover_attitude_std", "float", "... and the attitude covariance to this 1-sigma per axis [rad] (the "
          "step drifted the attitude before it was named; below valid_sigma, so the estimate stays valid)", 0.02,
          nonnegative=True, bounds=(0.0, 1.0), unit="rad"),
    Field("torquer_watch", "bool", "watch the torquers from the momentum residual of the commanded dipole, the "
          "field and the estimated rate (onboard/torquer_watch.py; ERROR 'torquer x|y|z' on /diagnostics at "
          "detection, reported only: the law has no reconfiguration)", True),
)

#: attitude_estimator: the filter's model of the sensors (defaults: the filter matched to design.sensors.default_suite,
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
    # default: onboard.mekf.MAG_BIAS_STD (tests/onboard/test_mekf_mag_bias.py pins them equal)
    Field("initial_mag_bias_std", "float", "initial magnetometer bias std per axis [T] (bias prior 0; the filter "
          "estimates the bias, states 7-9; 0: not estimated, the 6-state filter)", 3e-7, nonnegative=True,
          bounds=(0.0, 1e-5), unit="T"),
    Field("mag_bias_rw", "float", "magnetometer bias random walk std [T/s^0.5] (0: a constant bias)", 0.0,
          nonnegative=True, bounds=(0.0, 1e-7), unit="T/s^0.5"),
    Field("sun_wait", "float", "wall seconds to wait for a sun sample the on-board model predicts (lit) before "
          "the step goes on without it (counted as sun_missing)", 0.5, positive=True, bounds=(1e-3, 60.0), unit="s"),
    Field("sun_loss_samples", "int", "the sun sensor is lost after this many samples predicted lit without a sun "
          "sample in a row (WARN 'sun sensor' on /diagnostics; the steps then go on without waiting sun_wait; "
          "0: never)", 10, nonnegative=True, bounds=(0, 1000000)),
) + VALIDITY_FIELDS + WATCH_FIELDS

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
    Field("transition_timeout", "float", "bring-up: a managed node with no sign of life (no heartbeat, no lifecycle "
          "reply) this long is not answering [s, steady wall-clock time]", 30.0, positive=True, bounds=(0.1, 3600.0),
          unit="s"),
    Field("bringup_limit", "float", "bring-up: a bring-up (configure, then activate every managed node) not done "
          "this long, its nodes answering, is too slow [s, steady wall-clock time]", 300.0, positive=True, bounds=(1.0, 86400.0), unit="s"),
)
