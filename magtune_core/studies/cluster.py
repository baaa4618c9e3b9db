"""The Dask cluster a campaign runs on: closed by default, authenticated when it is someone else's.

A Dask worker runs whatever a connected client sends it, as the user that started it, so who
may connect is who may run code as the campaign's user. Hence:

* the default, a **LocalCluster** started for one campaign (:func:`local_cluster`), speaks TLS
  with a certificate made for it in memory (``distributed.security.Security.temporary()``) and
  requires it from every peer: only this process's client (and the workers it started) can
  connect; scheduler, nannies and workers listen on 127.0.0.1 only. Its HTTP server (the
  scheduler always runs one) serves no route and listens on a random loopback port unless the
  dashboard is asked for (``dashboard=True``: 127.0.0.1:8787, read-only pages without
  authentication, for as long as the campaign runs); the workers' HTTP servers serve nothing;
* an **existing cluster** (``--scheduler tls://HOST:PORT``) is reached with the TLS files given
  (:class:`TlsFiles`: CA, client certificate, key) or, without them, with the
  ``distributed.comm.tls`` settings of the Dask configuration (a YAML file in ~/.config/dask/ or
  ``DASK_CONFIG``); ``tcp://`` is accepted for a cluster the user secured otherwise (a private
  network), with a warning.

Used by :mod:`.campaign` and :mod:`.verify` (Monte Carlo runs as tasks) and, through
:func:`executor` / :class:`ClusterExecutor`, by ``magtune tune`` and ``magtune front
--scheduler`` (the tuner's candidate evaluations as tasks on an existing cluster). The project's
only Dask users are here and in :mod:`.campaign`.
"""
from __future__ import annotations

import logging
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from ..base.errors import ConfigError

#: Where the dashboard of a LocalCluster is served when asked for (loopback only).
DASHBOARD_ADDRESS = "127.0.0.1:8787"
#: The HTTP server of a closed LocalCluster: a random loopback port, no route.
CLOSED_HTTP = "127.0.0.1:0"
#: Dask configuration of a closed cluster: no HTTP route on the scheduler nor on the workers
#: (health, metrics, info pages, the proxy to the workers' pages), and TLS required everywhere.
CLOSED_CONFIG = {"distributed.scheduler.http.routes": [], "distributed.worker.http.routes": [],
                 "distributed.comm.require-encryption": True}
#: Environment of every LocalCluster worker: one BLAS/OpenMP thread per worker process (the
#: batched simulator is elementwise numpy; threads would only fight over the cores).
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}


@dataclass(frozen=True)
class TlsFiles:
    """TLS credentials of a client of an existing cluster (PEM files; any may be None)."""

    ca_file: str | None = None
    cert: str | None = None
    key: str | None = None

    def given(self) -> bool:
        return any((self.ca_file, self.cert, self.key))

    def check(self) -> None:
        """ConfigError naming the option of a missing file, or of an incomplete set."""
        for opt, value in (("--tls-ca-file", self.ca_file), ("--tls-cert", self.cert), ("--tls-key", self.key)):
            if value is None:
                raise ConfigError(opt, None, "a tls:// scheduler needs --tls-ca-file, --tls-cert and --tls-key "
                                             "(or none of them and distributed.comm.tls in the Dask configuration)")
            if not Path(value).is_file():
                raise ConfigError(value, None, f"{opt}: file not found")


def scheduler_security(scheduler: str, tls: TlsFiles | None):
    """The ``Security`` of a client of ``scheduler`` (an address), or None for plain tcp://.

    Raises ConfigError for TLS files with a tcp:// address, an incomplete or missing set of
    files, and a tls:// address with neither files nor a Dask TLS configuration.
    """
    from distributed.security import Security

    tls = tls or TlsFiles()
    if not scheduler.startswith("tls://"):
        if tls.given():
            raise ConfigError("--scheduler", None, f"TLS files given but {scheduler!r} is not a tls:// address")
        return None
    if tls.given():
        tls.check()
        return Security(tls_ca_file=tls.ca_file, tls_client_cert=tls.cert, tls_client_key=tls.key,
                        require_encryption=True)
    sec = Security()  # distributed.comm.tls.* of the Dask configuration
    if not (sec.tls_ca_file and sec.tls_client_cert):
        raise ConfigError("--scheduler", None, "a tls:// scheduler needs --tls-ca-file, --tls-cert and --tls-key, or "
                                               "distributed.comm.tls.ca-file and .client.cert in the Dask configuration")
    return sec


@contextmanager
def local_cluster(workers: int, dashboard: bool = False):
    """A closed LocalCluster of ``workers`` single-thread processes (module docstring); yields
    (cluster, security), the security being the only credentials that can connect."""
    import dask
    from distributed import LocalCluster
    from distributed.security import Security

    security = Security.temporary()
    with dask.config.set(CLOSED_CONFIG if not dashboard else {"distributed.comm.require-encryption": True}):
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, protocol="tls://",
                               host="127.0.0.1", security=security,
                               dashboard_address=DASHBOARD_ADDRESS if dashboard else CLOSED_HTTP,
                               silence_logs=logging.ERROR, env=dict(WORKER_ENV))
    try:
        yield cluster, security
    finally:
        cluster.close()


@contextmanager
def connect(scheduler: str | None, workers: int, *, dashboard: bool = False, tls: TlsFiles | None = None):
    """A client of the campaign's cluster: a closed LocalCluster (``scheduler`` None) or the
    existing cluster at ``scheduler``; yields (client, info) with info the ``campaign.json``
    fields (scheduler, dashboard link)."""
    from distributed import Client

    if scheduler:
        security = scheduler_security(scheduler, tls)
        client = Client(scheduler, timeout="20s", security=security)
        try:
            yield client, dict(scheduler=scheduler, secured=security is not None)
        finally:
            client.close()
        return
    with local_cluster(workers, dashboard) as (cluster, security):
        client = Client(cluster, security=security)
        try:
            yield client, dict(scheduler="LocalCluster", secured=True,
                               dashboard=cluster.dashboard_link if dashboard else None)
        finally:
            client.close()


def _one_thread(fn, *args):
    """Task body of :class:`ClusterExecutor`: ``fn(*args)`` with BLAS/OpenMP and numba on one thread
    (the cluster's worker threads are the parallelism, as in the tuner's local pool:
    ``design.objective.one_thread_per_worker``; numba's setting is per thread, BLAS's per process)."""
    import numba
    from threadpoolctl import threadpool_limits

    numba.set_num_threads(1)
    with threadpool_limits(limits=1):
        return fn(*args)


class ClusterExecutor:
    """The tuner's executor on a Dask cluster (``design.objective.HinfObjective(executor=...)``):
    ``submit`` runs a population's part as a task (``pure=False``: every call is computed),
    ``share`` sends the objective's models once to every worker (``Client.scatter(broadcast=True)``),
    ``workers`` is the number of parts: the cluster's worker threads when it was connected (fixed,
    so a run's split, hence its result, does not depend on workers joining or leaving later)."""

    def __init__(self, client):
        self.client = client
        info = client.scheduler_info(n_workers=-1)["workers"]
        self.workers = max(1, sum(int(w.get("nthreads", 1)) for w in info.values()))

    def submit(self, fn, *args):
        """A future of ``fn(*args)`` computed on the cluster (one thread, :func:`_one_thread`)."""
        return self.client.submit(_one_thread, fn, *args, pure=False)

    def share(self, obj):
        """A future holding ``obj`` on every worker, passed to :meth:`submit` in its place."""
        return self.client.scatter([obj], broadcast=True, hash=False)[0]


class ClusterError(RuntimeError):
    """The cluster cannot run the tuner's tasks (no worker, or workers without magtune_core)."""


@contextmanager
def executor(scheduler: str, tls: TlsFiles | None = None, wait: float = 30.0):
    """A :class:`ClusterExecutor` on the existing cluster at ``scheduler`` (tcp:// or tls://, with
    ``tls`` as in :func:`connect`), once at least one worker is there (``wait`` s) and every worker
    imports magtune_core (the tasks are its functions); the client is closed on exit.

    Raises OSError when the scheduler cannot be reached, :class:`ClusterError` as above."""
    with connect(scheduler, 0, tls=tls) as (client, _):
        try:
            client.wait_for_workers(1, timeout=wait)
        except TimeoutError:
            raise ClusterError(f"{scheduler} has no worker after {wait:g} s; start `dask worker {scheduler}`") from None
        try:
            client.run(exec, "import magtune_core")
        except ImportError as exc:
            raise ClusterError(f"the workers of {scheduler} cannot import magtune_core ({exc}); install the project "
                               "there or put it on their PYTHONPATH") from None
        yield ClusterExecutor(client)
