"""A real external Dask cluster for the tests: a `dask scheduler` and two `dask worker` processes on
127.0.0.1 (the console scripts of this venv), TLS when certificate files are given. Used by the
campaign tests (tests/studies/test_campaign.py) and the tuner-on-a-cluster tests
(tests/studies/test_tune_cluster.py).

Every process runs in its own process group and gets SIGTERM from the kernel if pytest dies
(``die_with_parent``); the ``finally`` of :func:`dask_cluster` terminates each group, waits, and
kills what is left (a nanny's worker child included), so no process outlives the test.
"""
from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from magtune_core.ros.process import die_with_parent

ROOT = Path(__file__).resolve().parents[2]


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now (for the scheduler to listen on)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def tls_files(tmp_path) -> dict:
    """A CA/certificate/key triple in PEM files (Dask's temporary self-signed certificate, which is
    its own CA): the credentials of an existing secured cluster and of its clients."""
    from distributed.security import Security

    sec = Security.temporary()
    files = dict(ca=tmp_path / "ca.pem", cert=tmp_path / "cert.pem", key=tmp_path / "key.pem")
    files["ca"].write_text(sec.tls_ca_file)
    files["cert"].write_text(sec.tls_scheduler_cert)
    files["key"].write_text(sec.tls_scheduler_key)
    return files


def tls_options(tls: dict) -> list[str]:
    """The ``--tls-ca-file/--tls-cert/--tls-key`` options of ``tls`` (dask CLI and magtune alike)."""
    return ["--tls-ca-file", str(tls["ca"]), "--tls-cert", str(tls["cert"]), "--tls-key", str(tls["key"])]


def _stop(procs) -> None:
    """SIGTERM every process group, wait, then SIGKILL whatever is left of each group."""
    for p in reversed(procs):
        with contextlib.suppress(ProcessLookupError):
            os.killpg(p.pid, signal.SIGTERM)
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            pass
    for p in procs:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(p.pid, signal.SIGKILL)
        p.wait()


@contextlib.contextmanager
def dask_cluster(tmp_path, tls: dict | None = None, nanny: bool = True):
    """A real `dask scheduler` and two `dask worker` processes (w1, w2) on localhost, TLS when
    ``tls`` files are given; yields (address, {name: worker Popen}, client security). The workers
    import this checkout's magtune_core (PYTHONPATH) and run one thread each."""
    from distributed import Client
    from distributed.security import Security

    dask_cli = str(Path(sys.executable).parent / "dask")
    port = free_port()
    proto = "tls" if tls else "tcp"
    addr = f"{proto}://127.0.0.1:{port}"
    opts = tls_options(tls) if tls else []
    sec = Security(tls_ca_file=str(tls["ca"]), tls_client_cert=str(tls["cert"]), tls_client_key=str(tls["key"]),
                   require_encryption=True) if tls else None
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    logs = [open(tmp_path / f"{n}.log", "w") for n in ("scheduler", "worker1", "worker2")]
    procs, workers = [], {}
    start = dict(stderr=subprocess.STDOUT, env=env, cwd=tmp_path, preexec_fn=die_with_parent(), start_new_session=True)
    try:
        procs.append(subprocess.Popen([dask_cli, "scheduler", "--host", "127.0.0.1", "--port", str(port),
                                       "--protocol", proto, "--no-dashboard", *opts], stdout=logs[0], **start))
        for i in (1, 2):
            workers[f"w{i}"] = subprocess.Popen(
                [dask_cli, "worker", addr, "--nthreads", "1", "--nworkers", "1", "--host", "127.0.0.1", "--no-dashboard",
                 "--name", f"w{i}", *opts, *([] if nanny else ["--no-nanny"])], stdout=logs[i], **start)
            procs.append(workers[f"w{i}"])
        deadline = time.monotonic() + 90
        while True:  # the scheduler takes a moment to listen; then wait for both workers
            try:
                with Client(addr, timeout="5s", security=sec) as c:
                    c.wait_for_workers(2, timeout=max(1.0, deadline - time.monotonic()))
                break
            except OSError:
                if time.monotonic() > deadline or any(p.poll() is not None for p in procs):
                    raise
                time.sleep(0.5)
        yield addr, workers, sec
    finally:
        _stop(procs)
        for f in logs:
            f.close()
