"""Process supervision of the node runners: ROS domain lock, node processes, stop signals.

Every node runs in its own process group, stopped in a ``finally`` block (SIGINT, then
SIGTERM, then SIGKILL, :func:`stop_nodes`) that a second Ctrl-C, SIGTERM or SIGHUP cannot
interrupt (:class:`StopSignals`); every node also gets SIGTERM from the kernel if the runner
dies (``PR_SET_PDEATHSIG``, :func:`die_with_parent`: even ``kill -9`` of the runner leaves no
orphan) and inherits the domain lock's descriptor (:class:`DomainLock`), so the domain is free
again only when the runner and all its nodes are gone. Executables are resolved as ``ros2 run``
does. Used by the SIL runner (:mod:`.sil`) and the replay runner (:mod:`.replay`); no rclpy.
"""
from __future__ import annotations

import ctypes
import fcntl
import os
import signal
import stat
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from ..base import ament
from ..base.errors import SilError

PACKAGE = "magtune_ros"
#: ROS_DOMAIN_IDs handed out to runs: 215-232 map Fast DDS ports above Linux's ephemeral range
#: (32768-60999), the other range the ROS 2 docs call safe besides 0-101, which other tools use.
DOMAIN_RANGE = range(215, 233)


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


#: ``--dds-interfaces`` choices: loopback (default) or all (a multi-host setup).
DDS_INTERFACES = ("loopback", "all")
#: The Fast DDS profile of loopback mode: UDPv4 on 127.0.0.1 only + shared memory, no builtin transports.
LOOPBACK_PROFILE = ament.ROOT / "config" / "dds" / "fastdds_loopback.xml"
#: The environment variables Fast DDS reads its default XML profile from (2.x and 3.x names).
PROFILE_VARS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def dds_env(env: dict, interfaces: str = "loopback") -> dict:
    """Set the DDS network scope of node processes in ``env`` (in place; returned).

    ``loopback``: Fast DDS loads :data:`LOOPBACK_PROFILE` (every DDS socket on 127.0.0.1,
    discovery by multicast on the loopback interface only; the discovery range is SUBNET, confined
    to loopback by the profile, because rmw_fastrtps's LOCALHOST range adds an unrestricted UDP
    transport with sockets on 0.0.0.0 and the host's address). Another RMW ignores the profile:
    then the range stays LOCALHOST. ``all``: Fast DDS's defaults (or the user's own profile) and
    the SUBNET range, for nodes on several hosts. Raises SilError if the profile is missing.
    """
    if interfaces not in DDS_INTERFACES:
        raise SilError(f"--dds-interfaces: expected one of {', '.join(DDS_INTERFACES)}, got {interfaces!r}")
    if interfaces == "all":
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET"
        return env
    if not LOOPBACK_PROFILE.is_file():
        raise SilError(f"the DDS loopback profile {LOOPBACK_PROFILE} is missing (a broken checkout?)")
    fast = env.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp") in ("", "rmw_fastrtps_cpp")
    for var in PROFILE_VARS:
        env[var] = str(LOOPBACK_PROFILE)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET" if fast else "LOCALHOST"
    return env


def child_env(domain_id: int, prefix: Path, *more: Path, interfaces: str = "loopback") -> dict:
    """Environment of the node processes: isolated domain, DDS on loopback unless ``interfaces``
    is ``all`` (:func:`dds_env`), package paths."""
    env = ament.child_env(prefix, *more)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    dds_env(env, interfaces)
    env.pop("ROS_STATIC_PEERS", None)
    env.setdefault("RCUTILS_LOGGING_BUFFERED_STREAM", "1")
    return env


#: How a domain lock file is opened: never through a symlink (ELOOP), never truncated, not
#: inherited by exec'd programs unless passed on purpose (``pass_fds``).
LOCK_OPEN_FLAGS = os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC


def lock_path(domain_id: int) -> Path:
    """The machine-wide lock file of a ROS_DOMAIN_ID (the domain is shared by every user)."""
    return Path(tempfile.gettempdir()) / f"magtune_ros_domain_{domain_id}.lock"


def open_lock_file(path: Path) -> int | None:
    """Descriptor of the lock file ``path``, or None when it must be treated as taken.

    Opened with :data:`LOCK_OPEN_FLAGS` (mode 0644): a symlink planted at the path is never
    followed (ELOOP) and an existing file is never truncated or written (the lock is the flock,
    not the content). A file owned by another user, a symlink or anything that is not a regular
    file is "taken": the caller moves on to the next domain id.
    """
    try:
        fd = os.open(path, LOCK_OPEN_FLAGS, 0o644)
    except OSError:  # ELOOP (symlink), EACCES (another user's 0644 file), ...
        return None
    st = os.fstat(fd)
    if st.st_uid != os.geteuid() or not stat.S_ISREG(st.st_mode):
        os.close(fd)
        return None
    return fd


class DomainLock:
    """Reserve a ROS_DOMAIN_ID for this run with an exclusive flock on a lock file in the temp
    directory (:func:`open_lock_file`: symlinks and other users' files count as taken)."""

    def __init__(self, domain_id: int | None = None):
        self.fh = None
        ids = [domain_id] if domain_id is not None else list(DOMAIN_RANGE)
        start = os.getpid() % len(ids)
        for did in ids[start:] + ids[:start]:
            fd = open_lock_file(lock_path(did))
            if fd is None:
                continue
            fh = os.fdopen(fd, "rb", buffering=0)
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
