"""Software-in-the-loop runner: the three magtune_ros nodes as separate processes over DDS.

``magtune sil --gains config/gains/sigma_60.yaml --orbits 5 --ts 1 [--bag bags/NAME]``
(also ``python -m magtune_core.sil ...``).

Subprocesses only: this module never imports rclpy. Executables are resolved as ``ros2 run``
does (``<prefix>/lib/magtune_ros/<exe>`` for the first prefix of AMENT_PREFIX_PATH holding the
package's ament index marker). Each run gets a ROS_DOMAIN_ID of its own (held by a lock file,
so concurrent runs never share a domain) and ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST. Every
node runs in its own process group, stopped in a ``finally`` block (SIGINT, then SIGTERM,
then SIGKILL), so neither Ctrl-C nor a failing node leaves orphans.

The simulator runs in lockstep with the controller (see magtune_ros/simulator.py) and writes
its trajectory to an .npz (``SimResult``), from which the summary (paper section 5
figures: final and peak |dq_R|, RMS over orbits 2-5, peak |m|) is computed.
"""
from __future__ import annotations

import argparse
import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

PACKAGE = "magtune_ros"
NODES = ("controller", "attitude_sensors", "simulator")
#: Recorder executable of the bags helper, started first with
#: ``--ros-args -p use_sim_time:=true -p path:=<bag>`` when --bag is given; the simulator then
#: waits for a second subscriber of sim/truth before step 0 and the recorder is stopped with
#: SIGINT after the simulator finished (so it can close the MCAP file).
RECORDER_EXE = "recorder"
#: Override as "package/executable" (e.g. MAGTUNE_RECORDER=magtune_bags/recorder).
RECORDER_ENV = "MAGTUNE_RECORDER"


def recorder_args(bag, custom: dict | None = None) -> list[str]:
    """ROS arguments of the recorder process; ``custom`` goes to metadata.yaml custom_data."""
    args = ["-p", "use_sim_time:=true", "-p", f"path:={Path(bag).resolve()}"]
    if custom:
        items = ", ".join(f"'{k}={v}'" for k, v in custom.items())
        args += ["-p", f"custom_data:=[{items}]"]
    return args
ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SPACECRAFT = ROOT / "config" / "spacecraft.yaml"
#: ROS_DOMAIN_IDs handed out to runs: 215-232 map Fast DDS ports above Linux's ephemeral range
#: (32768-60999), the other range the ROS 2 docs call safe besides 0-101, which other tools use.
DOMAIN_RANGE = range(215, 233)


class SilError(RuntimeError):
    """The SIL run could not be started or a node failed."""


# ------------------------------------------------------------------ resolution
def ament_prefixes() -> list[Path]:
    prefixes = [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    fallback = ROOT / "ros2_ws" / "install" / PACKAGE
    if fallback not in prefixes:
        prefixes.append(fallback)  # the project's own workspace, built by scripts/bootstrap.sh
    return prefixes


def package_prefix(package: str = PACKAGE) -> Path:
    """The install prefix of ``package`` from the ament resource index (as ament_index_python)."""
    for prefix in ament_prefixes():
        if (prefix / "share" / "ament_index" / "resource_index" / "packages" / package).is_file():
            return prefix
    raise SilError(f"package '{package}' not found in AMENT_PREFIX_PATH; run 'bash scripts/bootstrap.sh' "
                   f"and '. scripts/env.sh'")


def resolve_executable(exe: str, package: str = PACKAGE) -> Path:
    """<prefix>/lib/<package>/<exe>, exactly where ``ros2 run <package> <exe>`` looks."""
    path = package_prefix(package) / "lib" / package / exe
    if not (path.is_file() and os.access(path, os.X_OK)):
        raise SilError(f"executable '{exe}' of package '{package}' not found at {path}")
    return path


def child_env(domain_id: int, prefix: Path, *more: Path) -> dict:
    """Environment of the node processes: isolated domain, localhost discovery, package paths."""
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_STATIC_PEERS", None)
    mine = [str(x) for x in (prefix, *more)]
    amp = mine + [p for p in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p and p not in mine]
    env["AMENT_PREFIX_PATH"] = os.pathsep.join(amp)
    pyver = f"python{sys.version_info.major}.{sys.version_info.minor}"
    sites = [str(Path(x) / "lib" / pyver / "site-packages") for x in mine]
    pp = sites + [str(ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
    env["PYTHONPATH"] = os.pathsep.join(pp)
    env.setdefault("RCUTILS_LOGGING_BUFFERED_STREAM", "1")
    return env


class DomainLock:
    """Reserve a ROS_DOMAIN_ID for this run with an exclusive lock file in the temp directory."""

    def __init__(self, domain_id: int | None = None):
        self.fh = None
        ids = [domain_id] if domain_id is not None else list(DOMAIN_RANGE)
        start = os.getpid() % len(ids)
        for did in ids[start:] + ids[:start]:
            fh = open(Path(tempfile.gettempdir()) / f"magtune_ros_domain_{did}.lock", "w")
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                fh.close()
                continue
            self.fh, self.domain_id = fh, did
            return
        raise SilError(f"no free ROS_DOMAIN_ID in {ids[0]}..{ids[-1]}")

    def release(self):
        if self.fh:
            self.fh.close()
            self.fh = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()


# ------------------------------------------------------------------ processes
@dataclass
class NodeProcess:
    name: str
    popen: subprocess.Popen
    log: Path

    def tail(self, n: int = 5) -> str:
        try:
            lines = self.log.read_text(errors="replace").strip().splitlines()
        except OSError:
            return ""
        return "\n".join(lines[-n:])


def start_node(name: str, exe: Path, ros_args: list[str], env: dict, log_dir: Path) -> NodeProcess:
    log = log_dir / f"{name}.log"
    with open(log, "wb") as fh:
        p = subprocess.Popen([str(exe), "--ros-args", *ros_args], env=env, stdout=fh, stderr=subprocess.STDOUT,
                             stdin=subprocess.DEVNULL, start_new_session=True)
    return NodeProcess(name, p, log)


def stop_nodes(procs: list[NodeProcess], grace: float = 5.0) -> None:
    """SIGINT each process group, then SIGTERM, then SIGKILL; reap everything."""
    for sig, wait in ((signal.SIGINT, grace), (signal.SIGTERM, 2.0), (signal.SIGKILL, 2.0)):
        alive = [p for p in procs if p.popen.poll() is None]
        if not alive:
            break
        for p in alive:
            try:
                os.killpg(p.popen.pid, sig)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + wait
        for p in alive:
            try:
                p.popen.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
    for p in procs:  # group leftovers (e.g. grandchildren) after the leader exited
        try:
            os.killpg(p.popen.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass


# ------------------------------------------------------------------ run
def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt(f"signal {signum}")


@dataclass
class SilRun:
    """Outcome of a SIL run: the simulator's trajectory, its figures of merit and counters."""

    result: object  # magtune_core.simulate.SimResult
    figures: dict
    counters: dict
    wall_time: float        # simulator's stepping time (after discovery)
    total_wall_time: float  # including process start-up and shutdown
    domain_id: int
    log_dir: Path | None  # None: temporary logs removed after success
    diagnostics: dict = field(default_factory=dict)

    @property
    def real_time_factor(self) -> float:
        return float(self.result.t[-1]) / max(self.wall_time, 1e-9)

    def summary(self) -> str:
        from .simulate import format_figures

        return (f"{format_figures(self.figures)}\n"
                f"missed steps {self.counters.get('missed_steps', 0)}  steps {self.counters.get('steps', 0)}  "
                f"wall {self.wall_time:.2f} s (total {self.total_wall_time:.2f} s)  "
                f"real-time factor {self.real_time_factor:.0f}x")


def run_sil(gains, *, orbits: float = 5.0, steps: int | None = None, ts: float | None = None,
            spacecraft=DEFAULT_SPACECRAFT, substeps: int = 2, bag=None, real_time_factor: float = 0.0,
            lockstep: bool = True, lockstep_timeout: float = 2.0, startup_timeout: float = 30.0,
            timeout: float | None = None, domain_id: int | None = None, log_dir=None, results=None,
            simulator_params: dict | None = None, sensor_params: dict | None = None,
            controller_params: dict | None = None, on_start=None, environment: str = "paper",
            env_options=None) -> SilRun:
    """Start controller, attitude_sensors and simulator (+ recorder with ``bag``), wait, clean up.

    ``timeout`` (wall s, default generous) bounds the whole run; parameters dicts are extra
    ROS parameters per node. Raises SilError naming the failing node and its last log lines.
    ``environment`` "paper" (default) or "full" with ``env_options`` a
    ``fullenv.FullEnvironmentOptions``: the simulator builds the full environment and every node
    gets the actual orbit's nominal period (``fullenv.full_params``), as the offline
    ``simulate(..., environment="full")``.
    """
    from .simulate import SimResult, figures_of_merit

    gains = Path(gains)
    if not gains.is_file():
        raise SilError(f"gains file not found: {gains}")
    from .params import ConfigError
    from .rosparams import check_ros_params

    for f in (gains, spacecraft):
        if f:
            try:
                check_ros_params(f)
            except ConfigError as exc:
                raise SilError(str(exc)) from None
    prefix = package_prefix()
    exes = {n: resolve_executable(n) for n in NODES}
    rec_exe = None
    if bag:
        try:
            rpkg, _, rexe = os.environ.get(RECORDER_ENV, f"{PACKAGE}/{RECORDER_EXE}").rpartition("/")
            rec_exe = resolve_executable(rexe, rpkg or PACKAGE)
        except SilError as exc:
            raise SilError(f"--bag needs a recorder executable ({exc}); set {RECORDER_ENV}=package/executable "
                           "if it lives elsewhere") from None
    own_dir = not log_dir  # a temporary log directory is removed after a successful run
    log_dir = Path(log_dir) if log_dir else Path(tempfile.mkdtemp(prefix="magtune_sil_"))
    log_dir.mkdir(parents=True, exist_ok=True)
    results = Path(results) if results else log_dir / "results.npz"  # loaded into memory before cleanup
    if results.exists():
        results.unlink()

    common = {"use_sim_time": True}
    sim = dict(common, substeps=int(substeps), results_path=str(results.resolve()), lockstep=bool(lockstep),
               lockstep_timeout=float(lockstep_timeout), startup_timeout=float(startup_timeout),
               real_time_factor=float(real_time_factor))
    if rec_exe:
        sim["min_truth_subscribers"] = 2  # the recorder must be listening before step 0
    if steps:
        sim["steps"] = int(steps)
    else:
        sim["orbits"] = float(orbits)
    if ts is not None:
        common_ts = {"ts": float(ts)}
    else:
        from .gains import load_gains
        from .params import ConfigError

        try:
            common_ts = {"ts": float(load_gains(gains).ts)}
        except ConfigError as exc:
            raise SilError(str(exc)) from None
    env_sim: dict = {}
    if environment == "full":
        from .fullenv import FullEnvironmentOptions, full_params
        from .params import load_spacecraft, SpacecraftParams

        opts = env_options or FullEnvironmentOptions()
        if opts.epoch != FullEnvironmentOptions().epoch or opts.raan_deg or opts.arg_lat_deg or opts.zonal_degree != 2:
            raise SilError("the simulator node takes the default epoch/RAAN/argument of latitude/zonal degree")
        sc_params = load_spacecraft(spacecraft) if spacecraft else SpacecraftParams()
        common["orbit_period"] = float(full_params(sc_params, opts).orbit_period)
        env_sim = dict(environment="full", env_gravity_gradient=bool(opts.gravity_gradient), env_drag=bool(opts.drag),
                       env_srp=bool(opts.srp), env_field=str(opts.field), igrf_degree=int(opts.igrf_degree))
        sim["orbit_period"] = common["orbit_period"]
    elif environment != "paper":
        raise SilError(f"unknown environment {environment!r} (expected 'paper' or 'full')")
    params = {
        "simulator": {**sim, **env_sim, **common_ts, **(simulator_params or {})},
        "attitude_sensors": {**common, **common_ts, **(sensor_params or {})},
        "controller": {**common, **common_ts, **(controller_params or {})},
    }
    pfile = log_dir / "sil_params.yaml"
    pfile.write_text(yaml.safe_dump({k: {"ros__parameters": v} for k, v in params.items()}))
    sc = ["--params-file", str(Path(spacecraft).resolve())] if spacecraft else []

    procs: list[NodeProcess] = []
    lock = DomainLock(domain_id)
    t0 = time.perf_counter()
    old_term = signal.getsignal(signal.SIGTERM)
    if old_term in (signal.SIG_DFL, None):  # turn SIGTERM into KeyboardInterrupt -> finally
        signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        env = child_env(lock.domain_id, prefix, *([rec_exe.parents[2]] if rec_exe else []))
        if rec_exe:
            custom = {"gains": gains.name, **common_ts}
            try:
                from .gains import load_gains
                custom["sigma"] = f"{load_gains(gains).sigma:g}"
            except ValueError:
                pass  # the controller node reports a bad gains file itself
            procs.append(start_node("recorder", rec_exe, recorder_args(bag, custom), env, log_dir))
        procs.append(start_node("controller", exes["controller"],
                                sc + ["--params-file", str(gains.resolve()), "--params-file", str(pfile)], env, log_dir))
        procs.append(start_node("attitude_sensors", exes["attitude_sensors"], sc + ["--params-file", str(pfile)],
                                env, log_dir))
        procs.append(start_node("simulator", exes["simulator"], sc + ["--params-file", str(pfile)], env, log_dir))
        if on_start:
            on_start(lock.domain_id, procs)
        sim_p = procs[-1]
        n_steps = steps or orbits * 5614.8 / (ts or 1.0)
        deadline = time.monotonic() + (timeout if timeout else startup_timeout + 60.0 + 0.05 * n_steps)
        while True:
            rc = sim_p.popen.poll()
            if rc is not None:
                break
            for p in procs[:-1]:
                if p.popen.poll() is not None:
                    raise SilError(f"node '{p.name}' exited with status {p.popen.returncode}:\n{p.tail()}")
            if time.monotonic() > deadline:
                raise SilError(f"SIL run timed out after {time.monotonic() - t0:.0f} s; simulator log:\n{sim_p.tail()}")
            time.sleep(0.05)
        if rc != 0 or not results.is_file():
            raise SilError(f"simulator exited with status {rc}:\n{sim_p.tail()}")
    except SilError as exc:
        raise SilError(f"{exc}\n(node logs in {log_dir})") from None
    finally:
        stop_nodes([p for p in procs if p.name != "recorder"])
        stop_nodes([p for p in procs if p.name == "recorder"], grace=10.0)  # last: let it close the bag
        lock.release()
        if old_term in (signal.SIG_DFL, None):
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
    total = time.perf_counter() - t0
    res = SimResult.from_npz(results)
    counters = json.loads(str(res.info.get("counters", "{}")))
    if own_dir:
        shutil.rmtree(log_dir, ignore_errors=True)
        log_dir = None
    return SilRun(res, figures_of_merit(res), counters, float(res.info.get("wall_time", total)), total,
                  lock.domain_id, log_dir)


# ------------------------------------------------------------------ CLI
def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``sil`` on an argparse subparsers object (``magtune sil ...``)."""
    p = subparsers.add_parser("sil", help="software-in-the-loop run of the ROS 2 nodes (lockstep, sim time)",
                              description=__doc__.split("\n\n")[0])
    add_arguments(p)
    return p


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``magtune sil``; sets ``func``/``handler`` to cmd_sil."""
    p.add_argument("--gains", required=True, help="controller gains parameter file (config/gains/sigma_*.yaml)")
    p.add_argument("--orbits", type=float, default=5.0, help="run length in orbits (default 5)")
    p.add_argument("--steps", type=int, default=None, help="run length in controller steps (overrides --orbits)")
    p.add_argument("--ts", type=float, default=None, help="controller sample period [s] (default: gains file ts)")
    p.add_argument("--substeps", type=int, default=2, help="RK4 sub-steps per sample period (default 2)")
    p.add_argument("--spacecraft", default=str(DEFAULT_SPACECRAFT), help="spacecraft parameter file")
    p.add_argument("--rtf", type=float, default=0.0, help="pace at this real-time factor (default 0: max speed)")
    p.add_argument("--bag", default=None, help="record the run to this MCAP bag (needs the recorder node)")
    p.add_argument("--results", default=None, help="keep the trajectory .npz here")
    p.add_argument("--log-dir", default=None, help="node logs and generated parameters (default: temp dir)")
    p.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: a free one)")
    p.add_argument("--timeout", type=float, default=None, help="abort after this many wall seconds")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_environment_arguments(p)
    p.set_defaults(func=cmd_sil, handler=cmd_sil)


def add_environment_arguments(p: argparse.ArgumentParser) -> None:
    """--environment and the switches of the full environment (shared with ``magtune sampling``)."""
    p.add_argument("--environment", choices=("paper", "full"), default="paper",
                   help="paper: eq. 26 field, circular orbit, GG + residual dipole (default); full: J2 orbit, "
                        "IGRF degree 10, GG with actual r, residual dipole, drag, SRP (docs/environment.md)")
    p.add_argument("--no-drag", action="store_true", help="full environment: switch drag off")
    p.add_argument("--no-srp", action="store_true", help="full environment: switch SRP off")
    p.add_argument("--no-gravity-gradient", action="store_true", help="full environment: switch gravity gradient off")
    from .field import FIELD_MODELS

    p.add_argument("--env-field", default="igrf", choices=("igrf",) + tuple(FIELD_MODELS),
                   help="full environment field: igrf (default) or a periodic model of field.py")
    p.add_argument("--igrf-degree", type=int, default=10, help="full environment: IGRF degree (default 10)")


def environment_options(args):
    """FullEnvironmentOptions from the parsed --environment switches."""
    from .fullenv import FullEnvironmentOptions

    return FullEnvironmentOptions(gravity_gradient=not args.no_gravity_gradient, drag=not args.no_drag,
                                  srp=not args.no_srp, field=args.env_field, igrf_degree=args.igrf_degree)


def cmd_sil(args) -> int:
    try:
        run = run_sil(args.gains, orbits=args.orbits, steps=args.steps, ts=args.ts, substeps=args.substeps,
                      spacecraft=args.spacecraft, real_time_factor=args.rtf, bag=args.bag, results=args.results,
                      log_dir=args.log_dir, domain_id=args.domain_id, timeout=args.timeout,
                      environment=args.environment, env_options=environment_options(args))
    except SilError as exc:
        print(f"magtune sil: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("magtune sil: interrupted; all nodes stopped", file=sys.stderr)
        return 130
    if args.json:
        print(json.dumps(dict(run.figures, **{"missed_steps": run.counters.get("missed_steps", 0),
                                              "wall_time": run.wall_time, "real_time_factor": run.real_time_factor,
                                              "counters": run.counters,
                                              "log_dir": str(run.log_dir) if run.log_dir else None})))
    else:
        print(run.summary())
    return 0


def main(argv=None) -> int:
    from .cli import command_main
    return command_main('sil', argv)


if __name__ == "__main__":
    raise SystemExit(main())
