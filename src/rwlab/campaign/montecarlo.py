"""Monte Carlo pointing campaigns on Dask: every run's row, in batches over the workers.

Each run depends only on its seed (:mod:`rwlab.campaign.runs`), so the rows are
the same whichever worker, batch or worker count computes them; finished
batches go to a :class:`~rwlab.campaign.store.RunStore` as they finish, and what
the cluster did on the way (runs resumed, batches retried, workers lost) is an
:class:`Execution`. The budget of the rows is :func:`rwlab.campaign.budget.budget`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from rwlab.campaign.engine import batches, map_batches, worker_count
from rwlab.campaign.runs import Campaign, check_runs, run_batch
from rwlab.campaign.store import RunStore

__all__ = ["Execution", "run_campaign", "tasks_per_worker"]


def run_campaign(
    campaign: Campaign,
    client,
    *,
    progress=None,
    store: RunStore | None = None,
    execution: Execution | None = None,
    say=None,
) -> list[dict]:
    """Every run's row, in run order, computed in batches on ``client``'s workers.

    Parameters
    ----------
    campaign : Campaign
        The campaign.
    client : distributed.Client
        The cluster.
    progress : callable, optional
        ``progress(runs done)`` after each batch (runs kept from before included).
    store : RunStore, optional
        Where finished batches are kept as they finish; runs it already holds
        are not computed again (a resumed campaign).
    execution : Execution, optional
        Filled with what happened: runs kept from before, batches retried, workers lost.
    say : callable, optional
        ``say(line)`` when a worker is lost or a batch retried (the console).

    Returns
    -------
    list of dict
        One row per run, in run order.
    """
    seeds = check_runs(campaign)
    execution = execution if execution is not None else Execution()
    kept = store.rows() if store is not None else {}
    kept = {i: r for i, r in kept.items() if i < campaign.runs}
    execution.resumed_runs = len(kept)
    if store is not None:
        execution.retries.extend(store.retries())
        execution.lost_workers.extend(store.lost_workers())
    todo = [(i, s) for i, s in enumerate(seeds) if i not in kept]
    workers = worker_count(client)
    per_worker = tasks_per_worker(len(todo), campaign.duration, workers)
    work = batches(todo, workers, per_worker) if todo else []

    def keep(i: int, rows: list[dict]) -> None:
        if store is not None:
            store.add(rows)

    def save() -> None:
        if store is not None:
            store.save_retries(execution.retries, execution.lost_workers)

    def retried(i: int, attempt: int, reason: str) -> None:
        runs = [run for run, _ in work[i]]
        execution.retries.append({"runs": runs, "attempt": attempt, "reason": reason})
        save()
        if say is not None:
            say(f"retrying runs {_span(runs)} (attempt {attempt}): {reason}")

    def lost(worker) -> None:
        entry = {
            "address": worker.address,
            "time": worker.time,
            "running_runs": sorted(run for i in worker.running for run, _ in work[i]),
            "recomputed_runs": sorted(run for i in worker.recomputed for run, _ in work[i]),
        }
        execution.lost_workers.append(entry)
        save()
        if say is not None:
            what = [f"it was computing runs {_span(entry['running_runs'])}"] * bool(
                entry["running_runs"]
            ) + [
                f"runs {_span(entry['recomputed_runs'])} it had finished are computed again"
            ] * bool(entry["recomputed_runs"])
            say(f"worker {worker.address} lost" + (f": {'; '.join(what)}" if what else ""))

    if progress is not None and kept:
        progress(len(kept))
    new = map_batches(
        client,
        run_batch,
        work,
        campaign,
        progress=None if progress is None else (lambda k: progress(len(kept) + k)),
        on_batch=keep,
        on_retry=retried,
        on_lost_worker=lost,
    )
    rows = {**kept, **{r["run"]: r for r in new}}
    return [rows[i] for i in range(campaign.runs)]


def tasks_per_worker(runs: int, duration: float, workers: int) -> int:
    """Tasks per worker: about an hour of simulated time each, 4 to 64 per worker.

    Long runs go one or a few to a task, so that the campaign's tail (the last
    worker busy while the others idle) is one short task, not a quarter of a
    worker's share; short runs are grouped, so that Dask's per-task cost stays
    small against the work; at most 64 per worker keeps the kept batches' files few.

    Parameters
    ----------
    runs : int
        Runs to compute.
    duration : float
        Seconds simulated per run.
    workers : int
        Workers.

    Returns
    -------
    int
    """
    hours = runs * duration / 3600.0
    return int(min(64, max(4, math.ceil(hours / max(1, workers)))))


def _span(runs: list[int]) -> str:
    """Run indices in words: "3–7" for a contiguous span, else the list."""
    if runs and runs == list(range(runs[0], runs[-1] + 1)) and len(runs) > 2:
        return f"{runs[0]}–{runs[-1]}"
    return ", ".join(map(str, runs))


@dataclass
class Execution:
    """How a campaign ran: runs kept from an interrupted run, batches retried, workers lost.

    Attributes
    ----------
    resumed_runs : int
        Runs read back from a :class:`RunStore` rather than computed.
    retries : list of dict
        One entry per batch this process submitted again: ``runs`` (the run indices of
        the batch), ``attempt`` (1 for the first retry of that batch) and ``reason``.
    lost_workers : list of dict
        One entry per worker the scheduler lost: ``address``, ``time`` (Unix, s),
        ``running_runs`` (the runs it was computing) and ``recomputed_runs`` (runs it
        had finished whose results were lost before they were gathered, computed again
        by the scheduler without an error).
    """

    resumed_runs: int = 0
    retries: list[dict] = field(default_factory=list)
    lost_workers: list[dict] = field(default_factory=list)

    def to_dict(self) -> dict:
        """Plain JSON for budget.json: every re-execution counted, whoever made it, in runs.

        ``runs_flown_again`` counts run executions beyond each run's first: every run of
        each batch this process submitted again (a batch of 3 runs retried twice: 6), plus
        the runs the scheduler computed again on its own (lost results, or its own retries
        of a lost worker's runs beyond those this process made). ``batches_resubmitted``
        counts this process's resubmissions alone. (Version 2 added batches and runs in
        one ``retries`` count.)

        Returns
        -------
        dict
            ``resumed_runs``, ``runs_flown_again``, ``batches_resubmitted``,
            ``retried_runs``, ``recomputed_runs``, ``retry_log``, ``lost_workers``.
        """
        ours = sorted({r for entry in self.retries for r in entry["runs"]})
        recomputed = sorted({r for w in self.lost_workers for r in w["recomputed_runs"]})
        running = sorted({r for w in self.lost_workers for r in w["running_runs"]})
        silent = sorted(set(running) - set(ours))
        return {
            "resumed_runs": self.resumed_runs,
            "runs_flown_again": sum(len(e["runs"]) for e in self.retries)
            + len(recomputed)
            + len(silent),
            "batches_resubmitted": len(self.retries),
            "retried_runs": sorted({*ours, *recomputed, *silent}),
            "recomputed_runs": recomputed,
            "retry_log": list(self.retries),
            "lost_workers": list(self.lost_workers),
        }
