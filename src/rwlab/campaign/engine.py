"""The campaign engine: a Dask client, and batches of work mapped over its workers.

The default is a :class:`distributed.LocalCluster` of worker processes on this
machine (one thread each, loopback only, no dashboard); a scheduler address
sends the same work to an existing cluster (whose workers must have rwlab
installed). When a worker dies, the local cluster's nannies start a
replacement, and :func:`map_batches` submits the batches it was computing
again (up to ``MAX_RETRIES`` times each) and reports every retry, so a campaign
finishes with every run; each task is a pure function of its inputs, so a
retried batch gives the same rows. The local scheduler is told not to retry on
its own (``allowed-failures`` 0); what a scheduler still does silently (a lost
worker's finished but not yet gathered results computed again; a retry under a
remote scheduler's own ``allowed-failures``) is read from its event log
(``remove-worker`` events) and reported too (:class:`LostWorker`).
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import os
from dataclasses import dataclass

from rwlab._optional import require
from rwlab.errors import ConfigError, LostWorkerError

__all__ = [
    "MAX_RETRIES",
    "WORKER_PRELOAD",
    "LostWorker",
    "batches",
    "dask_client",
    "map_batches",
    "worker_count",
]

MAX_RETRIES = 3  # times one batch is submitted again after its worker died


# What every local worker imports before it is forked (see ``_fork_workers_from``): the
# campaign's modules pull in numba, scipy and python-control, ~1.3 s of CPU per process;
# forkserver_quiet keeps a worker forked while its cluster closes from printing a traceback.
WORKER_PRELOAD = ("distributed", "rwlab.campaign.runs", "rwlab.campaign.forkserver_quiet")


@contextlib.contextmanager
def dask_client(
    workers: int | None = None,
    scheduler: str | None = None,
    preload: tuple[str, ...] | None = WORKER_PRELOAD,
):
    """A ``distributed.Client``: on ``scheduler`` (an address such as tcp://host:8786), or on
    a new local cluster of ``workers`` processes (default: the machine's cores).

    The local workers are forked from one server process that imported ``preload`` once
    (where the platform forks, i.e. not on Windows), rather than each spawned afresh to
    import them: start-up costs one worker's imports, not one per worker.

    Parameters
    ----------
    workers : int, optional
        Processes of a new local cluster.
    scheduler : str, optional
        Address of a running scheduler (not with ``workers``).
    preload : tuple of str or None
        Modules the local workers import before they are forked; None: spawn every
        worker as a fresh interpreter (distributed's default).

    Yields
    ------
    distributed.Client
        Closed, with its local cluster, when the block ends.
    """
    require("distributed", "running on Dask")
    import dask
    from distributed import Client, LocalCluster

    if workers is not None and scheduler is not None:
        raise ConfigError("give workers or scheduler, not both")
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise ConfigError(f"cannot reach the Dask scheduler at {scheduler} ({exc})") from None
        with client:
            yield client
        return
    n = workers if workers is not None else (os.cpu_count() or 1)
    if n < 1:
        raise ConfigError(f"workers must be ≥ 1, got {n}")
    from distributed.deploy.spec import SpecCluster

    before = set(SpecCluster._instances)
    try:
        with (
            dask.config.set(
                {
                    "distributed.scheduler.allowed-failures": 0,
                    "distributed.worker.multiprocessing-method": _fork_workers_from(preload),
                }
            ),
            LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address=None,
                # the scheduler's HTTP server (health, metrics) always starts: on a free
                # loopback port, not 8787 (taken by any other cluster: a warning each run)
                scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                silence_logs=logging.ERROR,
            ) as cluster,
            Client(cluster) as client,
        ):
            yield client
    except BaseException:  # Ctrl-C or SIGTERM while it starts or runs: no noise at exit
        # a callback of the cluster's event loop cut by the stop is logged by tornado as an
        # error with its traceback (seen once, in a fresh clone's suite run): after a
        # stop, nothing it could say is news
        logging.getLogger("tornado.application").setLevel(logging.CRITICAL + 1)
        _close_quietly(set(SpecCluster._instances) - before)
        raise


def _fork_workers_from(preload: tuple[str, ...] | None) -> str:
    """The multiprocessing start method for local workers: ``forkserver`` with ``preload``
    imported in the server (each worker a fork of it, imports done), else ``spawn``.

    A spawned worker imports distributed and, with its first task, rwlab's campaign
    modules: 2 workers doing so at once on a busy 2-core machine took 11.9 s to start
    against 7.7 s for one. ``fork`` from this process would inherit everything, but this
    process runs the cluster's threads (forking a threaded process is unsafe); the fork
    server is single-threaded. The preload list is the server's for this process's
    lifetime (multiprocessing starts one server per process, at its first use).
    """
    import multiprocessing

    import dask

    if preload is None or "forkserver" not in multiprocessing.get_all_start_methods():
        return "spawn"
    from distributed.utils import get_mp_context

    with dask.config.set({"distributed.worker.multiprocessing-method": "forkserver"}):
        ctx = get_mp_context()  # distributed sets its own preload list once: ours replaces it
    ctx.set_forkserver_preload(list(preload))
    return "forkserver"


def _close_quietly(clusters) -> None:
    """Close the local clusters left half-started by an interrupt, quietly.

    distributed closes them again at exit and, for one interrupted while its
    workers start, prints an AssertionError traceback; marking them closed here
    (after trying to close them) keeps the interrupt's message the last line.
    ``SpecCluster._instances`` is distributed's own registry (no public API).
    """
    from distributed.core import Status

    for cluster in clusters:
        with contextlib.suppress(Exception):
            cluster.close(timeout=5)
        cluster.status = Status.closed


def worker_count(client) -> int:
    """Workers the scheduler knows now (at least 1).

    Parameters
    ----------
    client : distributed.Client
        The cluster.

    Returns
    -------
    int
    """
    return max(1, len(client.scheduler_info().get("workers", {})))


def batches(items: list, n_workers: int, per_worker: int = 4) -> list[list]:
    """Split ``items`` in order into ``per_worker`` tasks per worker (fewer when there are
    fewer items), of sizes that differ by at most one.

    Parameters
    ----------
    items : list
        The work, in order.
    n_workers : int
        Number of workers.
    per_worker : int
        Tasks per worker (more balance the load, fewer cost less overhead).

    Returns
    -------
    list of list
        The batches; concatenated, they are ``items``.
    """
    n = max(1, min(len(items), per_worker * max(1, n_workers)))
    edges = [len(items) * i // n for i in range(n + 1)]
    return [items[a:b] for a, b in itertools.pairwise(edges)]


@dataclass(frozen=True)
class LostWorker:
    """A worker the scheduler removed while the campaign ran, and what it took with it.

    Attributes
    ----------
    address : str
        The worker's address.
    time : float
        When the scheduler removed it (Unix time, s).
    running : tuple of int
        The batches it was computing (run again: by :func:`map_batches`, or by the
        scheduler's own retries).
    recomputed : tuple of int
        The batches it had finished whose results were lost before they were gathered
        (computed again by the scheduler).
    """

    address: str
    time: float
    running: tuple[int, ...]
    recomputed: tuple[int, ...]


def _lost_workers(client, since: float, where: dict, seen: set) -> list[LostWorker]:
    """The scheduler's ``remove-worker`` events after ``since`` not in ``seen`` (unexpected
    removals only: a worker closed on purpose loses nothing), with our batches' indices."""
    found = []
    with contextlib.suppress(Exception):  # no event log (an old scheduler): nothing known
        for stamp, msg in client.get_events("all"):
            if (
                stamp < since
                or not isinstance(msg, dict)
                or msg.get("action") != "remove-worker"
                or msg.get("expected")
                or (stamp, msg.get("worker")) in seen
            ):
                continue
            seen.add((stamp, msg.get("worker")))

            def ours(keys) -> tuple[int, ...]:
                return tuple(sorted({where[k] for k in keys or () if k in where}))

            found.append(
                LostWorker(
                    str(msg.get("worker")),
                    float(stamp),
                    ours(msg.get("processing-tasks")),
                    ours(msg.get("lost-computed-tasks")),
                )
            )
    return found


def _pinned(fn, batch, *args):
    """Run ``fn(batch, *args)`` with BLAS on one thread (the work is small matrices)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1, user_api="blas"):
        return fn(batch, *args)


def map_batches(
    client,
    fn,
    work: list[list],
    *args,
    progress=None,
    on_batch=None,
    on_retry=None,
    on_lost_worker=None,
    max_retries: int = MAX_RETRIES,
) -> list:
    """``fn(batch, *args)`` for every batch on the cluster; the results of all, in order.

    Parameters
    ----------
    client : distributed.Client
        The cluster.
    fn : callable
        ``fn(batch, *args)`` returns one result per item of its batch (runs on a worker).
    work : list of list
        The batches (see :func:`batches`).
    *args
        Passed to every call (scattered once).
    progress : callable, optional
        ``progress(done)``: items finished so far, after each batch.
    on_batch : callable, optional
        ``on_batch(i, results)`` as soon as batch ``i`` is back (to keep it on disk).
    on_retry : callable, optional
        ``on_retry(i, attempt, reason)`` when batch ``i`` is submitted again because
        the worker computing it died (``attempt`` 1, 2, …).
    on_lost_worker : callable, optional
        ``on_lost_worker(lost)`` for each :class:`LostWorker` the scheduler reports
        (checked after each batch and at the end).
    max_retries : int
        Retries of one batch before the campaign stops.

    Returns
    -------
    list
        Every item's result, in the order of ``work``.

    Raises
    ------
    LostWorkerError
        A batch lost its worker more than ``max_retries`` times.
    """
    import time

    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    since = time.time()
    seen: set = set()

    def check_lost() -> None:
        if on_lost_worker is not None:
            for lost in _lost_workers(client, since, where, seen):
                on_lost_worker(lost)

    def submit(i: int):
        future = client.submit(_pinned, fn, work[i], *args, pure=False)
        where[future.key] = i
        return future

    where: dict = {}
    futures = [submit(i) for i in range(len(work))]
    attempts = [0] * len(work)
    results: list = [None] * len(work)
    done = 0
    pending = as_completed(futures)
    try:
        for future in pending:
            i = where[future.key]
            try:
                batch = future.result()
            except KilledWorker as exc:
                attempts[i] += 1
                if attempts[i] > max_retries:
                    raise LostWorkerError(
                        f"batch {i} (items {len(work[i])}) lost its worker "
                        f"{attempts[i]} times; the cluster is unhealthy ({exc})"
                    ) from None
                if on_retry is not None:
                    on_retry(i, attempts[i], f"worker lost ({type(exc).__name__})")
                futures.append(submit(i))
                pending.add(futures[-1])
                check_lost()
                continue
            results[i] = batch
            if on_batch is not None:
                on_batch(i, batch)
            done += len(work[i])
            if progress is not None:
                progress(done)
            check_lost()
    finally:
        client.cancel([f for f in futures if not f.done()])
    check_lost()
    return [r for batch in results for r in batch]
