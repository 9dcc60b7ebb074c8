"""The campaign engine: a Dask client, and batches of work mapped over its workers.

The default is a :class:`distributed.LocalCluster` of worker processes on this
machine (one thread each, loopback only, no dashboard); a scheduler address
sends the same work to an existing cluster (whose workers must have rwlab
installed). Dask reschedules the tasks of a worker that dies on the others, and
the local cluster's nannies start a replacement, so a campaign finishes with
every run; each task is a pure function of its inputs, so a retried batch gives
the same rows.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import os

from rwlab._optional import require
from rwlab.errors import ConfigError

__all__ = ["batches", "dask_client", "map_batches", "worker_count"]


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None):
    """A ``distributed.Client``: on ``scheduler`` (an address such as tcp://host:8786), or on
    a new local cluster of ``workers`` processes (default: the machine's cores).

    Parameters
    ----------
    workers : int, optional
        Processes of a new local cluster.
    scheduler : str, optional
        Address of a running scheduler (not with ``workers``).

    Yields
    ------
    distributed.Client
        Closed, with its local cluster, when the block ends.
    """
    require("distributed", "running on Dask")
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
    with (
        LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
            silence_logs=logging.ERROR,
        ) as cluster,
        Client(cluster) as client,
    ):
        yield client


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


def _pinned(fn, batch, *args):
    """Run ``fn(batch, *args)`` with BLAS on one thread (the work is small matrices)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1, user_api="blas"):
        return fn(batch, *args)


def map_batches(client, fn, work: list[list], *args, progress=None) -> list:
    """``fn(batch, *args)`` for every batch on the cluster; the results of all, in order.

    ``fn`` returns one result per item of its batch; ``progress(done)`` is called with
    the number of items finished after each batch.

    Parameters
    ----------
    client : distributed.Client
        The cluster.
    fn : callable
        ``fn(batch, *args)`` returns one result per item.
    work : list of list
        The batches (see :func:`batches`).
    *args
        Passed to every call (scattered once).
    progress : callable, optional
        ``progress(done)`` after each batch.

    Returns
    -------
    list
        Every item's result, in order.
    """
    from distributed import as_completed

    futures = [client.submit(_pinned, fn, b, *args, pure=False) for b in work]
    where = {f.key: i for i, f in enumerate(futures)}
    results: list = [None] * len(work)
    done = 0
    try:
        for future in as_completed(futures):
            i = where[future.key]
            results[i] = future.result()
            done += len(work[i])
            if progress is not None:
                progress(done)
    finally:
        client.cancel([f for f in futures if not f.done()])
    return [r for batch in results for r in batch]
