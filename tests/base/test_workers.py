"""Pool workers die with their parent (magtune_core.base.workers, issue 32 item 7): a parent killed
by SIGKILL leaves no worker behind, whether the pool was made from the main thread (parent-death
signal) or from a thread that has ended since (watchdog; the parent-death signal would have killed
those workers as soon as that thread ended, with the parent alive)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from magtune_core.ros.process import die_with_parent  # the test's child dies with pytest

#: A parent that makes a 2-worker pool (from the main thread or a thread that then ends), shows
#: that the pool still works after that thread is gone, prints the workers' pids and waits.
SCRIPT = r"""
import os, sys, threading, time
from magtune_core.base.workers import worker_pool
box = {}
def make():
    box["pool"] = worker_pool(2)
if sys.argv[1] == "thread":
    t = threading.Thread(target=make); t.start(); t.join()
else:
    make()
time.sleep(0.5)  # a worker killed by the ended thread's death signal would break the pool here
pool = box["pool"]
futs = [pool.submit(time.sleep, 0.2) for _ in range(4)]
[f.result() for f in futs]
print(" ".join(str(p) for p in pool._processes), flush=True)
time.sleep(600)
"""


def _alive(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def kill_parent_and_wait(proc: subprocess.Popen, workers: list[int], timeout: float = 5.0) -> float:
    """SIGKILL ``proc``; seconds until every pid of ``workers`` is gone (fails after ``timeout``)."""
    assert workers and all(_alive(p) for p in workers)
    t0 = time.monotonic()
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    while any(_alive(p) for p in workers):
        assert time.monotonic() - t0 < timeout, [p for p in workers if _alive(p)]
        time.sleep(0.05)
    return time.monotonic() - t0


@pytest.mark.parametrize("where", ["main", "thread"])
def test_pool_workers_die_with_a_killed_parent(where):
    proc = subprocess.Popen([sys.executable, "-c", SCRIPT, where], stdout=subprocess.PIPE, text=True,
                            preexec_fn=die_with_parent(signal.SIGKILL))
    workers = []
    try:
        line = proc.stdout.readline()
        assert proc.poll() is None, "the pool broke: a worker died while its parent was alive"
        workers = [int(p) for p in line.split()]
        assert len(workers) == 2
        # main thread: the kernel's signal, immediate; thread: the watchdog, within WATCH_PERIOD (0.25 s)
        # plus scheduling; 2 s leaves room on a loaded 2-core machine
        assert kill_parent_and_wait(proc, workers, timeout=2.0) < 2.0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for p in workers:
            if _alive(p):
                os.kill(p, signal.SIGKILL)
