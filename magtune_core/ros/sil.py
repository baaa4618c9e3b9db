"""Software-in-the-loop runner: the three magtune_ros nodes as separate processes over DDS.

``magtune sil --gains config/gains/sigma_60.yaml --orbits 5 --ts 1 [--bag bags/NAME]``
(the command: :mod:`magtune_core.cli.sil`).

A run is a validated :class:`~magtune_core.ros.scenario.SilScenario` (every file read once,
one parameter file written per node); this module launches its nodes (:mod:`.process`: own
ROS_DOMAIN_ID, localhost discovery, process groups, parent-death, clean stop), waits for the
simulators and collects their trajectories. The simulator runs in lockstep with the controller
(see magtune_ros/simulator.py) and writes its trajectory to an .npz (``SimResult``), from which
the summary (paper section 5 figures: final and peak |dq_R|, RMS over orbits 2-5, peak |m|) is
computed. Subprocesses only: this module never imports rclpy.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from ..base.errors import ConfigError, SilError
from ..base.topics import topic_specs
from ..design.faults import kill_time
from ..sim.metrics import format_figures
from ..sim.simulate import DIVERGED_EXIT, STARTUP_EXIT, SimResult
from .process import PACKAGE, DomainLock, NodeProcess, StopSignals, child_env, package_prefix, resolve_executable, start_node, stop_nodes
from .scenario import MODE_MANAGER, SilRequest, SilScenario, tag

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


class LogProgress:
    """Follows the simulator's log for its ``step k/n`` lines (logged every tenth of the run)
    and hands them to ``callback(k, n)``: progress without another topic or subscriber."""

    PATTERN = re.compile(rb"step (\d+)/(\d+)")

    def __init__(self, log: Path, callback=None):
        self.log, self.callback, self.offset, self.n, self.last = log, callback, 0, 0, -1

    def poll(self) -> None:
        """Read the log's new whole lines and report each new step."""
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
        """Last poll, then report the end ``(n, n)`` once."""
        self.poll()
        if self.callback is not None and self.n and self.last < self.n:
            self.last = self.n
            self.callback(self.n, self.n)


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
    #: faults the runner injected itself: (kind, sim time [s], wall time.time() [s]) (sensors_killed)
    faults_injected: list = field(default_factory=list)

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall second of stepping."""
        return float(self.result.t[-1]) / max(self.wall_time, 1e-9)

    def summary(self) -> str:
        """The figures of merit and counters, as ``magtune sil`` prints them."""
        return (f"{format_figures(self.figures)}\n"
                f"missed steps {self.counters.get('missed_steps', 0)}  steps {self.counters.get('steps', 0)}  "
                f"wall {self.wall_time:.2f} s (total {self.total_wall_time:.2f} s)  "
                f"real-time factor {self.real_time_factor:.0f}x")


def run_sil(gains, *, on_start=None, progress=None, **scenario) -> SilRun:
    """One satellite in the root namespace: :func:`run_fleet` of
    ``SilScenario.build({"": gains}, SilRequest(**scenario))`` (keywords: the fields of
    :class:`~magtune_core.ros.scenario.SilRequest`)."""
    return run_fleet(SilScenario.build({"": gains}, SilRequest(**scenario)), on_start=on_start, progress=progress)[""]


# ------------------------------------------------------------------ launch
def _recorder_executable(scenario: SilScenario) -> Path | None:
    if not scenario.bag:
        return None
    try:
        rpkg, _, rexe = os.environ.get(RECORDER_ENV, f"{PACKAGE}/{RECORDER_EXE}").rpartition("/")
        return resolve_executable(rexe, rpkg or PACKAGE)
    except SilError as exc:
        raise SilError(f"--bag needs a recorder executable ({exc}); set {RECORDER_ENV}=package/executable "
                       "if it lives elsewhere") from None


def _recorder_ros_args(scenario: SilScenario) -> list[str]:
    """Recorder arguments: the bag, its custom data (gains, ts, sigma per satellite), the topics."""
    sats = scenario.satellites
    if scenario.multi:
        names = tuple(s.namespace for s in sats)
        custom = {"satellites": ",".join(names), "ts": sats[0].ts,
                  **{f"{tag(s.namespace)}.gains": s.gains_path.name for s in sats},
                  **{f"{tag(s.namespace)}.sigma": f"{s.gains.sigma:g}" for s in sats}}
        rargs = recorder_args(scenario.bag, custom) + ["-p", "topics:=[" + ", ".join(
            f"'{t}'" for t in topic_specs(names)) + "]", "-r", f"/clock:={names[0]}/clock"]
    else:
        custom = {"gains": sats[0].gains_path.name, "ts": sats[0].ts, "sigma": f"{sats[0].gains.sigma:g}"}
        if scenario.time_origin_ns:
            custom["time_origin_ns"] = scenario.time_origin_ns
        rargs = recorder_args(scenario.bag, custom)
    if scenario.bag_topics:   # replaces the default project topic list
        rargs += ["-p", "topics:=[" + ", ".join(f"'{t}'" for t in scenario.bag_topics) + "]"]
    if scenario.bag_exclude:
        rargs += ["-p", "exclude:='" + scenario.bag_exclude.replace("'", "''") + "'"]  # a YAML string, whatever the regex
    return rargs


def _executables(scenario: SilScenario) -> dict[str, Path]:
    """Every executable the run starts (SilError naming the missing one, before anything starts)."""
    exes = {n: resolve_executable(n) for n in scenario.nodes}
    if scenario.foxglove is not None:
        exes["live_bridge"] = resolve_executable("live_bridge")
    rec = _recorder_executable(scenario)
    if rec:
        exes["recorder"] = rec
    return exes


def _launch(scenario: SilScenario, exes: dict, pfiles: dict, env: dict, log_dir: Path, fds: tuple,
            procs: list[NodeProcess]) -> dict[str, NodeProcess]:
    """Start the recorder (first: it must listen before step 0), the Foxglove bridge and each
    satellite's nodes (each with its own parameter file; ``-r __ns:=NS -r /clock:=NS/clock``),
    appending each to ``procs`` as it starts (the caller stops them whatever happens).

    Returns
    -------
    dict
        namespace -> the satellite's simulator process (the run ends when they exit).
    """
    sims = {}
    if "recorder" in exes:
        procs.append(start_node("recorder", exes["recorder"], _recorder_ros_args(scenario), env, log_dir, fds))
    if scenario.foxglove is not None:
        names = tuple(s.namespace for s in scenario.satellites) if scenario.multi else ("",)
        procs.append(start_node("live_bridge", exes["live_bridge"], [], env, log_dir, fds,
                                args=["--port", str(scenario.foxglove), "--topics", *topic_specs(names)]))
    for sat in scenario.satellites:
        ns = sat.namespace
        remap = ["-r", f"__ns:={ns}", "-r", f"/clock:={ns}/clock"] if ns else []
        prefix = f"{tag(ns)}_" if ns else ""
        for node in scenario.nodes:
            # a sensors kill is timed by the simulator's log line: unbuffered, so the runner sees it at once
            nenv = dict(env, RCUTILS_LOGGING_BUFFERED_STREAM="0") if node == "simulator" and \
                kill_time(scenario.faults) is not None else env
            procs.append(start_node(f"{prefix}{node}", exes[node], ["--params-file", str(pfiles[ns][node])] + remap
                                    + scenario.remaps(node),
                                    nenv, log_dir, fds))
            if node == "simulator":
                sims[ns] = procs[-1]
    return sims


# ------------------------------------------------------------------ wait
class KillWatch:
    """The ``sensors_killed`` fault of one satellite: follows its simulator's log for the line
    ``fault sensors_killed at t=T s`` (the simulator holds that step 1 s) and sends SIGKILL to the
    process group of the satellite's attitude_sensors at once; ``events`` (kind, T, wall time)."""

    PATTERN = re.compile(rb"fault sensors_killed at t=([0-9.]+) s")

    def __init__(self, sim: NodeProcess, victim: NodeProcess):
        self.sim, self.victim, self.offset, self.events = sim, victim, 0, []

    def poll(self) -> None:
        if self.events:
            return
        try:
            with open(self.sim.log, "rb") as fh:
                fh.seek(self.offset)
                data = fh.read()
        except OSError:
            return
        end = data.rfind(b"\n") + 1
        self.offset += end
        m = self.PATTERN.search(data[:end])
        if m:
            try:
                os.killpg(self.victim.popen.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.events.append(("sensors_killed", float(m.group(1)), time.time()))


def _wait(scenario: SilScenario, procs: list[NodeProcess], sims: dict, res_paths: dict, progress, t0: float,
          kills: dict | None = None) -> None:
    """Poll until every simulator (``sims``: namespace -> process) exited with its trajectory
    written; SilError on a failed node, a diverged simulation or the run's timeout.
    ``progress(k, n)``: summed step lines; ``kills`` namespace -> :class:`KillWatch` (its victim's
    exit is the fault, not a failure)."""
    kills = kills or {}
    # without a user's timeout, a guard against a hung run only: the simulators' own wait for their peers (with the
    # mode manager, its bring-up limit too), then 20 steps/s per satellite, 7x below the slowest loaded rate
    # measured (the full environment's 11,000 steps at >135 steps/s with two CPU hogs, scripts/load_test.sh)
    deadline = time.monotonic() + (scenario.timeout if scenario.timeout else
                                   scenario.peer_wait() + 60.0 + 0.05 * scenario.n_steps * len(sims))
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
            if ns in rcs:
                continue
            rc = p.popen.poll()
            watches[ns].poll()
            if rc is not None:
                rcs[ns] = rc
                _check_simulator_exit(p, rc, res_paths[ns], [q for q in procs if q is not p])
        report()
        for w in kills.values():
            w.poll()
        victims = [w.victim for w in kills.values() if w.events]
        for p in procs:
            if p not in sims.values() and p not in victims and p.popen.poll() is not None:
                if p.name.endswith(MODE_MANAGER) and p.popen.returncode == 2:  # a node's one-line reason
                    raise ConfigError(p.name, None, p.tail(1).removeprefix(f"{MODE_MANAGER}: "))
                raise SilError(f"node '{p.name}' exited with status {p.popen.returncode}:\n{p.tail()}")
        if time.monotonic() > deadline:
            raise SilError(f"SIL run timed out after {time.monotonic() - t0:.0f} s; simulator log:\n"
                           f"{next(iter(sims.values())).tail()}")
        if len(rcs) < len(sims):
            time.sleep(0.05)
    for w in watches.values():
        w.finish()
    report()


def _check_simulator_exit(p: NodeProcess, rc: int, results: Path, peers: list[NodeProcess]) -> None:
    """SilError for a simulator that did not finish its run; one that never started (its peers did not come up
    within startup_timeout) shows each peer's last log lines too, so the error says which one did not."""
    if rc == STARTUP_EXIT:
        said = "".join(f"\n--- {q.name}:\n{q.tail(3) or '(nothing logged)'}" for q in peers)
        raise SilError(f"simulator {p.name} exited with status {rc}:\n{p.tail()}\nits peers' last lines:{said}")
    if rc == DIVERGED_EXIT:
        line = next((ln for ln in reversed(p.tail(20).splitlines()) if "diverged" in ln), "")
        raise SilError(f"the simulation diverged and was stopped ({p.name}): "
                       + (line.split("] ", 1)[-1] if line else "see the simulator log"))
    if rc != 0 or not results.is_file():
        raise SilError(f"simulator {p.name} exited with status {rc}:\n{p.tail()}")


# ------------------------------------------------------------------ run
def run_fleet(scenario: SilScenario, *, on_start=None, progress=None) -> dict[str, SilRun]:
    """Run ``scenario``: satellites side by side in one ROS domain, one namespace each,
    optionally recorded in one bag.

    Each satellite is its own lockstep simulation: its three nodes run with ``-r __ns:=NS``
    (relative topics become ``NS/sim/truth``, ...) and ``-r /clock:=NS/clock`` (each simulator
    is the time source of its own nodes only; with one satellite in the root namespace nothing
    is remapped). The recorder (with a bag) subscribes to every satellite's topics and clocks and
    follows the first satellite's clock for log times; every message keeps its own satellite's
    sim time in its header stamp. ``on_start(domain_id, procs)`` is called once every process
    started; ``progress(k, n)`` with each "step k/n" line the simulators log (every tenth of the
    run; summed over satellites) and once with ``(n, n)`` at the end.

    Returns
    -------
    dict
        namespace (normalized: ``""`` or ``/sat1``) -> :class:`SilRun`. Raises SilError naming
        the failing node and its last log lines.
    """
    prefix = package_prefix()  # SilError before anything is written when the package is not built
    exes = _executables(scenario)
    own_dir = scenario.log_dir is None  # a temporary log directory is removed after a successful run
    log_dir = scenario.log_dir or Path(tempfile.mkdtemp(prefix="magtune_sil_"))
    log_dir.mkdir(parents=True, exist_ok=True)
    res_paths = {s.namespace: scenario.results_path(s, log_dir) for s in scenario.satellites}
    for path in res_paths.values():
        if path.exists():
            path.unlink()
    pfiles = {s.namespace: scenario.write_parameter_files(s, log_dir, res_paths[s.namespace])
              for s in scenario.satellites}
    procs: list[NodeProcess] = []
    kills: dict[str, KillWatch] = {}
    lock = DomainLock(scenario.domain_id)
    t0 = time.perf_counter()
    stops = StopSignals().__enter__()
    try:
        env = child_env(lock.domain_id, prefix, *([exes["recorder"].parents[2]] if "recorder" in exes else []),
                        interfaces=scenario.dds_interfaces)
        sims = _launch(scenario, exes, pfiles, env, log_dir, (lock.fh.fileno(),), procs)
        if kill_time(scenario.faults) is not None:
            by_name = {p.name: p for p in procs}
            kills = {ns: KillWatch(sim, by_name[f"{tag(ns)}_attitude_sensors" if ns else "attitude_sensors"])
                     for ns, sim in sims.items()}
        if on_start:
            on_start(lock.domain_id, procs)
        _wait(scenario, procs, sims, res_paths, progress, t0, kills)
    except SilError as exc:
        raise SilError(f"{exc}\n(node logs in {log_dir})") from None
    finally:
        stops.shield()  # a second Ctrl-C / SIGHUP must not abort the clean-up
        try:
            # the mode managers first: they bring their managed nodes down (reverse order, lifecycle)
            stop_nodes([p for p in procs if p.name.endswith(MODE_MANAGER)])
            stop_nodes([p for p in procs if p.name != "recorder" and not p.name.endswith(MODE_MANAGER)])
            stop_nodes([p for p in procs if p.name == "recorder"], grace=10.0)  # last: let it close the bag
        finally:
            lock.release()  # after every node is gone (they also held the lock's descriptor)
            stops.__exit__()
    total = time.perf_counter() - t0
    out = {}
    for ns, path in res_paths.items():
        res = SimResult.from_npz(path)
        counters = json.loads(str(res.info.get("counters", "{}")))
        out[ns] = SilRun(res, res.figures_of_merit(), counters, float(res.info.get("wall_time", total)), total,
                         lock.domain_id, None if own_dir else log_dir,
                         faults_injected=list(kills[ns].events) if ns in kills else [])
    if own_dir:
        shutil.rmtree(log_dir, ignore_errors=True)
    return out
