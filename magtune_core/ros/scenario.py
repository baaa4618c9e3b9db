"""A SIL scenario: every input of a run read once, validated before any process starts.

:meth:`SilScenario.build` reads the spacecraft file and each gains file once, validates them
with their schemas (``SpacecraftParams.FIELDS``, ``Gains.FIELDS``) and the run options, and
derives the nominal orbit period once (``period_model``, or the actual orbit's for the full
environment, :func:`magtune_core.sim.fullenv.full_params`). :meth:`SilScenario.write_parameter_files`
then writes one ROS 2 parameter file per node, holding everything that node takes (spacecraft
parameters with the derived ``orbit_period``, the gains for the controller, the run's own
settings): each node reads one file and validates it once. Any bad input raises ConfigError
(one line, exit status 2 in the CLI).
"""
from __future__ import annotations

import datetime as _dt
import math
import os
import re
import tempfile
from dataclasses import dataclass
from dataclasses import field as _field
from pathlib import Path

import yaml

from ..base.ament import ROOT
from ..base.errors import ConfigError, SilError
from ..base.paramfile import check_path, check_ros_params, load_ros_params, load_user_yaml, merge_ros_params
from ..base.schema import parse
from ..base.topics import TOPIC_ATTITUDE, TOPIC_ESTIMATE
from ..design import faults as fl
from ..design.fitfield import field_for_spacecraft
from ..design.gains import CONTROLLER_NODE, Gains
from ..design.hardware import check_spacecraft_agrees, load_hardware
from ..design.node_params import INITIAL_RATE_ERROR
from ..design.params import SpacecraftParams, check_field_epoch, check_sample_period, warn_tle
from ..design.sensors import default_suite
from ..onboard.modes import DETUMBLE, POINTING, ModeParams
from ..onboard.params import (
    BDOT_FIELDS,
    DIPOLE_LIMIT,
    ESTIMATOR_FIELDS,
    MANAGER_FIELDS,
    MODE_FIELDS,
    MODE_NAMES,
    TORQUER_FIELDS,
)
from ..onboard.torquers import Torquers
from ..sim.fullenv import FullEnvironmentOptions, full_params
from ..sim.initial import initial_conditions
from ..sim.simulate import initial_state
from ..sim.substeps import MIN_SUBSTEPS, substeps_for_rate

DEFAULT_SPACECRAFT = ROOT / "config" / "spacecraft.yaml"
#: The SIL nodes of one satellite, in start order after the recorder.
NODES = ("controller", "attitude_sensors", "simulator")
#: ``attitude="estimator"``: the estimator node, started before the simulator; the controller's
#: sensors/attitude is remapped to its estimate/attitude (docs/estimation.md).
ESTIMATOR = "attitude_estimator"
ATTITUDE_SOURCES = ("truth", "estimator")
#: Started after them with ``modes``: it brings the two managed nodes up (docs/ros.md).
MODE_MANAGER = "mode_manager"
#: A ROS namespace as ``magtune sil --gains NS=FILE`` takes it: tokens of letters, digits, _.
NAMESPACE = re.compile(r"^(/[A-Za-z][A-Za-z0-9_]*)+$")


#: Simulator outputs that only viewers and bags read, off in a run where nothing can read them (SilScenario.outputs_read):
#: 0.3-0.5 ms of the simulator's CPU per step (bench/sil_hops.py).
UNREAD_OUTPUTS_OFF = {"publish_tf": False, "publish_markers": False, "publish_torques": False}


def normalize_namespace(ns: str) -> str:
    """``sat1`` / ``/sat1/`` -> ``/sat1``; ``""`` or ``/`` -> ``""`` (root). Raises ConfigError
    for a name ROS would reject."""
    ns = "/" + str(ns).strip().strip("/")
    if ns == "/":
        return ""
    if not NAMESPACE.match(ns):
        raise ConfigError(ns, None, "not a valid ROS namespace (tokens of letters, digits and '_', "
                                    "each starting with a letter, e.g. /sat1)")
    return ns


def tag(ns: str) -> str:
    """File-name form of a namespace: ``/sat1/a`` -> ``sat1_a``."""
    return ns.strip("/").replace("/", "_")


def epoch_ns(epoch) -> int:
    """A naive UTC ``datetime`` (the spacecraft file's ``epoch``) in integer ns since 1970."""
    import calendar

    return calendar.timegm(epoch.timetuple()) * 1_000_000_000 + epoch.microsecond * 1000


def _positive_finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0


def check_run_arguments(*, orbits=None, steps=None, substeps=2, real_time_factor=0.0, timeout=None,
                        lockstep_timeout=2.0) -> None:
    """ConfigError for a non-physical run length or setting (before any node starts)."""
    if steps is not None and not (isinstance(steps, int) and 0 < steps <= 10**8):
        raise ConfigError("--steps", None, f"expected a positive number of steps (at most 1e8), got {steps!r}")
    if steps is None and not (_positive_finite(orbits) and orbits <= 1e4):
        raise ConfigError("--orbits", None, f"expected a positive run length in orbits (at most 1e4), got {orbits!r}")
    if not (isinstance(substeps, int) and 1 <= substeps <= 1000):
        raise ConfigError("--substeps", None, f"expected an integer in [1, 1000], got {substeps!r}")
    if not (real_time_factor == 0 or _positive_finite(real_time_factor)):
        raise ConfigError("--rtf", None, f"expected 0 (as fast as possible) or a positive factor, got {real_time_factor!r}")
    if timeout is not None and not _positive_finite(timeout):
        raise ConfigError("--timeout", None, f"expected a positive number of wall seconds, got {timeout!r}")
    if not (_positive_finite(lockstep_timeout) and lockstep_timeout <= 3600):
        raise ConfigError("--lockstep-timeout", None, f"expected a positive number of wall seconds (at most 3600), "
                                                      f"got {lockstep_timeout!r}")


def check_writable(path, flag: str, *, directory: bool = False, empty: bool = False) -> None:
    """ConfigError unless ``path`` (a file, or a directory with ``directory``) can be written
    now, so an unwritable output is reported before the run, not after it. Probed for real (a
    temporary file created and removed in the nearest existing directory): permission bits say
    nothing for root or a read-only file system. ``empty``: an existing directory must be empty
    (a bag directory). Nothing is left behind."""
    p = Path(path)
    check_path(p)  # a symbolic link loop: one line before anything starts
    if directory and p.exists() and not p.is_dir():
        raise ConfigError(flag, None, f"{p} exists and is not a directory")
    if not directory and p.is_dir():
        raise ConfigError(flag, None, f"{p} is a directory; give a file name")
    if empty and p.is_dir() and any(p.iterdir()):
        raise ConfigError(flag, None, f"{p} exists and is not empty; choose a new name")
    probe_dir = p if directory else p.parent
    while not probe_dir.exists() and probe_dir != probe_dir.parent:
        probe_dir = probe_dir.parent
    if not probe_dir.is_dir():
        raise ConfigError(flag, None, f"cannot create {p}: {probe_dir} is not a directory")
    try:
        fd, name = tempfile.mkstemp(prefix=".magtune_probe_", dir=probe_dir)
        os.close(fd)
        os.unlink(name)
        if not directory and p.exists():
            with open(p, "ab"):
                pass
    except OSError as exc:
        raise ConfigError(flag, None, f"cannot write {p}: {exc.strerror or exc}") from None


def _plain(v):
    """A parameter value as a plain YAML scalar/list rcl reads back identically."""
    if isinstance(v, (_dt.datetime, _dt.date)):
        return v.isoformat()
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if hasattr(v, "tolist"):
        return v.tolist()
    return v


def initial_state_parameters(sc: SpacecraftParams, simulator_params: dict, attitude_deg, rate_deg, substeps, ts: float):
    """The simulator's ``initial_quaternion``/``initial_rate_error`` from the CLI's degrees
    (:func:`magtune_core.sim.initial.initial_conditions`) and the RK4 sub-steps (``substeps`` None:
    re-chosen every step from the rate, :class:`magtune_core.sim.substeps.Substeps`, from 2 up to what the
    initial inertial rate needs, the simulator's ``max_substeps``; 2 throughout from the paper's dw(0)).
    Returns (simulator_params, substeps); ConfigError for a bad state."""
    if attitude_deg is not None or rate_deg is not None:
        q0, dw0 = initial_conditions(attitude_deg if attitude_deg is not None else (0.0, 0.0, 0.0),
                                     rate_deg if rate_deg is not None else (0.0, 0.0, 0.0))
        if attitude_deg is not None:
            simulator_params["initial_quaternion"] = [float(x) for x in q0]
        if rate_deg is not None:
            simulator_params["initial_rate_error"] = [float(x) for x in dw0]
    if substeps is None:
        q0 = simulator_params.get("initial_quaternion", (1.0, 0.0, 0.0, 0.0))
        dw0 = simulator_params.get("initial_rate_error", INITIAL_RATE_ERROR)
        simulator_params["max_substeps"] = substeps_for_rate(initial_state(sc, dw0, q0)[4:], ts)
        substeps = MIN_SUBSTEPS
    return simulator_params, substeps


def check_modes_arguments(modes: bool, initial_mode, mode_params) -> tuple[str, dict]:
    """The first mode (DETUMBLE with the mode manager, POINTING without) and the manager's
    parameters, validated by their schemas (ranges, hysteresis) before anything starts."""
    mode = initial_mode or (DETUMBLE if modes else POINTING)
    if mode not in MODE_NAMES:
        raise ConfigError("--initial-mode", None, f"expected one of {', '.join(MODE_NAMES)}, got {mode!r}")
    mparams = dict(mode_params or {})
    if not modes:
        if mparams:
            raise ConfigError("mode parameters", None, "only with --modes")
        return mode, mparams
    extra = sorted(set(mparams) - {f.name for f in MODE_FIELDS + MANAGER_FIELDS + BDOT_FIELDS})
    if extra:
        raise ConfigError("mode parameters", extra[0], "not a mode-manager parameter")
    ModeParams.from_mapping(mparams, "mode parameters")
    for fields in (MANAGER_FIELDS, BDOT_FIELDS):
        names = {f.name for f in fields}
        parse({k: v for k, v in mparams.items() if k in names}, fields, "mode parameters")
    return mode, mparams


def check_attitude_arguments(attitude: str, sensor_params, estimator_params, field, suite=None) -> tuple[dict, dict]:
    """The sensors' and the estimator's parameters for ``attitude`` ("truth": unchanged, no
    estimator), validated by ESTIMATOR_FIELDS before anything starts (ConfigError: one line).
    With the estimator the sensors default to ``suite`` (a hardware file's sensor parameters,
    :meth:`magtune_core.design.hardware.Hardware.sensor_parameters`), else to
    :func:`magtune_core.design.sensors.default_suite` (the filter's own model), the explicit
    ``sensor_params`` on top."""
    sensor_params = dict(sensor_params or {})
    if attitude not in ATTITUDE_SOURCES:
        raise ConfigError("--attitude", None, f"expected one of {', '.join(ATTITUDE_SOURCES)}, got {attitude!r}")
    if attitude == "truth":
        if estimator_params:
            raise ConfigError("estimator parameters", None, "only with --attitude estimator")
        return sensor_params, {}
    if field is not None:
        raise ConfigError("--attitude", None, "estimator: the on-board model is the spacecraft's field_model; "
                                              "no --field file")
    eparams = dict(estimator_params or {})
    names = {f.name for f in ESTIMATOR_FIELDS}
    extra = sorted(set(eparams) - names)
    if extra:
        raise ConfigError("estimator parameters", extra[0], "not an attitude_estimator parameter")
    parse(eparams, ESTIMATOR_FIELDS, "estimator parameters")
    if suite is not None:
        return {**suite, "seed": 0, **sensor_params}, eparams
    su = default_suite()
    g = su.gyro
    defaults = dict(mag_noise_std=su.magnetometer.noise_std, gyro_arw=g.arw, gyro_rrw=g.rrw,
                    gyro_bias=[float(x) for x in g.bias], sun_noise_std=su.sun.noise_std,
                    position_noise_std=su.position.noise_std, velocity_noise_std=su.position.velocity_noise_std,
                    seed=0)
    return {**defaults, **sensor_params}, eparams


#: The keys of a scenario file (``magtune sil --scenario FILE``), each validated by its schema.
SCENARIO_KEYS = ("faults", "torquers")


def load_scenario_file(path) -> dict:
    """A scenario file: YAML with ``faults:``, a list of mappings of
    :data:`magtune_core.design.faults.FAULT_FIELDS` (``{kind: mag_dropout, t: 3000, duration: 30}``),
    and ``torquers:``, a mapping of :data:`magtune_core.onboard.params.TORQUER_FIELDS`
    (coupling into the magnetometer, duty cycle; docs/torquers.md).

    Returns
    -------
    dict
        ``{"faults": (Fault, ...), "torquers": {field: value}}`` (torquers: only the fields given);
        ConfigError naming the file, the entry and the field otherwise.
    """
    doc = load_user_yaml(path, "expected a scenario YAML file with a 'faults:' list")
    if doc is None:
        doc = {}
    if not isinstance(doc, dict):
        raise ConfigError(path, None, f"expected a mapping with {', '.join(SCENARIO_KEYS)}, got {type(doc).__name__}")
    from ..base.schema import check_names

    check_names(doc, (), path, allowed=SCENARIO_KEYS)
    tq = doc.get("torquers") or {}
    if not isinstance(tq, dict):
        raise ConfigError(path, "torquers", f"expected a mapping of {', '.join(f.name for f in TORQUER_FIELDS)}")
    parse(tq, TORQUER_FIELDS, f"{path}: torquers", allowed=())
    return {"faults": fl.from_list(doc.get("faults"), f"{path}: faults"), "torquers": dict(tq),
            "torquers_source": f"{path}: torquers"}


def check_torquer_arguments(torquers, ts_values, where: str = "torquers") -> dict:
    """The torquers' parameters (TORQUER_FIELDS given), validated against every satellite's Ts: {name: value}."""
    given = dict(torquers or {})
    values = parse(given, TORQUER_FIELDS, where, allowed=())
    tq = Torquers.from_values(values)
    for ts in ts_values:
        tq.check(ts, where)
    return {k: _plain(values[k]) for k in given}


def check_fault_arguments(faults, epoch_time: bool, *, steps=None, orbits=None, ts=(), period=None,
                          dipole_limit=None) -> tuple:
    """The injected faults (Fault objects, spec strings or mappings), validated (ConfigError: one line).

    Given the run's length (``steps``, or ``orbits`` of ``period`` [s]) and the satellites' sample
    periods ``ts`` [s], a fault that starts at or after the end of the run is refused too
    (:func:`magtune_core.design.faults.check_times`; the end of the longest satellite's run, as
    :func:`magtune_core.design.faults.run_end` counts it); a length that is not a positive number
    is left to :func:`check_run_arguments`. With the rods' ``dipole_limit`` (3,) a stuck value beyond it is refused
    (:func:`magtune_core.design.faults.check_torquer_values`).
    """
    out = fl.from_list(list(faults or ()), "--fault")
    if dipole_limit is not None:
        fl.check_torquer_values(out, dipole_limit, "--fault")
    if out and epoch_time:
        raise ConfigError("--fault", None, "fault times are sim time from 0: not with --epoch-time")
    known = _positive_finite(steps) if steps is not None else _positive_finite(orbits) and _positive_finite(period)
    if out and ts and known and all(_positive_finite(t) for t in ts):
        fl.check_times(out, max(fl.run_end(t, steps, orbits, period) for t in ts), "--fault")
    return out


@dataclass(frozen=True)
class Satellite:
    """One satellite of a scenario: its namespace, gains file and the controller's parameters."""

    namespace: str
    gains_path: Path
    gains: Gains
    #: the gains file's parameters for the controller, as read (provenance included)
    gains_params: dict
    ts: float


def run_sample_period(ts, sc: SpacecraftParams, gains: dict) -> float:
    """The run's sample period [s]: ``--ts`` checked before anything uses it (range, Nyquist; one
    line naming ``--ts``), else the shortest of the gains files' (each checked by its schema)."""
    if ts is None:
        return min(g.ts for g in gains.values())
    check_sample_period(ts, sc, "--ts")
    return float(ts)


@dataclass(frozen=True)
class SilRequest:
    """What is asked of a SIL run, as given (CLI options, a scenario file, a test's keywords): checked
    once by :meth:`SilScenario.build`, which derives everything else from it."""

    # -- run length and pace
    orbits: float = 5.0
    steps: int | None = None
    #: overrides each gains file's ts
    ts: float | None = None
    #: None: re-chosen every step from the rate (sim.substeps.Substeps; 2 throughout from the paper's dw(0))
    substeps: int | None = None
    real_time_factor: float = 0.0
    lockstep: bool = True
    lockstep_timeout: float = 2.0
    startup_timeout: float = 30.0
    timeout: float | None = None
    # -- the spacecraft, its environment and initial state
    spacecraft: object = DEFAULT_SPACECRAFT
    #: "paper" or "full" (with env_options, sim.fullenv.FullEnvironmentOptions)
    environment: str = "paper"
    env_options: object = None
    #: a field file for the paper environment
    field: object = None
    #: rotation vector [deg] -> the simulator's initial_quaternion (sim.initial.initial_conditions)
    initial_attitude_deg: object = None
    #: dw(0) [deg/s], body axes -> the simulator's initial_rate_error
    initial_rate_deg: object = None
    # -- the flight stack
    #: start the mode manager (initial_mode: DETUMBLE with it, POINTING without)
    modes: bool = False
    initial_mode: str | None = None
    mode_params: dict | None = None
    #: "truth" or "estimator" (the attitude_estimator node; the sensors default to design.sensors.default_suite)
    attitude: str = "truth"
    estimator_params: dict | None = None
    #: injected faults (design.faults: Fault objects, KIND@T... specs or mappings)
    faults: tuple = ()
    #: TORQUER_FIELDS values; errors name torquers_source
    torquers: dict | None = None
    torquers_source: str = "torquers"
    #: a hardware file (design.hardware): its torquers and sensors, a layer over the spacecraft file's node sections
    hardware: object = None
    # -- extra ROS parameters of each node (every satellite)
    simulator_params: dict | None = None
    sensor_params: dict | None = None
    controller_params: dict | None = None
    # -- outputs and network
    bag: object = None
    bag_topics: tuple | None = None
    bag_exclude: str | None = None
    #: stamps from the spacecraft epoch
    epoch_time: bool = False
    foxglove: int | None = None
    results: object = None
    log_dir: object = None
    domain_id: int | None = None
    dds_interfaces: str = "loopback"


def check_outputs(req: SilRequest) -> None:
    """The run's outputs can be written and their options make sense: ConfigError (one line) otherwise."""
    for path, flag in ((req.log_dir, "--log-dir"), (req.results, "--results"), (req.bag, "--bag")):
        if path:
            check_writable(path, flag, directory=flag != "--results", empty=flag == "--bag")
    if req.foxglove is not None and not 0 <= int(req.foxglove) <= 65535:
        raise ConfigError("--foxglove", None, f"{req.foxglove}: expected a TCP port 0..65535 (0: any free port)")
    if req.bag_exclude:
        try:
            re.compile(req.bag_exclude)
        except re.error as exc:
            raise ConfigError("--bag-exclude", None, f"{req.bag_exclude!r} is not a regular expression ({exc})") from None
    if (req.bag_topics or req.bag_exclude) and not req.bag:
        raise ConfigError("--bag-topics/--bag-exclude", None, "only with --bag")


def check_environment(req: SilRequest, sc: SpacecraftParams):
    """The environment options, checked; returns (FullEnvironmentOptions or None, the spacecraft with the
    nominal period of the actual orbit for the full environment, derived here once)."""
    if req.environment not in ("paper", "full"):
        raise SilError(f"unknown environment {req.environment!r} (expected 'paper' or 'full')")
    if req.field is not None:
        if req.environment == "full":
            raise ConfigError("--field", None, "the full environment uses IGRF along the actual orbit; give "
                              "--field with --environment paper")
        field_for_spacecraft(req.field, sc)  # validated here: one line before any process starts
    if req.environment != "full":
        return None, sc
    opts = req.env_options or FullEnvironmentOptions()
    if opts.epoch is not None or opts.raan_deg is not None or opts.arg_lat_deg is not None or opts.zonal_degree != 2:
        raise SilError("the simulator node flies the spacecraft file's orbit: set epoch, raan, arg_latitude "
                       "there (zonal degree 2)")
    return opts, full_params(sc, opts)


@dataclass(frozen=True)
class SilScenario:
    """Everything a SIL run needs, validated; built by :meth:`build` (see the module docstring)."""

    satellites: tuple[Satellite, ...]
    spacecraft_path: Path
    spacecraft: SpacecraftParams   # orbit_period: the nominal period every node is given
    spacecraft_doc: dict           # the spacecraft parameter file as read (sections per node)
    orbits: float = 5.0
    steps: int | None = None
    substeps: int = 2
    real_time_factor: float = 0.0
    lockstep: bool = True
    lockstep_timeout: float = 2.0
    startup_timeout: float = 30.0
    timeout: float | None = None
    environment: str = "paper"
    env_options: FullEnvironmentOptions | None = None
    field_file: Path | None = None
    bag: Path | None = None
    bag_topics: tuple | None = None
    bag_exclude: str | None = None
    time_origin_ns: int = 0
    foxglove: int | None = None
    domain_id: int | None = None
    log_dir: Path | None = None
    results: Path | None = None
    #: DDS network scope of the nodes: loopback (default) or all (process.dds_env)
    dds_interfaces: str = "loopback"
    #: extra ROS parameters per node name (every satellite): simulator, attitude_sensors, controller
    node_params: dict = _field(default_factory=dict)
    #: fly the flight modes: the mode manager brings the managed nodes up and runs ModeLogic
    modes: bool = False
    #: the first mode (mode manager and controller)
    initial_mode: str = POINTING
    #: the mode manager's parameters (MODE_FIELDS, MANAGER_FIELDS, BDOT_FIELDS), validated
    mode_params: dict = _field(default_factory=dict)
    #: the controller's attitude: "truth" (sensors/attitude, truth plus noise) or "estimator"
    attitude: str = "truth"
    #: injected faults (design.faults.Fault), every satellite
    faults: tuple = ()
    #: the torquers' coupling and duty cycle (TORQUER_FIELDS given), every satellite's simulator,
    #: sensors and controller
    torquers: dict = _field(default_factory=dict)
    #: node -> parameters of the hardware file (design.hardware.Hardware.node_parameters); empty without one
    hardware_params: dict = _field(default_factory=dict)

    @classmethod
    def build(cls, satellites: dict, request: SilRequest | None = None) -> "SilScenario":
        """Read and validate every input of a run, once.

        Parameters
        ----------
        satellites : dict
            Namespace -> gains file (``{"": path}``: one satellite in the root namespace).
        request : SilRequest, optional
            What is asked of the run (default: ``SilRequest()``, the paper's 5-orbit run).

        Returns
        -------
        SilScenario
            The validated scenario.

        Raises
        ------
        ConfigError
            A bad input (one line naming the option or file and field).
        SilError
            An unsupported combination.
        """
        req = request or SilRequest()
        sats = {normalize_namespace(ns): Path(g) for ns, g in satellites.items()}
        if not satellites or len(sats) != len(satellites):
            raise ConfigError("--gains", None, "two satellites with the same namespace" if sats else "no satellite given")
        # one read per file: the rcl-compatibility check returns the parameters the schema validates
        gains_params = {ns: check_ros_params(g, CONTROLLER_NODE) for ns, g in sats.items()}
        gains = {ns: Gains.from_mapping(gains_params[ns], g) for ns, g in sats.items()}
        sc_doc = load_ros_params(req.spacecraft)
        sc = SpacecraftParams.from_mapping(merge_ros_params(sc_doc), req.spacecraft, strict=True,
                                           base_dir=Path(req.spacecraft).parent)
        warn_tle(sc, req.spacecraft)
        hw = load_hardware(req.hardware) if req.hardware is not None else None
        if hw is not None:
            check_spacecraft_agrees(hw, sc_doc, req.spacecraft)
        simulator_params, substeps = initial_state_parameters(
            sc, dict(req.simulator_params or {}), req.initial_attitude_deg, req.initial_rate_deg, req.substeps,
            run_sample_period(req.ts, sc, gains))
        mode, mparams = check_modes_arguments(req.modes, req.initial_mode, req.mode_params)
        sensor_params, eparams = check_attitude_arguments(req.attitude, req.sensor_params, req.estimator_params,
                                                          req.field, hw and hw.sensor_parameters())
        check_run_arguments(orbits=req.orbits, steps=req.steps, substeps=substeps, real_time_factor=req.real_time_factor,
                            timeout=req.timeout, lockstep_timeout=req.lockstep_timeout)
        sat_list = []
        for ns, g in sats.items():
            sat_ts = float(req.ts if req.ts is not None else gains[ns].ts)
            check_sample_period(sat_ts, sc, "--ts" if req.ts is not None else f"{g}: field 'ts'")
            sat_list.append(Satellite(ns, g, gains[ns], gains_params[ns], sat_ts))
        check_outputs(req)
        opts, sc = check_environment(req, sc)
        if opts is not None:  # IGRF along the whole run: its last step inside the field model's years, before any node
            last = max(s.ts for s in sat_list) * (req.steps if req.steps else math.ceil(req.orbits * sc.orbit_period))
            check_field_epoch(sc.epoch + _dt.timedelta(seconds=float(last)), req.spacecraft,
                              "epoch (the run's last step, --orbits/--steps after it)")
        hw_params = hw.node_parameters() if hw is not None else {}
        simulator = {**merge_ros_params(sc_doc, "simulator"), **hw_params.get("simulator", {})}  # its rods' limits
        faults = check_fault_arguments(req.faults, req.epoch_time, steps=req.steps, orbits=req.orbits,
                                       ts=[s.ts for s in sat_list], period=sc.orbit_period,
                                       dipole_limit=simulator.get("dipole_limit", DIPOLE_LIMIT.default))
        time_origin_ns = epoch_ns(sc.epoch) if req.epoch_time else 0
        if time_origin_ns and (len(sats) > 1 or "" not in sats):
            raise ConfigError("--epoch-time", None, "one satellite at a time (the recorder follows one clock)")
        return cls(tuple(sat_list), Path(req.spacecraft), sc, sc_doc, orbits=req.orbits, steps=req.steps,
                   substeps=substeps, real_time_factor=req.real_time_factor, lockstep=req.lockstep,
                   lockstep_timeout=req.lockstep_timeout, startup_timeout=req.startup_timeout, timeout=req.timeout,
                   environment=req.environment, env_options=opts,
                   field_file=Path(req.field) if req.field is not None else None,
                   bag=Path(req.bag) if req.bag else None, bag_topics=tuple(req.bag_topics) if req.bag_topics else None,
                   bag_exclude=req.bag_exclude, time_origin_ns=int(time_origin_ns),
                   foxglove=None if req.foxglove is None else int(req.foxglove), domain_id=req.domain_id,
                   log_dir=Path(req.log_dir) if req.log_dir else None,
                   results=Path(req.results) if req.results else None, dds_interfaces=req.dds_interfaces,
                   node_params={"simulator": simulator_params, "attitude_sensors": dict(sensor_params or {}),
                                "controller": dict(req.controller_params or {}), ESTIMATOR: eparams},
                   modes=bool(req.modes), initial_mode=mode, mode_params=mparams, attitude=req.attitude, faults=faults,
                   torquers=check_torquer_arguments(req.torquers, [s.ts for s in sat_list], req.torquers_source),
                   hardware_params=hw_params)

    # ------------------------------------------------------------------ derived
    @property
    def multi(self) -> bool:
        """Several satellites, or one outside the root namespace (topics and files get a tag)."""
        return len(self.satellites) > 1 or self.satellites[0].namespace != ""

    @property
    def nodes(self) -> tuple[str, ...]:
        """The nodes of one satellite in start order (the mode manager last, with ``modes``)."""
        nodes = NODES[:-1] + ((ESTIMATOR,) if self.attitude == "estimator" else ()) + NODES[-1:]
        return nodes + ((MODE_MANAGER,) if self.modes else ())

    def remaps(self, node: str) -> list[str]:
        """Extra ``-r`` arguments of ``node``: with the estimator the controller and the mode manager read its estimate."""
        if self.attitude == "estimator" and node in ("controller", MODE_MANAGER):
            return ["-r", f"{TOPIC_ATTITUDE}:={TOPIC_ESTIMATE}"]
        return []

    @property
    def outputs_read(self) -> bool:
        """Whether anything may read the simulator's outputs for viewers (/tf, sim/markers, sim/*_torque): a
        recorder, the live view, or a user's tool on a domain they chose. Otherwise the run's domain is its own
        (process.DomainLock) and nothing can."""
        return bool(self.bag) or self.foxglove is not None or self.domain_id is not None

    @property
    def n_steps(self) -> float:
        """Controller steps of the run (the slowest satellite's count when their Ts differ)."""
        return self.steps or self.orbits * self.spacecraft.orbit_period / min(s.ts for s in self.satellites)

    def results_path(self, sat: Satellite, log_dir: Path) -> Path:
        """Where the simulator of ``sat`` writes its trajectory (``results``, tagged per satellite)."""
        ns = sat.namespace
        if self.results:
            r = self.results
            return r.with_name(f"{r.stem}_{tag(ns)}{r.suffix}") if self.multi and ns else r
        return log_dir / (f"results_{tag(ns)}.npz" if ns else "results.npz")

    def _spacecraft_params(self, node: str) -> dict:
        """The spacecraft file's parameters for ``node`` (fully qualified), with the derived period; a
        ``tle_file`` becomes its lines (``tle``: the node's parameter file lives elsewhere)."""
        params = {k: _plain(v) for k, v in merge_ros_params(self.spacecraft_doc, node).items()}
        params["orbit_period"] = float(self.spacecraft.orbit_period)
        if params.pop("tle_file", ""):
            tle = self.spacecraft.tle
            params["tle"] = ([tle.name] if tle.name else []) + [tle.line1, tle.line2]
        return params

    def peer_wait(self) -> float:
        """The simulator's wait for its peers [wall s]: with the mode manager, longer by the manager's bring-up limit
        (the longest it waits for nodes that answer), so a node that does not come up is named by the manager's
        bring-up error rather than by the simulator's "no subscriber/controller matched"."""
        if not self.modes:
            return float(self.startup_timeout)
        manager = {f.name: f.default for f in MANAGER_FIELDS}
        return float(self.startup_timeout) + float(self.mode_params.get("bringup_limit", manager["bringup_limit"]))

    def node_parameters(self, sat: Satellite, results_path: Path) -> dict[str, dict]:
        """The ROS parameters of each node of ``sat``: node name -> {name: value}."""
        common = {"use_sim_time": True, "ts": float(sat.ts)}
        sim = dict(common, time_origin_ns=int(self.time_origin_ns), substeps=int(self.substeps),
                   lockstep=bool(self.lockstep), lockstep_timeout=float(self.lockstep_timeout),
                   startup_timeout=self.peer_wait(), real_time_factor=float(self.real_time_factor),
                   results_path=str(results_path.resolve()))
        if self.bag:
            sim["min_truth_subscribers"] = 2  # the recorder must be listening before step 0
        if self.steps:
            sim["steps"] = int(self.steps)
        else:
            sim["orbits"] = float(self.orbits)
        if self.environment == "full":
            o = self.env_options
            sim.update(environment="full", env_gravity_gradient=bool(o.gravity_gradient), env_drag=bool(o.drag),
                       env_srp=bool(o.srp), env_field=str(o.field), igrf_degree=int(o.igrf_degree))
        elif self.field_file is not None:
            sim["field_file"] = str(self.field_file.resolve())
        own = {"simulator": sim, "attitude_sensors": dict(common), "controller": dict(common, initial_mode=self.initial_mode),
               ESTIMATOR: dict(common, environment=self.environment, time_origin_ns=int(self.time_origin_ns))}
        if self.environment == "full":
            own[ESTIMATOR]["igrf_degree"] = int(self.env_options.igrf_degree)
        sensor_faults = [f.spec for f in self.faults if f.kind in fl.SENSOR_KINDS]
        sim_faults = [f.spec for f in self.faults if f.kind not in fl.SENSOR_KINDS]  # torquers, the kill
        if sensor_faults:
            own["attitude_sensors"]["faults"] = sensor_faults
        if sim_faults:
            sim["faults"] = sim_faults
        for node in ("simulator", "attitude_sensors", "controller", ESTIMATOR):  # one schema, the same values
            own[node].update(self.torquers)
        if self.modes:  # the managed nodes wait for the mode manager's transitions
            bd = {k: v for k, v in self.mode_params.items() if k in {f.name for f in BDOT_FIELDS}}
            own["attitude_sensors"]["autostart"] = own["controller"]["autostart"] = False
            own["controller"].update(bd)
            own[MODE_MANAGER] = dict(common, initial_mode=self.initial_mode, **self.mode_params)
            if self.attitude == "estimator":  # managed too; an estimate counts only while valid
                own[ESTIMATOR].update(autostart=False, validity_gate=True)
                own[MODE_MANAGER]["managed_nodes"] = ["attitude_sensors", ESTIMATOR, "controller"]
        out = {}
        for node in self.nodes:
            params = self._spacecraft_params(f"{sat.namespace}/{node}")
            params.update(self.hardware_params.get(node, {}))  # the hardware file's layer (design.hardware)
            if node == "simulator" and not self.outputs_read:
                params = {**UNREAD_OUTPUTS_OFF, **params}  # the spacecraft file's simulator section still wins
            if node == "controller":
                params.update({k: _plain(v) for k, v in sat.gains_params.items()})
            out[node] = {**params, **own[node], **self.node_params.get(node, {})}
        return out

    def write_parameter_files(self, sat: Satellite, log_dir: Path, results_path: Path) -> dict[str, Path]:
        """One parameter file per node of ``sat`` in ``log_dir``, keyed ``/**/<node>`` (applies under
        any namespace, :func:`magtune_core.base.paramfile.node_matches`).

        Returns
        -------
        dict
            node name -> the file written.
        """
        out = {}
        prefix = f"{tag(sat.namespace)}_" if sat.namespace else ""
        for node, params in self.node_parameters(sat, results_path).items():
            path = log_dir / f"{prefix}{node}.params.yaml"
            path.write_text(yaml.safe_dump({f"/**/{node}": {"ros__parameters": params}}, sort_keys=False))
            out[node] = path
        return out
