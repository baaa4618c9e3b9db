"""``magtune sil``: software-in-the-loop run of the ROS 2 nodes (lockstep, sim time)."""
from __future__ import annotations

import argparse

from ..base import jsonout
from ..base.errors import ConfigError
from ..design.faults import parse_spec
from ..ros import sil
from ..ros.process import DDS_INTERFACES
from ..ros.scenario import SilRequest, SilScenario, load_scenario_file, normalize_namespace
from .common import CommandError, add_environment_arguments, add_hardware_argument, environment_options, plain_summary

#: The ROS_DOMAIN_IDs whose DDS (RTPS) ports fit in 16 bits: 7400 + 250 x id + offsets <= 65535.
DOMAIN_ID_MIN, DOMAIN_ID_MAX = 0, 232


def register(sub) -> None:
    p = sub.add_parser("sil", help="software-in-the-loop run of the ROS 2 nodes (lockstep, sim time)",
                       description=plain_summary(sil.__doc__))
    p.add_argument("--gains", required=True, nargs="+", metavar="[NS=]FILE",
                   help="controller gains parameter file (config/gains/sigma_*.yaml); several satellites side by "
                        "side in one domain as NS=FILE each, e.g. sat1=config/gains/sigma_60.yaml "
                        "sat2=config/gains/sigma_240.yaml (each in namespace /NS with its own clock /NS/clock)")
    p.add_argument("--orbits", type=float, default=5.0, help="run length in orbits (default 5)")
    p.add_argument("--steps", type=int, default=None, help="run length in controller steps (overrides --orbits)")
    p.add_argument("--ts", type=float, default=None, help="controller sample period [s] (default: gains file ts)")
    p.add_argument("--substeps", type=int, default=None,
                   help="RK4 sub-steps per sample period (default: from the initial rate, |w| h <= 0.05 rad, at "
                        "least 2: 2 for the paper's dw(0); docs/modes.md)")
    p.add_argument("--initial-rate-deg", type=_triple("--initial-rate-deg"), default=None, metavar="X,Y,Z",
                   help="initial rate deviation dw(0) [deg/s, body axes] from the orbit-following rate "
                        "(default: the paper's dw(0) = [1e-3, 2e-3, 0] rad/s)")
    p.add_argument("--initial-attitude-deg", type=_triple("--initial-attitude-deg"), default=None, metavar="RX,RY,RZ",
                   help="initial attitude as a rotation vector [deg] (axis x angle, at most 180 deg) of the body "
                        "w.r.t. the orbital axes (default: aligned)")
    p.add_argument("--modes", action=argparse.BooleanOptionalAction, default=None,
                   help="fly the flight modes: start the mode manager (lifecycle bring-up, ModeLogic, health "
                        "monitor) in DETUMBLE; without it the controller flies POINTING (the paper's run). "
                        "Default: on when --initial-rate-deg or --initial-attitude-deg is given (a deployment), "
                        "off otherwise; --no-modes flies eq. 17 from any initial state")
    p.add_argument("--initial-mode", default=None, metavar="MODE",
                   help="with --modes: the first mode (DETUMBLE, ACQUISITION, POINTING, SAFE; default DETUMBLE, a "
                        "deployment; POINTING starts a settled satellite, e.g. to inject a fault)")
    p.add_argument("--attitude", choices=("truth", "estimator"), default="truth",
                   help="the controller's attitude: truth (sensors/attitude: truth plus attitude_noise_std, the "
                        "default) or estimator (the attitude_estimator node's MEKF on gyro, magnetometer, sun sensor "
                        "and position fix, with the estimator's default sensors: docs/estimation.md)")
    p.add_argument("--estimator-param", action="append", default=[], metavar="NAME=VALUE",
                   help="with --attitude estimator: an attitude_estimator parameter (ESTIMATOR_FIELDS, YAML value), "
                        "e.g. gate_probability=0.999; repeatable")
    p.add_argument("--fault", action="append", default=[], metavar="KIND@T[:DURATION][,axis=A][,value=V]",
                   help="inject a fault at sim time T [s] (repeatable): mag_stuck, mag_spike, mag_bias, mag_dropout "
                        "(DURATION required), gyro_bias, torquer_dead, torquer_stuck, sensors_killed; e.g. "
                        "mag_dropout@3000:30, gyro_bias@100,axis=z,value=0.02, torquer_dead@500,axis=y "
                        "(docs/modes.md#faults)")
    p.add_argument("--scenario", default=None, metavar="FILE",
                   help="scenario file: YAML with a 'faults:' list of {kind, t, duration, axis, value} (added to "
                        "--fault) and a 'torquers:' mapping (torquer_coupling, torquer_off_time, torquer_decay_time, "
                        "duty_compensation; docs/torquers.md)")
    p.add_argument("--spacecraft", "--config", dest="spacecraft", default=None,
                   help="spacecraft/orbit parameter file (default: the global --config, config/spacecraft.yaml)")
    add_hardware_argument(p)
    p.add_argument("--field", metavar="FILE", default=None,
                   help="paper environment: simulate this field file (magtune fit-field output) instead of the "
                        "spacecraft's field_model (the full environment keeps IGRF along the orbit)")
    p.add_argument("--rtf", type=float, default=0.0, help="pace at this real-time factor (default 0: max speed)")
    p.add_argument("--lockstep-timeout", type=float, default=2.0, metavar="S",
                   help="wall seconds the simulator waits for a step's command before it holds the last one and "
                        "counts a missed step (default 2): a step nobody answered, e.g. a killed or deactivated "
                        "controller or sensors node, or an input it rejected. A magnetometer dropout costs nothing: "
                        "the controller answers each sample without a field at once (held dipole, then zero)")
    p.add_argument("--bag", default=None, help="record the run to this MCAP bag (needs the recorder node)")
    p.add_argument("--bag-topics", nargs="+", default=None, metavar="TOPIC",
                   help="with --bag: record only these topics (/name or /name:pkg/msg/Type; default: every project topic)")
    p.add_argument("--bag-exclude", default=None, metavar="REGEX",
                   help="with --bag: leave out the topics matching REGEX (e.g. '^/sim/markers$')")
    p.add_argument("--epoch-time", action="store_true",
                   help="stamp the run from the spacecraft file's epoch (real dates in bags and Foxglove) "
                        "instead of from 0")
    p.add_argument("--foxglove", type=int, nargs="?", const=8765, default=None, metavar="PORT",
                   help="stream the run live to Foxglove: WebSocket server on localhost:PORT (default 8765); "
                        "pace with --rtf to watch it")
    p.add_argument("--results", default=None, help="keep the trajectory .npz here")
    p.add_argument("--log-dir", default=None, help="node logs and generated parameters (default: temp dir)")
    p.add_argument("--dds-interfaces", choices=DDS_INTERFACES, default="loopback",
                   help="DDS network scope of the nodes: loopback (default: every DDS socket on 127.0.0.1) or all "
                        "(nodes or viewers on other hosts; docs/reliability.md)")
    p.add_argument("--domain-id", type=int, default=None,
                   help=f"ROS_DOMAIN_ID, {DOMAIN_ID_MIN}-{DOMAIN_ID_MAX} (the ids whose DDS ports fit in 16 bits; "
                        "default: a free one)")
    p.add_argument("--timeout", type=float, default=None, help="abort after this many wall seconds")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    add_environment_arguments(p)
    p.set_defaults(func=run)


def check_domain_id(domain_id: int | None) -> None:
    """``--domain-id`` within :data:`DOMAIN_ID_MIN`..:data:`DOMAIN_ID_MAX` (a larger id passed the
    checks and the nodes died in DDS, "Calculated port number is too high"); None is a free one.

    Raises
    ------
    ConfigError
        one line naming the option and the range (exit 2, before any node starts).
    """
    if domain_id is not None and not DOMAIN_ID_MIN <= domain_id <= DOMAIN_ID_MAX:
        raise ConfigError("--domain-id", None, f"{domain_id}: expected a ROS_DOMAIN_ID in {DOMAIN_ID_MIN}-"
                                               f"{DOMAIN_ID_MAX} (larger ids give DDS ports above 65535)")


def _spacecraft(args) -> str:
    """--spacecraft/--config of the subcommand, else the global --config (the repository's by default)."""
    return args.spacecraft or args.config


def run(args) -> int:
    import sys

    def progress(k, n):  # one line per tenth of the run (the simulator's own step log)
        if not args.quiet:
            print(f"magtune sil: step {k}/{n} ({100 * k // max(n, 1)} %)", file=sys.stderr, flush=True)

    check_domain_id(args.domain_id)
    sats = satellites(args.gains)
    scen = load_scenario_file(args.scenario) if args.scenario else {"faults": (), "torquers": {},
                                                                    "torquers_source": "torquers"}
    faults = list(scen["faults"])
    faults += [parse_spec(f) for f in args.fault]
    # every input validated before anything starts (one line and exit 2 for a bad one)
    scenario = SilScenario.build(sats, SilRequest(orbits=args.orbits, steps=args.steps, ts=args.ts, substeps=args.substeps,
                                 spacecraft=_spacecraft(args), real_time_factor=args.rtf, bag=args.bag,
                                 lockstep_timeout=args.lockstep_timeout,
                                 results=args.results, log_dir=args.log_dir, domain_id=args.domain_id,
                                 timeout=args.timeout, environment=args.environment,
                                 env_options=environment_options(args), field=args.field, epoch_time=args.epoch_time,
                                 foxglove=args.foxglove, bag_topics=args.bag_topics, bag_exclude=args.bag_exclude,
                                 dds_interfaces=args.dds_interfaces, initial_rate_deg=args.initial_rate_deg,
                                 initial_attitude_deg=args.initial_attitude_deg, modes=_modes(args),
                                 initial_mode=args.initial_mode,
                                 attitude=args.attitude, estimator_params=_assignments(args.estimator_param),
                                 faults=faults, torquers=scen["torquers"],
                                 torquers_source=scen["torquers_source"], hardware=args.hardware))
    if not args.quiet:
        print("magtune sil: starting the nodes (discovery takes a few seconds)", file=sys.stderr, flush=True)
        if args.foxglove is not None:
            print(f"magtune sil: Foxglove live view at ws://127.0.0.1:{args.foxglove} (Open connection -> "
                  "Foxglove WebSocket; layout docs/foxglove_layout.json)", file=sys.stderr, flush=True)
    runs = sil.run_fleet(scenario, progress=progress)
    def as_json(res):
        return dict(res.figures, **{"missed_steps": res.counters.get("missed_steps", 0),
                                    "wall_time": res.wall_time, "real_time_factor": res.real_time_factor,
                                    "counters": res.counters, "log_dir": str(res.log_dir) if res.log_dir else None})

    if list(runs) == [""]:  # one satellite, root namespace: the summary as before
        print(jsonout.dumps(as_json(runs[""])) if args.json else runs[""].summary())
    elif args.json:
        print(jsonout.dumps({ns or "/": as_json(r) for ns, r in runs.items()}))
    else:
        for ns, r in runs.items():
            print(f"== {ns or '/'} ({sats.get(ns, '')})\n{r.summary()}")
    return 0


def _assignments(items: list[str]) -> dict:
    """``NAME=VALUE`` strings -> {name: YAML value} (one line, exit 2, for a malformed one)."""
    import yaml

    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise CommandError(f"--estimator-param: expected NAME=VALUE, got {item!r}", code=2)
        try:
            out[name.strip()] = yaml.safe_load(value)
        except yaml.YAMLError:
            raise CommandError(f"--estimator-param {name}: not a YAML value: {value!r}", code=2) from None
    return out


def _triple(flag: str):
    """argparse type of ``X,Y,Z``: three finite numbers (a bad one: one line naming the flag, exit 2)."""
    import argparse
    import math

    def parse(text: str):
        try:
            v = tuple(float(x) for x in text.split(","))
        except ValueError:
            v = ()
        if len(v) != 3 or not all(math.isfinite(x) for x in v):
            raise argparse.ArgumentTypeError(f"expected three numbers X,Y,Z, got {text!r}")
        return v
    parse.__name__ = flag
    return parse


def satellites(values: list[str]) -> dict:
    """``--gains`` values -> {namespace: gains file}: ``FILE`` is the root namespace, ``NS=FILE``
    the namespace /NS (normalized and checked by :func:`magtune_core.ros.scenario.normalize_namespace`)."""
    out: dict = {}
    for v in values:
        ns, sep, path = v.partition("=")
        ns, path = (ns, path) if sep else ("", v)
        ns = normalize_namespace(ns)
        if ns in out:
            raise CommandError(f"--gains: namespace {ns or '/'} given twice", code=2)
        out[ns] = path
    return out


def _modes(args) -> bool:
    """--modes / --no-modes as given; else on for a deployment (an initial rate or attitude given)."""
    if args.modes is not None:
        return bool(args.modes)
    return args.initial_rate_deg is not None or args.initial_attitude_deg is not None
