"""The campaign's progress counter: runs finished, each once, whatever was retried or kept."""

from __future__ import annotations

import io
import threading
from contextlib import redirect_stderr

import pytest

from rwlab.campaign.engine import batches, map_batches
from rwlab.cli._common import _steps_progress

_FAILED: set[int] = set()
_LOCK = threading.Lock()


class _Gone:
    """The worker a KilledWorker names (its address is all the message reads)."""

    address = "tcp://127.0.0.1:1"


def _flaky(batch: list[int]) -> list[int]:
    """Each item times ten; the batch starting at 3 loses its worker once (as Dask says it)."""
    from distributed.scheduler import KilledWorker

    with _LOCK:
        first = batch[0] == 3 and 3 not in _FAILED
        _FAILED.add(batch[0])
    if first:
        raise KilledWorker(batch[0], _Gone(), 0)  # type: ignore[arg-type]
    return [x * 10 for x in batch]


def test_progress_counts_finished_runs_once_across_a_retry():
    """A retried batch counts when it finishes, once; the count ends at the number of runs
    and never passes it (version 2 counted the same, but the console printed the tenth
    below, e.g. "10 % (2 of 12 runs)")."""
    from distributed import Client, LocalCluster

    _FAILED.clear()
    work = batches(list(range(12)), n_workers=1, per_worker=4)  # [0–2], [3–5], [6–8], [9–11]
    seen: list[int] = []
    retried: list[tuple[int, int]] = []
    with (
        LocalCluster(
            n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None
        ) as cluster,
        Client(cluster) as client,
    ):
        out = map_batches(
            client,
            _flaky,
            work,
            progress=seen.append,
            on_retry=lambda i, attempt, _why: retried.append((i, attempt)),
        )
    assert out == [x * 10 for x in range(12)]
    assert retried == [(1, 1)]
    assert seen == sorted(seen) and len(set(seen)) == len(seen) == len(work)
    assert seen[-1] == 12 and {b - a for a, b in zip([0, *seen], seen, strict=False)} == {3}


@pytest.mark.parametrize(
    ("done", "line"),
    [(2, "16 % (2 of 12 runs)"), (8, "66 % (8 of 12 runs)"), (12, "100 % (12 of 12 runs)")],
)
def test_the_console_prints_the_share_done_not_the_tenth_below(done, line):
    err = io.StringIO()
    with redirect_stderr(err), _steps_progress(12, "lqg campaign", unit="runs") as report:
        report(done)
    assert err.getvalue().strip() == f"lqg campaign: {line}"
