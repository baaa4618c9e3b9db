"""Process helpers for the ROS bag tests: isolated DDS domain, start/stop, executables."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from magtune_core.ros.process import DomainLock, die_with_parent

ROOT = Path(__file__).resolve().parents[2]
SUPPORT = ROOT / "tests" / "support"
_EXE_DIR = ROOT / "ros2_ws" / "install" / "magtune_ros" / "lib" / "magtune_ros"


def executable(name: str) -> list[str]:
    """Command of a magtune_ros node: the colcon-installed executable (as ``ros2 run`` uses)."""
    exe = _EXE_DIR / name
    if not exe.exists():
        raise FileNotFoundError(f"{exe} missing: run scripts/bootstrap.sh (colcon build)")
    return [str(exe)]


def ros_env(lock=None) -> dict:
    """Environment with a ROS_DOMAIN_ID reserved by ``lock`` (a ``process.DomainLock``: a lock
    file per id, so concurrent test runs on this machine never share a domain), discovery
    limited to this host."""
    env = dict(os.environ)
    if lock is None:
        lock = DomainLock()
    env["ROS_DOMAIN_ID"] = str(lock.domain_id)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["PYTHONUNBUFFERED"] = "1"
    env["_MAGTUNE_LOCK"] = str(id(lock))
    _locks[id(lock)] = lock
    return env


_locks: dict = {}


class Procs:
    """Starts processes in one environment; ``stop_all`` (call in ``finally``) ends them all, and the
    kernel sends each SIGTERM if the test process itself dies (``die_with_parent``)."""

    def __init__(self, env: dict, logdir: Path):
        self.env, self.logdir, self.procs = env, Path(logdir), []
        self.logdir.mkdir(parents=True, exist_ok=True)

    def start(self, name: str, cmd: list[str]) -> subprocess.Popen:
        out = open(self.logdir / f"{name}.out", "w+")
        p = subprocess.Popen(cmd, env=self.env, stdout=out, stderr=subprocess.STDOUT,
                             cwd=ROOT, start_new_session=True, preexec_fn=die_with_parent())
        p.log_path = self.logdir / f"{name}.out"  # type: ignore[attr-defined]
        self.procs.append(p)
        return p

    def python(self, name: str, script: str, *args) -> subprocess.Popen:
        return self.start(name, [sys.executable, str(SUPPORT / script), *map(str, args)])

    @staticmethod
    def output(p) -> str:
        return Path(p.log_path).read_text()

    def wait_for_line(self, p, text: str, timeout: float = 60.0) -> None:
        # generous: a Python+rclpy process start takes 1-2 s idle, 20+ s on a loaded 2-core box
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if text in self.output(p):
                return
            if p.poll() is not None:
                raise RuntimeError(f"process exited ({p.returncode}):\n{self.output(p)}")
            time.sleep(0.05)
        raise TimeoutError(f"'{text}' not seen in {timeout} s:\n{self.output(p)}")

    def stop_all(self) -> None:
        """SIGINT every process, SIGKILL what is left after 5 s, release the domain id."""
        for p in self.procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        end = time.monotonic() + 5
        for p in self.procs:
            try:
                p.wait(timeout=max(0.1, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        lock = _locks.pop(int(self.env.get("_MAGTUNE_LOCK", 0)), None)
        if lock is not None:
            lock.release()
