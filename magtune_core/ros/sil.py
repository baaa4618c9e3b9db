"""Software-in-the-loop runner: the three magtune_ros nodes as separate processes over DDS.

``magtune sil --gains config/gains/sigma_60.yaml --orbits 5 --ts 1 [--bag bags/NAME]``
(the command: :mod:`magtune_core.cli.sil`).

Subprocesses only: this module never imports rclpy. Executables are resolved as ``ros2 run``
does (``<prefix>/lib/magtune_ros/<exe>`` for the first prefix of AMENT_PREFIX_PATH holding the
package's ament index marker). Each run gets a ROS_DOMAIN_ID of its own (held by a lock file,
so concurrent runs never share a domain) and ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST. Every
node runs in its own process group, stopped in a ``finally`` block (SIGINT, then SIGTERM,
then SIGKILL) that a second Ctrl-C, SIGTERM or SIGHUP cannot interrupt; every node also gets
SIGTERM from the kernel if the runner dies (``PR_SET_PDEATHSIG``, so even ``kill -9`` of the
runner leaves no orphan) and inherits the domain lock's descriptor, so the domain is free again
only when the runner and all its nodes are gone.

The simulator runs in lockstep with the controller (see magtune_ros/simulator.py) and writes
its trajectory to an .npz (``SimResult``), from which the summary (paper section 5
figures: final and peak |dq_R|, RMS over orbits 2-5, peak |m|) is computed.
"""
from __future__ import annotations

import ctypes
import fcntl
import json
import math
import os
import re
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from ..base import ament
from ..base.ament import ROOT
from ..base.errors import ConfigError
from ..base.paramfile import check_ros_params
from ..base.topics import topic_specs
from ..design.fitfield import field_for_spacecraft
from ..design.gains import CONTROLLER_NODE, Gains
from ..design.params import SpacecraftParams, check_sample_period
from ..sim.fullenv import FullEnvironmentOptions, full_params
from ..sim.metrics import format_figures
from ..sim.simulate import DIVERGED_EXIT, SimResult

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


DEFAULT_SPACECRAFT = ROOT / "config" / "spacecraft.yaml"
#: ROS_DOMAIN_IDs handed out to runs: 215-232 map Fast DDS ports above Linux's ephemeral range
#: (32768-60999), the other range the ROS 2 docs call safe besides 0-101, which other tools use.
DOMAIN_RANGE = range(215, 233)


def epoch_ns(epoch) -> int:
    """A naive UTC ``datetime`` (the spacecraft file's ``epoch``) in integer ns since 1970."""
    import calendar

    return calendar.timegm(epoch.timetuple()) * 1_000_000_000 + epoch.microsecond * 1000


class SilError(RuntimeError):
    """The SIL run could not be started or a node failed."""


# ------------------------------------------------------------------ resolution
def package_prefix(package: str = PACKAGE) -> Path:
    """The install prefix of ``package`` (:func:`magtune_core.base.ament.package_prefix`)."""
    try:
        return ament.package_prefix(package)
    except ament.AmentNotFound as exc:
        raise SilError(str(exc)) from None


def resolve_executable(exe: str, package: str = PACKAGE) -> Path:
    """<prefix>/lib/<package>/<exe>, exactly where ``ros2 run <package> <exe>`` looks."""
    try:
        return ament.executable(package, exe)
    except ament.AmentNotFound as exc:
        raise SilError(str(exc)) from None


def child_env(domain_id: int, prefix: Path, *more: Path) -> dict:
    """Environment of the node processes: isolated domain, localhost discovery, package paths."""
    env = ament.child_env(prefix, *more)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_STATIC_PEERS", None)
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


PR_SET_PDEATHSIG = 1


def die_with_parent(sig: int = signal.SIGTERM):
    """A ``preexec_fn`` that makes the child receive ``sig`` when the runner dies (Linux
    ``prctl(PR_SET_PDEATHSIG)``), whatever kills the runner, SIGKILL included; SIGTERM lets
    the recorder still close its bag. If the runner already died between fork and this call
    (the child was re-parented), the child signals itself at once."""
    parent = os.getpid()

    def preexec():
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
        except (OSError, AttributeError):  # pragma: no cover - not Linux: the finally still stops the nodes
            return
        if os.getppid() != parent:
            os.kill(os.getpid(), sig)
    return preexec


def start_node(name: str, exe: Path, ros_args: list[str], env: dict, log_dir: Path,
               keep_fds: tuple = (), args=()) -> NodeProcess:
    """Start ``exe [args] --ros-args ros_args`` in its own process group, dying with the runner
    (:func:`die_with_parent`).

    ``keep_fds``: descriptors the node inherits (the domain lock: its flock is then held until
    the runner *and* every node have closed it, so the domain is never handed out while a node
    of this run is still alive, even after a SIGKILL of the runner).
    """
    log = log_dir / f"{name}.log"
    with open(log, "wb") as fh:
        p = subprocess.Popen([str(exe), *args, "--ros-args", *ros_args], env=env, stdout=fh, stderr=subprocess.STDOUT,
                             stdin=subprocess.DEVNULL, start_new_session=True, pass_fds=keep_fds,
                             preexec_fn=die_with_parent())
    return NodeProcess(name, p, log)


def wait_groups_gone(procs: list[NodeProcess], timeout: float = 5.0) -> bool:
    """Wait until no process of the nodes' process groups is left (grandchildren included)."""
    end = time.monotonic() + timeout
    while True:
        alive = []
        for p in procs:
            try:
                os.killpg(p.popen.pid, 0)
                alive.append(p)
            except (ProcessLookupError, PermissionError):
                pass
        if not alive or time.monotonic() > end:
            return not alive
        time.sleep(0.02)


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
    wait_groups_gone(procs)


# ------------------------------------------------------------------ input checks
def _positive_finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0


def check_run_arguments(*, orbits=None, steps=None, substeps=2, real_time_factor=0.0, timeout=None) -> None:
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


def check_writable(path, flag: str, *, directory: bool = False, empty: bool = False) -> None:
    """ConfigError unless ``path`` (a file, or a directory with ``directory``) can be written
    now, so an unwritable output is reported before the run, not after it. Probed for real (a
    temporary file created and removed in the nearest existing directory): permission bits say
    nothing for root or a read-only file system. ``empty``: an existing directory must be empty
    (a bag directory). Nothing is left behind."""
    p = Path(path)
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


class LogProgress:
    """Follows the simulator's log for its ``step k/n`` lines (logged every tenth of the run)
    and hands them to ``callback(k, n)``: progress without another topic or subscriber."""

    PATTERN = re.compile(rb"step (\d+)/(\d+)")

    def __init__(self, log: Path, callback=None):
        self.log, self.callback, self.offset, self.n, self.last = log, callback, 0, 0, -1

    def poll(self) -> None:
        if self.callback is None:
            return
        try:
            with open(self.log, "rb") as fh:
                fh.seek(self.offset)
                data = fh.read()
        except OSError:
            return
        end = data.rfind(b"\n") + 1  # whole lines only
        self.offset += end
        for m in self.PATTERN.finditer(data[:end]):
            k, self.n = int(m.group(1)), int(m.group(2))
            if k > self.last:
                self.last = k
                self.callback(k, self.n)

    def finish(self) -> None:
        self.poll()
        if self.callback is not None and self.n and self.last < self.n:
            self.last = self.n
            self.callback(self.n, self.n)


# ------------------------------------------------------------------ run
def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt(f"signal {signum}")


#: Signals that stop a run: Ctrl-C, ``kill``, closed terminal.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class StopSignals:
    """While running: SIGINT/SIGTERM/SIGHUP raise KeyboardInterrupt (-> the ``finally`` that
    stops the nodes). While stopping (:meth:`shield`): they are noted, not raised, so a second
    Ctrl-C cannot abort the clean-up half-way and leave a node behind (the clean-up is bounded:
    SIGINT, then SIGTERM, then SIGKILL). Only installable from the main thread; elsewhere the
    caller's handlers stay (and the nodes still die with the runner)."""

    def __init__(self):
        self.old: dict = {}
        self.pending: list[int] = []

    def __enter__(self):
        try:
            for s in STOP_SIGNALS:
                self.old[s] = signal.signal(s, _raise_interrupt)
        except ValueError:  # not the main thread
            self.old.clear()
        return self

    def shield(self):
        def note(signum, frame):  # noqa: ARG001
            self.pending.append(signum)
        for s in self.old:
            signal.signal(s, note)

    def __exit__(self, *exc):
        for s, h in self.old.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)


@dataclass
class SilRun:
    """Outcome of a SIL run: the simulator's trajectory, its figures of merit and counters."""

    result: SimResult
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
        return (f"{format_figures(self.figures)}\n"
                f"missed steps {self.counters.get('missed_steps', 0)}  steps {self.counters.get('steps', 0)}  "
                f"wall {self.wall_time:.2f} s (total {self.total_wall_time:.2f} s)  "
                f"real-time factor {self.real_time_factor:.0f}x")


#: A ROS namespace as ``magtune sil --gains NS=FILE`` takes it: tokens of letters, digits, _.
NAMESPACE = re.compile(r"^(/[A-Za-z][A-Za-z0-9_]*)+$")


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


def run_sil(gains, **kwargs) -> SilRun:
    """One satellite in the root namespace: :func:`run_fleet` with ``{"": gains}``.

    Start controller, attitude_sensors and simulator (+ recorder with ``bag``), wait, clean up.
    Keyword arguments as :func:`run_fleet`.
    """
    return run_fleet({"": gains}, **kwargs)[""]


def _tag(ns: str) -> str:
    return ns.strip("/").replace("/", "_")


def run_fleet(satellites: dict, *, orbits: float = 5.0, steps: int | None = None, ts: float | None = None,
              spacecraft=DEFAULT_SPACECRAFT, substeps: int = 2, bag=None, real_time_factor: float = 0.0,
              lockstep: bool = True, lockstep_timeout: float = 2.0, startup_timeout: float = 30.0,
              timeout: float | None = None, domain_id: int | None = None, log_dir=None, results=None,
              simulator_params: dict | None = None, sensor_params: dict | None = None,
              controller_params: dict | None = None, on_start=None, environment: str = "paper",
              env_options=None, field=None, progress=None, epoch_time: bool = False,
              foxglove: int | None = None, bag_topics=None, bag_exclude: str | None = None) -> dict[str, SilRun]:
    """Satellites side by side in one ROS domain, one namespace each (``{"/sat1": gains_a,
    "/sat2": gains_b}``; ``""`` is the root namespace), optionally recorded in one bag.

    Each satellite is its own lockstep simulation: its three nodes run with ``-r __ns:=NS``
    (relative topics become ``NS/sim/truth``, ...) and ``-r /clock:=NS/clock`` (each simulator
    is the time source of its own nodes only; with one satellite in the root namespace nothing
    is remapped). The gains file goes to that satellite's controller only; the SIL's own
    parameters are keyed ``/**/<node>`` so they apply under any namespace. The recorder (with
    ``bag``) subscribes to every satellite's topics and clocks and follows the first satellite's
    clock for log times; every message keeps its own satellite's sim time in its header stamp.

    ``timeout`` (wall s, default generous) bounds the whole run; parameters dicts are extra
    ROS parameters per node (every satellite). Raises SilError naming the failing node and its
    last log lines. ``environment`` "paper" (default) or "full" with ``env_options`` a
    ``fullenv.FullEnvironmentOptions``: the simulator builds the full environment and every node
    gets the actual orbit's nominal period (``fullenv.full_params``), as the offline
    ``simulate(..., environment="full")``. The orbit (altitude, inclination, RAAN, argument of
    latitude, epoch) is the spacecraft file's. ``field``: a field file (``magtune fit-field``) the
    simulators use as b(t) in the paper environment instead of the spacecraft's ``field_model``
    (the full environment keeps IGRF along the actual orbit).
    ``progress(k, n)`` is called with each "step k/n" line the simulators log (every tenth of the run; summed over satellites) and once with
    ``(n, n)`` at the end. ``results``: the trajectory ``.npz`` (``<stem>_<ns><suffix>`` per
    satellite when there are several).
    ``epoch_time``: stamps and /clock start at the spacecraft file's ``epoch`` (ns since 1970)
    instead of 0, so bag tools and Foxglove show real dates (the bag's ``custom_data`` keeps
    ``time_origin_ns``; the trajectory's ``t`` still starts at 0). ``foxglove``: a port (0: any
    free one) for the ``live_bridge`` node, which streams the run to Foxglove over WebSocket.
    ``bag_topics`` / ``bag_exclude`` (a regex): what the recorder keeps (default: every project topic).

    Returns
    -------
    dict
        namespace (as given, normalized: ``""`` or ``/sat1``) -> :class:`SilRun`.
    """
    if not satellites:
        raise ConfigError("--gains", None, "no satellite given")
    sats = {normalize_namespace(ns): Path(g) for ns, g in satellites.items()}
    if len(sats) != len(satellites):
        raise ConfigError("--gains", None, "two satellites with the same namespace")
    # every input is validated before any process starts (ConfigError: one line, exit 2 in the CLI)
    # (one read per file: the rcl-compatibility check returns the parameters the schema validates)
    gains_params = {ns: Gains.from_mapping(check_ros_params(g, CONTROLLER_NODE), g) for ns, g in sats.items()}
    sc_params = SpacecraftParams.from_mapping(check_ros_params(spacecraft), spacecraft, strict=True)
    check_run_arguments(orbits=orbits, steps=steps, substeps=substeps, real_time_factor=real_time_factor,
                        timeout=timeout)
    for ns, g in sats.items():
        check_sample_period(float(ts if ts is not None else gains_params[ns].ts), sc_params,
                            "--ts" if ts is not None else f"{g}: field 'ts'")
    for path, flag in ((log_dir, "--log-dir"), (results, "--results")):
        if path:
            check_writable(path, flag, directory=flag == "--log-dir")
    if bag:
        check_writable(bag, "--bag", directory=True, empty=True)
    if field is not None:
        if environment == "full":
            raise ConfigError("--field", None, "the full environment uses IGRF along the actual orbit; give --field "
                              "with --environment paper")
        field_for_spacecraft(field, sc_params)  # validated here: one line before any process starts
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
    multi = len(sats) > 1 or "" not in sats
    res_paths = {}
    for ns in sats:
        if results:
            r = Path(results)
            res_paths[ns] = r.with_name(f"{r.stem}_{_tag(ns)}{r.suffix}") if multi and ns else r
        else:  # loaded into memory before cleanup
            res_paths[ns] = log_dir / (f"results_{_tag(ns)}.npz" if ns else "results.npz")
        if res_paths[ns].exists():
            res_paths[ns].unlink()

    if foxglove is not None and not 0 <= int(foxglove) <= 65535:
        raise ConfigError("--foxglove", None, f"{foxglove}: expected a TCP port 0..65535 (0: any free port)")
    if bag_exclude:
        try:
            re.compile(bag_exclude)
        except re.error as exc:
            raise ConfigError("--bag-exclude", None, f"{bag_exclude!r} is not a regular expression ({exc})") from None
    if (bag_topics or bag_exclude) and not bag:
        raise ConfigError("--bag-topics/--bag-exclude", None, "only with --bag")
    time_origin_ns = epoch_ns(sc_params.epoch) if epoch_time else 0
    if time_origin_ns and multi:
        raise ConfigError("--epoch-time", None, "one satellite at a time (the recorder follows one clock)")

    common = {"use_sim_time": True}
    sim = dict(common, time_origin_ns=int(time_origin_ns), substeps=int(substeps), lockstep=bool(lockstep), lockstep_timeout=float(lockstep_timeout),
               startup_timeout=float(startup_timeout), real_time_factor=float(real_time_factor))
    if rec_exe:
        sim["min_truth_subscribers"] = 2  # the recorder must be listening before step 0
    if steps:
        sim["steps"] = int(steps)
    else:
        sim["orbits"] = float(orbits)
    env_sim: dict = {}
    if environment == "full":
        opts = env_options or FullEnvironmentOptions()
        if opts.epoch is not None or opts.raan_deg is not None or opts.arg_lat_deg is not None \
                or opts.zonal_degree != 2:
            raise SilError("the simulator node flies the spacecraft file's orbit: set epoch, raan, arg_latitude "
                           "there (zonal degree 2)")
        common["orbit_period"] = float(full_params(sc_params, opts).orbit_period)
        env_sim = dict(environment="full", env_gravity_gradient=bool(opts.gravity_gradient), env_drag=bool(opts.drag),
                       env_srp=bool(opts.srp), env_field=str(opts.field), igrf_degree=int(opts.igrf_degree))
        sim["orbit_period"] = common["orbit_period"]
    elif environment == "paper" and field is not None:
        env_sim = dict(field_file=str(Path(field).resolve()))
    elif environment != "paper":
        raise SilError(f"unknown environment {environment!r} (expected 'paper' or 'full')")
    pfiles, common_ts = {}, {}
    for ns in sats:
        common_ts[ns] = {"ts": float(ts if ts is not None else gains_params[ns].ts)}
        params = {
            "simulator": {**sim, "results_path": str(res_paths[ns].resolve()), **env_sim, **common_ts[ns],
                          **(simulator_params or {})},
            "attitude_sensors": {**common, **common_ts[ns], **(sensor_params or {})},
            "controller": {**common, **common_ts[ns], **(controller_params or {})},
        }
        pfiles[ns] = log_dir / (f"sil_params_{_tag(ns)}.yaml" if ns else "sil_params.yaml")
        # keyed /**/<node>: applies whatever the namespace (see base.paramfile.node_matches); given
        # last on each command line so its values win over the spacecraft and gains files
        pfiles[ns].write_text(yaml.safe_dump({f"/**/{k}": {"ros__parameters": v} for k, v in params.items()}))
    sc = ["--params-file", str(Path(spacecraft).resolve())]

    procs: list[NodeProcess] = []
    sims: dict[str, NodeProcess] = {}
    lock = DomainLock(domain_id)
    t0 = time.perf_counter()
    stops = StopSignals().__enter__()
    try:
        env = child_env(lock.domain_id, prefix, *([rec_exe.parents[2]] if rec_exe else []))
        fds = (lock.fh.fileno(),)
        if rec_exe:
            if multi:
                custom = {"satellites": ",".join(sats), "ts": common_ts[next(iter(sats))]["ts"],
                          **{f"{_tag(ns)}.gains": g.name for ns, g in sats.items()},
                          **{f"{_tag(ns)}.sigma": f"{gains_params[ns].sigma:g}" for ns in sats}}
                rargs = recorder_args(bag, custom) + ["-p", "topics:=[" + ", ".join(
                    f"'{t}'" for t in topic_specs(tuple(sats))) + "]", "-r", f"/clock:={next(iter(sats))}/clock"]
            else:
                custom = {"gains": sats[""].name, **common_ts[""], "sigma": f"{gains_params[''].sigma:g}"}
                if time_origin_ns:
                    custom["time_origin_ns"] = time_origin_ns
                rargs = recorder_args(bag, custom)
            if bag_topics:   # replaces the default project topic list
                rargs += ["-p", "topics:=[" + ", ".join(f"'{t}'" for t in bag_topics) + "]"]
            if bag_exclude:
                rargs += ["-p", "exclude:='" + bag_exclude.replace("'", "''") + "'"]  # a YAML string, whatever the regex
            procs.append(start_node("recorder", rec_exe, rargs, env, log_dir, fds))
        if foxglove is not None:
            topics = [t for t in topic_specs(tuple(sats) if multi else ("",))]
            procs.append(start_node("live_bridge", resolve_executable("live_bridge"), [], env, log_dir, fds,
                                    args=["--port", str(int(foxglove)), "--topics", *topics]))
        for ns, g in sats.items():
            remap = ["-r", f"__ns:={ns}", "-r", f"/clock:={ns}/clock"] if ns else []
            tag = f"{_tag(ns)}_" if ns else ""
            procs.append(start_node(f"{tag}controller", exes["controller"], sc + [
                "--params-file", str(g.resolve()), "--params-file", str(pfiles[ns])] + remap, env, log_dir, fds))
            procs.append(start_node(f"{tag}attitude_sensors", exes["attitude_sensors"],
                                    sc + ["--params-file", str(pfiles[ns])] + remap, env, log_dir, fds))
            sims[ns] = start_node(f"{tag}simulator", exes["simulator"], sc + ["--params-file", str(pfiles[ns])] + remap,
                                  env, log_dir, fds)
            procs.append(sims[ns])
        if on_start:
            on_start(lock.domain_id, procs)
        n_steps = steps or orbits * sc_params.orbit_period / min(c["ts"] for c in common_ts.values())
        deadline = time.monotonic() + (timeout if timeout else startup_timeout + 60.0 + 0.05 * n_steps * len(sats))
        watches = {ns: LogProgress(p.log, (lambda k, n: None) if progress else None) for ns, p in sims.items()}
        shown = [-1]

        def report():
            if progress and all(w.n for w in watches.values()):
                k, n = sum(w.last for w in watches.values()), sum(w.n for w in watches.values())
                if k > shown[0]:
                    shown[0] = k
                    progress(k, n)

        rcs: dict[str, int] = {}
        while len(rcs) < len(sims):
            for ns, p in sims.items():
                if ns not in rcs:
                    rc = p.popen.poll()
                    watches[ns].poll()
                    if rc is not None:
                        rcs[ns] = rc
                        if rc == DIVERGED_EXIT:
                            line = next((ln for ln in reversed(p.tail(20).splitlines()) if "diverged" in ln), "")
                            raise SilError(f"the simulation diverged and was stopped ({p.name}): "
                                           + (line.split("] ", 1)[-1] if line else "see the simulator log"))
                        if rc != 0 or not res_paths[ns].is_file():
                            raise SilError(f"simulator {p.name} exited with status {rc}:\n{p.tail()}")
            report()
            for p in procs:
                if p not in sims.values() and p.popen.poll() is not None:
                    raise SilError(f"node '{p.name}' exited with status {p.popen.returncode}:\n{p.tail()}")
            if time.monotonic() > deadline:
                raise SilError(f"SIL run timed out after {time.monotonic() - t0:.0f} s; simulator log:\n"
                               f"{next(iter(sims.values())).tail()}")
            if len(rcs) < len(sims):
                time.sleep(0.05)
        for w in watches.values():
            w.finish()
        report()
    except SilError as exc:
        raise SilError(f"{exc}\n(node logs in {log_dir})") from None
    finally:
        stops.shield()  # a second Ctrl-C / SIGHUP must not abort the clean-up
        try:
            stop_nodes([p for p in procs if p.name != "recorder"])
            stop_nodes([p for p in procs if p.name == "recorder"], grace=10.0)  # last: let it close the bag
        finally:
            lock.release()  # after every node is gone (they also held the lock's descriptor)
            stops.__exit__()
    total = time.perf_counter() - t0
    out = {}
    for ns in sats:
        res = SimResult.from_npz(res_paths[ns])
        counters = json.loads(str(res.info.get("counters", "{}")))
        out[ns] = SilRun(res, res.figures_of_merit(), counters, float(res.info.get("wall_time", total)), total,
                         lock.domain_id, None if own_dir else log_dir)
    if own_dir:
        shutil.rmtree(log_dir, ignore_errors=True)
    return out
