"""Imported by the fork server that starts local Dask workers: a worker forked while
its cluster closes exits without a traceback.

When rwlab is interrupted (SIGTERM, Ctrl-C) while a nanny starts a worker, the
cluster frees the worker's semaphores before the fork server's child unpickles
them; the child then fails with ``FileNotFoundError`` and multiprocessing prints
its traceback after rwlab's "interrupted" line. That child has no cluster to
join, so it exits quietly; every other error is printed as before. Importing this
module replaces ``sys.excepthook`` of the importing process: only the fork
server imports it (``rwlab.campaign.engine.WORKER_PRELOAD``).
"""

from __future__ import annotations

import sys
import traceback


def _is_orphaned_start(exc_type: type[BaseException], tb) -> bool:
    """Whether the error is a semaphore gone before a forked worker could rebuild it."""
    if not issubclass(exc_type, FileNotFoundError):
        return False
    return any(
        frame.name == "__setstate__" and frame.filename.endswith("synchronize.py")
        for frame in traceback.extract_tb(tb)
    )


def _excepthook(exc_type, exc, tb) -> None:
    if not _is_orphaned_start(exc_type, tb):
        sys.__excepthook__(exc_type, exc, tb)


sys.excepthook = _excepthook
