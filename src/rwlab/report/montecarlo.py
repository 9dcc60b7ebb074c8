"""The ``rwlab attitude montecarlo`` workflow, callable from Python with the command's arguments.

:func:`montecarlo` runs a pointing campaign on Dask and writes its folder
(``results.parquet``, ``budget.json``, ``report.html``) for the
:class:`CampaignOptions` given; ``rwlab.montecarlo(out, scenario=..., runs=...)``
takes the same as keywords. Finished runs are kept
in ``OUT.partial`` as they finish, so that an interrupted campaign continues
with ``resume=True``, computing only the runs it lacks.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from rwlab._io import output_folder
from rwlab.campaign.indices import PointingRequirement
from rwlab.errors import ConfigError, RwlabError
from rwlab.interrupts import stopped

__all__ = ["CampaignOptions", "montecarlo"]

# write_campaign's files (report.campaign.CAMPAIGN_FILES, a test holds them equal), named
# here so that the folder is locked before the loop is loaded
_FILES = ("results.parquet", "budget.json", "report.html")


@dataclass(frozen=True)
class CampaignOptions:
    """What a campaign computes, as the command's options name it (files and names, not
    yet loaded: :func:`montecarlo` loads and checks them).

    Attributes
    ----------
    scenario : str
        A built-in scenario or a scenario TOML file.
    runs : int
        Number of runs.
    duration : float
        Seconds per run.
    controller : {'pd', 'lqr', 'lqg', 'lqg_ltr'}
        Designed on the nominal scenario, flown on each dispersed one.
    dispersions : str or os.PathLike, optional
        A dispersions TOML file (rwlab's GEO set by default).
    seed : int
        The campaign's seed; each run's is a child of it.
    epoch : str, optional
        UTC start, ISO 8601: the real sky.
    epoch_spread_days : float
        Each run starts at ``epoch`` plus a uniform draw of up to this many days.
    steady_after : float, optional
        Seconds from which the budget counts (default: half the run, at most an hour).
    start : {'acquisition', 'converged'}
        How each run starts (see :class:`rwlab.campaign.runs.Campaign`).
    requirement : PointingRequirement
        What the budget checks, its interpretation and windows (default: the
        scenario's APE bound, P = 0.95 of the runs, 95 % confidence, ensemble).
    """

    scenario: str = "geo-comsat"
    runs: int = 100
    duration: float = 3600.0
    controller: str = "lqg"
    dispersions: str | os.PathLike | None = None
    seed: int = 0
    epoch: str | None = None
    epoch_spread_days: float = 0.0
    steady_after: float | None = None
    start: str = "acquisition"
    requirement: PointingRequirement = field(default_factory=PointingRequirement)

    def campaign(self):
        """The :class:`~rwlab.campaign.runs.Campaign`: scenario and dispersions loaded.

        Returns
        -------
        Campaign
        """
        from rwlab.attitude.scenario import load_scenario
        from rwlab.campaign.dispersions import load_dispersions
        from rwlab.campaign.runs import Campaign

        return Campaign(
            load_scenario(self.scenario),
            load_dispersions(self.dispersions),
            self.duration,
            self.controller,
            self.seed,
            self.runs,
            epoch=self.epoch,
            epoch_spread_days=self.epoch_spread_days,
            steady_after=self.steady_after,
            start=self.start,
            requirement=self.requirement,
        )


def montecarlo(
    out: str | os.PathLike,
    options: CampaignOptions | None = None,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    resume: bool = False,
    progress: Callable[[int], None] | None = None,
    echo: Callable[[str], None] | None = None,
) -> tuple[dict, dict[str, Path]]:
    """A Monte Carlo pointing campaign, written into the folder ``out``.

    Parameters
    ----------
    out : str or os.PathLike
        The output folder (locked first; written whole or not at all).
    options : CampaignOptions, optional
        What the campaign computes (default: ``CampaignOptions()``).
    workers : int, optional
        Processes of a new local Dask cluster (default: the cores).
    scheduler : str, optional
        Address of a running Dask scheduler.
    force : bool
        Replace a previous campaign in ``out`` and start over (only when this one
        succeeds).
    resume : bool
        Continue the interrupted campaign kept in ``OUT.partial`` (same arguments).
    progress : callable, optional
        ``progress(done)``: runs finished so far (kept ones included), after each batch.
    echo : callable, optional
        ``echo(line)`` for what the campaign says on the way (where it runs,
        resuming, stopped, retried batches).

    Returns
    -------
    stats : dict
        Every number of ``budget.json``.
    paths : dict of str to Path
        The files written, by name (in ``out``).
    """
    options = options if options is not None else CampaignOptions()
    runs, duration = options.runs, options.duration
    say = echo or (lambda _text: None)
    if resume and force:
        raise ConfigError(
            "resume=True continues the kept runs and force=True starts over: give one of them"
        )
    if workers is not None and scheduler is not None:  # before anything is kept
        raise ConfigError("workers= and scheduler= both given: give one of them")
    with output_folder(out, _FILES, force=force, what="Monte Carlo campaign") as stage:
        from rwlab.campaign.budget import budget
        from rwlab.campaign.engine import dask_client
        from rwlab.campaign.montecarlo import Execution, run_campaign
        from rwlab.campaign.runs import check_runs, check_size, fly_run
        from rwlab.report.campaign import write_campaign

        check_size(runs)
        campaign = options.campaign()
        check_runs(campaign)  # before the cluster starts and anything is kept
        store = _run_store(out, campaign, force=force, resume=resume, say=say)
        where = scheduler or f"a local Dask cluster of {workers or 'one per core'} worker processes"
        say(f"{runs} runs of {duration:g} s on {where} (workers load the loop)...")
        execution = Execution()
        try:
            with dask_client(workers, scheduler) as client:
                rows = run_campaign(
                    campaign,
                    client,
                    progress=progress,
                    store=store,
                    execution=execution,
                    say=say,
                )
        except KeyboardInterrupt as exc:  # one line: the signal, what is kept, how to go on
            why = stopped() or (exc.args[0] if exc.args else "interrupted")
            raise KeyboardInterrupt(
                f"{why}; campaign stopped: {len(store.rows())} of {runs} runs kept in "
                f"{store.folder}, continue it with the same arguments and resume=True"
            ) from None
        except (RwlabError, OSError):
            say(
                f"\ncampaign stopped: {len(store.rows())} of {runs} runs kept in "
                f"{store.folder}; continue it with the same arguments and resume=True"
            )
            raise
        stats = {**budget(rows, campaign), "execution": execution.to_dict()}
        worst, _ = fly_run(campaign, stats["verdict"]["worst_runs"][0]["seed"])
        paths = write_campaign(rows, stats, campaign, worst, stage, force=force)
    shutil.rmtree(store.folder, ignore_errors=True)  # the campaign is complete in OUT
    ex = stats["execution"]
    if ex["runs_flown_again"] or ex["lost_workers"]:
        say(
            f"{len(ex['lost_workers'])} worker(s) lost, {ex['runs_flown_again']} run(s) flown "
            "again: runs "
            f"{ex['retried_runs']} computed again (each run depends only on its seed: the "
            "rows are those of an undisturbed campaign); see execution in budget.json"
        )
    return stats, {name: Path(out) / Path(p).name for name, p in paths.items()}


def _run_store(out, campaign, *, force: bool, resume: bool, say: Callable[[str], None]):
    """The campaign's kept runs (OUT.partial): resumed, started over, or new."""
    from rwlab.campaign.store import RunStore

    base = Path(os.path.abspath(out))
    store = RunStore(base.with_name(base.name + ".partial"), campaign)
    if store.exists() and resume:
        store.check()
        say(f"resuming: {len(store.rows())} runs kept in {store.folder}")
        return store
    if resume:
        raise ConfigError(f"nothing to resume: {store.folder} holds no interrupted campaign")
    if store.exists() and not force:
        raise FileExistsError(
            f"{store.folder} holds an interrupted campaign ({len(store.rows())} runs kept); "
            "continue it with resume=True, or start over with force=True"
        )
    shutil.rmtree(store.folder, ignore_errors=True)
    store.create()
    return store
