"""Process pools whose workers die with their parent, whatever kills it.

A ``concurrent.futures.ProcessPoolExecutor`` worker outlives a parent killed by SIGKILL (or any
signal that skips the pool's shutdown): it is re-parented to init and keeps computing. The
pools of ``magtune tune --workers N`` and ``magtune sampling`` are made by :func:`worker_pool`,
whose initializer gives every worker two guards:

* the kernel's parent-death signal (Linux ``prctl(PR_SET_PDEATHSIG, SIGKILL)``), set only when
  that is safe (:func:`parent_watch`): the signal follows the *thread* that forked the worker,
  so a worker forked by a thread that later ends would be killed with the parent still alive.
  :func:`worker_pool` therefore starts its workers at once, in the calling thread (the main
  thread in the commands);
* a watchdog thread in the worker that polls its parent's pid (:data:`WATCH_PERIOD`) and ends
  the worker (``os._exit``) when it has been re-parented: the guard for pools started from
  another thread and for platforms without ``prctl``.
"""
from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import threading
import time
from concurrent.futures import ProcessPoolExecutor, wait
from dataclasses import dataclass

PR_SET_PDEATHSIG = 1
#: Seconds between two parent checks of the watchdog thread.
WATCH_PERIOD = 0.25


def set_parent_death_signal(sig: int = signal.SIGKILL) -> bool:
    """Ask the kernel to send ``sig`` to this process when its parent (thread) dies; False where
    ``prctl`` is not available (not Linux)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):  # pragma: no cover - not Linux
        return False


@dataclass(frozen=True)
class ParentWatch:
    """What a pool worker watches: the pid of its expected parent (None: whatever its parent is
    when it starts, the fork server of a ``forkserver`` pool) and whether the parent-death signal
    may be used (the worker's parent thread lives as long as the parent process)."""

    parent: int | None
    pdeathsig: bool

    def install(self) -> None:
        """Set both guards in the worker (see the module docstring); a worker whose parent is
        already gone ends at once."""
        if self.pdeathsig:
            set_parent_death_signal(signal.SIGKILL)
        parent = os.getppid() if self.parent is None else self.parent
        if os.getppid() != parent:
            os._exit(1)
        threading.Thread(target=_watch, args=(parent,), name="magtune-parent-watch", daemon=True).start()


def parent_watch(start_method: str) -> ParentWatch:
    """The guards a pool made now, in this thread, with ``start_method`` can give its workers.

    ``fork``: the workers are forked by the thread that first submits (all at once, never later;
    :func:`worker_pool` submits at once), so the parent-death signal is safe from the main thread.
    ``forkserver``: the workers' parent is the single-threaded fork server, which ends with this
    process. ``spawn``: workers may be started later by any submitting thread: watchdog only.
    """
    main = threading.current_thread() is threading.main_thread()
    if start_method == "fork":
        return ParentWatch(os.getpid(), main)
    if start_method == "forkserver":
        return ParentWatch(None, True)
    return ParentWatch(os.getpid(), False)


def _watch(parent: int) -> None:
    """Watchdog loop: end this worker when it is re-parented (the pool's process died)."""
    while os.getppid() == parent:
        time.sleep(WATCH_PERIOD)
    os._exit(1)


def _init_worker(watch: ParentWatch, initializer, initargs) -> None:
    watch.install()
    if initializer is not None:
        initializer(*initargs)


def worker_pool(workers: int, initializer=None, initargs: tuple = ()) -> ProcessPoolExecutor:
    """A ProcessPoolExecutor of ``workers`` processes that die with this process (module
    docstring), each running ``initializer(*initargs)`` after the guards; its workers are started
    before it returns, from the calling thread."""
    ctx = multiprocessing.get_context()
    watch = parent_watch(ctx.get_start_method())
    pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker,
                               initargs=(watch, initializer, initargs))
    wait([pool.submit(os.getpid) for _ in range(workers)])
    return pool
