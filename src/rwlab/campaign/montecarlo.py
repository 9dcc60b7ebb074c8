"""Monte Carlo pointing campaigns: per-run seeds, dispersed runs in batches, the budget.

Run ``i`` of a campaign with seed ``S`` has the seed ``seed_i`` (the i-th child
of ``numpy.random.SeedSequence(S)``); from ``seed_i`` alone come its dispersed
scenario (:func:`rwlab.campaign.dispersions.draw`) and its noise (the
simulator's streams). The controller is designed on the nominal scenario and
flown on the dispersed one. A run is therefore the same whichever worker, batch
or worker count computes it, and any row can be re-flown with :func:`fly_run`.

A :class:`RunStore` keeps the rows on disk as batches finish, so an interrupted
campaign keeps what it finished and a resumed one computes only the rest: the
rows (and so the budget) are those of an uninterrupted campaign.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rwlab.attitude.control import CONTROLLERS, fly
from rwlab.attitude.scenario import Scenario
from rwlab.attitude.sim import SimResult, steady_start
from rwlab.campaign.budget import FORMAT, REFERENCE, index_table, interpretations, rpe_verdict
from rwlab.campaign.dispersions import Dispersion, apply, draw
from rwlab.campaign.engine import batches, map_batches, worker_count
from rwlab.campaign.indices import AXES, COLUMNS, PointingRequirement, run_indices
from rwlab.campaign.quantiles import clopper_pearson_lower, quantile_table
from rwlab.errors import ConfigError, FileFormatError

__all__ = [
    "AXES",
    "MAX_RUNS",
    "STARTS",
    "Campaign",
    "Execution",
    "RunStore",
    "axis_errors_deg",
    "budget",
    "check_runs",
    "fly_run",
    "run_campaign",
    "run_seeds",
]

WORST = 5  # seeds listed in the budget
STARTS = ("acquisition", "converged")
ROW_VERSION = 2  # what a row holds (a store of older rows belongs to another campaign)
STATISTIC = "steady_max_error_deg"  # the results.parquet column the budget's quantiles summarise
MAX_RUNS = 1_000_000  # beyond this a campaign is a mistake (1e6 runs: days on a cluster)
ROW_BYTES = 16_000  # a row's memory in this process, generous (~60 keys of a dict, measured ~6 kB)


@dataclass(frozen=True)
class Campaign:
    """What every run shares.

    Attributes
    ----------
    scenario : Scenario
        The nominal scenario (the design point).
    dispersions : tuple of Dispersion
    duration : float
        Seconds per run.
    controller : str
        One of ``rwlab.attitude.control.CONTROLLERS``.
    seed : int
        The campaign's seed.
    runs : int
    epoch : str, optional
        UTC start (ISO 8601) of the real sky; None: the scenario's.
    epoch_spread_days : float
        Each run starts at ``epoch`` plus a uniform draw in [0, this) days from its seed
        (a season or a year of starts); 0: every run at ``epoch``.
    steady_after : float, optional
        Seconds from which the budget's statistics count (None: half the run, at most its
        first hour).
    start : {'acquisition', 'converged'}
        'acquisition': each run starts from its (dispersed) initial attitude error, rate and
        filter error; 'converged': on target, at the orbital rate, with the filter's
        attitude and rate estimates at the truth (the gyro bias, alignment and
        disturbance estimates still start at their priors: the loop has no hook to start
        them converged).
    requirement : PointingRequirement
        What the budget checks, and the windows of its indices.
    """

    scenario: Scenario
    dispersions: tuple[Dispersion, ...]
    duration: float
    controller: str = "lqg"
    seed: int = 0
    runs: int = 1
    epoch: str | None = None
    epoch_spread_days: float = 0.0
    steady_after: float | None = None
    start: str = "acquisition"
    requirement: PointingRequirement = field(default_factory=PointingRequirement)

    def __post_init__(self) -> None:
        if self.start not in STARTS:
            raise ConfigError(f"start must be one of {', '.join(STARTS)}, got {self.start!r}")
        if not (math.isfinite(self.epoch_spread_days) and 0 <= self.epoch_spread_days <= 3660):
            raise ConfigError(
                f"epoch_spread_days must be in [0, 3660], got {self.epoch_spread_days!r}"
            )
        if self.epoch_spread_days > 0 and (self.epoch or self.scenario.sky.epoch) is None:
            raise ConfigError("epoch_spread_days needs an epoch (the real sky)")
        if self.controller not in CONTROLLERS:
            raise ConfigError(f"controller must be one of {CONTROLLERS}, got {self.controller!r}")
        if not (math.isfinite(self.duration) and self.duration >= self.scenario.run.dt):
            raise ConfigError(f"duration must be at least one step, got {self.duration!r} s")
        if isinstance(self.runs, bool) or not isinstance(self.runs, int) or self.runs < 1:
            raise ConfigError(f"runs must be a whole number ≥ 1, got {self.runs!r}")
        if self.steady_after is not None and not (
            isinstance(self.steady_after, (int, float))
            and math.isfinite(self.steady_after)
            and 0 <= self.steady_after < self.duration
        ):
            raise ConfigError(
                f"steady_after must be in [0, duration = {self.duration:g} s), got "
                f"{self.steady_after!r}; the budget counts only t ≥ steady_after"
            )


def run_seeds(seed: int, runs: int) -> list[int]:
    """The runs' seeds: a 63-bit word from each of ``SeedSequence(seed).spawn(runs)``.

    Parameters
    ----------
    seed : int
        The campaign's seed.
    runs : int
        Number of runs.

    Returns
    -------
    list of int
    """
    children = np.random.SeedSequence(seed).spawn(runs)
    return [int(c.generate_state(1, np.uint64)[0] >> np.uint64(1)) for c in children]


def dispersed(campaign: Campaign, run_seed: int) -> tuple[Scenario, dict]:
    """The run's scenario and its dispersed values (with its epoch, when dispersed).

    The filter keeps the nominal inertia (``filter.inertia``) while the truth's is
    dispersed: the filter's model error a flight filter has."""
    values: dict = draw(campaign.dispersions, campaign.scenario, run_seed)
    sc = apply(campaign.scenario, values)
    if not campaign.scenario.filter.inertia:
        sc = sc.with_(**{"filter.inertia": tuple(campaign.scenario.spacecraft.inertia)})
    epoch = campaign.epoch or campaign.scenario.sky.epoch
    if epoch is not None:
        if campaign.epoch_spread_days > 0:
            from datetime import UTC, datetime, timedelta

            from rwlab.attitude.ephemeris import parse_epoch

            parse_epoch(epoch)  # a clear error for a bad one
            start = datetime.fromisoformat(epoch.strip())
            start = start.astimezone(UTC) if start.tzinfo else start.replace(tzinfo=UTC)
            rng = np.random.default_rng([run_seed, 0x45504F43])  # its own stream ("EPOC")
            days = rng.uniform(0, campaign.epoch_spread_days)
            epoch = (start + timedelta(seconds=round(days * 86400))).isoformat()
        sc = sc.with_(**{"sky.epoch": epoch})
        values["epoch"] = epoch
    if campaign.start == "converged":
        sc = sc.with_(**CONVERGED)
        flat = {"run.initial_rate.x": 0.0, "run.initial_rate.y": 0.0, "run.initial_rate.z": 0.0}
        for key, value in {**CONVERGED, **flat}.items():
            if key in values:  # the row says what was flown
                values[key] = value
    return sc, values


#: A converged start: on target at the orbital rate, the filter's attitude at the truth
#: (its covariance keeps the floor ``sim`` gives it, 0.1°).
CONVERGED = {
    "run.initial_error_deg": 0.0,
    "run.initial_rate": (0.0, 0.0, 0.0),
    "filter.initial_error_deg": 0.0,
}


def axis_errors_deg(q: np.ndarray) -> np.ndarray:
    """(K, 3) pointing error about body x, y, z, degrees: the rotation vector of q (K, 4)
    (orbital → body, scalar last); its norm is the total error.

    Parameters
    ----------
    q : numpy.ndarray, shape (K, 4)
        Attitude quaternions, orbital → body, scalar last.

    Returns
    -------
    numpy.ndarray, shape (K, 3)
        Error about x, y, z, degrees.
    """
    qv, q4 = q[:, :3], q[:, 3:4]
    s = np.linalg.norm(qv, axis=1, keepdims=True)
    angle = 2 * np.arctan2(s, np.abs(q4))
    unit = np.divide(
        qv * np.sign(np.where(q4 == 0, 1.0, q4)), s, out=np.zeros_like(qv), where=s > 0
    )
    return np.degrees(angle * unit)


def steady_from(campaign: Campaign) -> float:
    """Where each run's steady window starts, s (``steady_after`` or the default).

    Parameters
    ----------
    campaign : Campaign
        The campaign.

    Returns
    -------
    float
        Seconds.
    """
    if campaign.steady_after is not None:
        return float(campaign.steady_after)
    return steady_start(campaign.duration)


def _indices(run: SimResult, campaign: Campaign, sc: Scenario) -> dict:
    """The run's ECSS indices (:func:`rwlab.campaign.indices.run_indices`)."""
    bound = campaign.requirement.bound_deg(campaign.scenario.control.pointing_requirement_deg)
    know = np.degrees(run.est_error_axes) if run.est_error_axes is not None else None
    sigma = run.sigma if run.sigma is not None else None
    return run_indices(
        run.t,
        axis_errors_deg(run.q),
        know,
        run.error_deg,
        run.steady_from_s,
        campaign.requirement,
        bound,
        sigma,
    )


def fly_run(campaign: Campaign, run_seed: int, log_every: int = 1) -> tuple[SimResult, dict]:
    """Fly one run: its trace and its row (seed, dispersed values, metrics).

    Parameters
    ----------
    campaign : Campaign
        The campaign.
    run_seed : int
        The run's seed.
    log_every : int
        Steps between logged rows of the trace.

    Returns
    -------
    run : SimResult
        The trace.
    row : dict
        Seed, dispersed values and metrics.
    """
    sc, values = dispersed(campaign, run_seed)
    steps = round(campaign.duration / sc.run.dt)
    run, metrics = fly(
        sc,
        campaign.controller,
        duration=campaign.duration,
        seed=run_seed,
        log_every=max(log_every, steps // 100_000),
        design=campaign.scenario,
        steady_after=steady_from(campaign),
    )
    return run, {"seed": run_seed, **values, **metrics, **_indices(run, campaign, sc)}


def _run_batch(items: list[tuple[int, int]], campaign: Campaign) -> list[dict]:
    """Rows of a batch of (run index, seed) pairs (runs on a worker)."""
    return [{"run": i, **fly_run(campaign, s)[1]} for i, s in items]


def check_size(runs: int) -> None:
    """Refuse a number of runs that cannot end or whose rows would not fit in memory."""
    if runs > MAX_RUNS:
        raise ConfigError(f"runs={runs} is more than {MAX_RUNS:,} runs; split the campaign")
    try:
        free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):  # not on this system: no check
        return
    need = runs * ROW_BYTES
    if need > free / 2:
        raise ConfigError(
            f"runs={runs} needs about {need / 2**30:.1f} GiB for its rows and this machine has "
            f"{free / 2**30:.1f} GiB free; run fewer runs (several campaigns with other seeds)"
        )


def check_runs(campaign: Campaign) -> list[int]:
    """The runs' seeds, once every run's dispersed scenario is known to be valid.

    A dispersion that makes a scenario invalid (a negative inertia, the triangle
    inequality) fails here, naming the run, not minutes later on a worker. A
    campaign too large to end or to hold in memory fails first (:func:`check_size`).

    Parameters
    ----------
    campaign : Campaign
        The campaign.

    Returns
    -------
    list of int
        The runs' seeds.
    """
    check_size(campaign.runs)
    seeds = run_seeds(campaign.seed, campaign.runs)
    for i, s in enumerate(seeds):
        try:
            dispersed(campaign, s)
        except ConfigError as exc:
            raise ConfigError(
                f"run {i} (seed {s}): the dispersed scenario is invalid ({exc}); "
                "narrow the dispersions' bounds"
            ) from None
    return seeds


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
        _run_batch,
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
        """Plain JSON for budget.json: every re-execution counted, whoever made it.

        ``retries`` counts the batches this process submitted again, plus the runs the
        scheduler computed again on its own (lost results, or its own retries of a lost
        worker's runs beyond those this process made).
        """
        ours = sorted({r for entry in self.retries for r in entry["runs"]})
        recomputed = sorted({r for w in self.lost_workers for r in w["recomputed_runs"]})
        running = sorted({r for w in self.lost_workers for r in w["running_runs"]})
        silent = sorted(set(running) - set(ours))
        return {
            "resumed_runs": self.resumed_runs,
            "retries": len(self.retries) + len(recomputed) + len(silent),
            "retried_runs": sorted({*ours, *recomputed, *silent}),
            "recomputed_runs": recomputed,
            "retry_log": list(self.retries),
            "lost_workers": list(self.lost_workers),
        }


def campaign_key(campaign: Campaign) -> str:
    """A digest of what defines every run except their number (a resume must match it)."""
    described = {
        "scenario": dataclasses.asdict(campaign.scenario),
        "dispersions": [dataclasses.asdict(d) for d in campaign.dispersions],
        "duration": campaign.duration,
        "controller": campaign.controller,
        "seed": campaign.seed,
        "rows": ROW_VERSION,
        "steady_after": steady_from(campaign),
        "start": campaign.start,
        "requirement": dataclasses.asdict(campaign.requirement),
    }
    text = json.dumps(described, sort_keys=True, default=_plain)
    return hashlib.sha256(text.encode()).hexdigest()


def _plain(obj):
    return obj.tolist() if hasattr(obj, "tolist") else repr(obj)


class RunStore:
    """A campaign's finished runs on disk, kept as they finish (a partial campaign).

    The folder holds ``campaign.json`` (the campaign's key and description) and
    one ``batch-<first run>.json`` per finished batch, each written atomically;
    ``retries.json`` lists retried batches. JSON keeps every float exactly, so
    rows read back are the rows computed.

    Parameters
    ----------
    folder : path-like
        The store (``OUT/runs`` for ``rwlab attitude montecarlo``).
    campaign : Campaign
    """

    FORMAT = "rwlab.CampaignRuns/1"

    def __init__(self, folder: str | os.PathLike, campaign: Campaign) -> None:
        self.folder = Path(folder)
        self.campaign = campaign
        self.key = campaign_key(campaign)

    def exists(self) -> bool:
        """Whether the folder holds a store."""
        return (self.folder / "campaign.json").is_file()

    def create(self) -> None:
        """Start an empty store (the folder is created)."""
        from rwlab._io import write_json

        c = self.campaign
        write_json(
            self.folder / "campaign.json",
            {
                "format": self.FORMAT,
                "key": self.key,
                "scenario": c.scenario.name,
                "controller": c.controller,
                "duration_s": c.duration,
                "campaign_seed": c.seed,
                "runs": c.runs,
            },
        )

    def check(self) -> None:
        """Refuse a store written by another campaign (other options than this one's)."""
        path = self.folder / "campaign.json"
        head = self._read(path)
        if head.get("format") != self.FORMAT:
            raise FileFormatError(f"{path}: not a campaign's runs ({head.get('format')!r})")
        if head.get("key") != self.key:
            raise ConfigError(
                f"{path}: the kept runs belong to another campaign (scenario "
                f"{head.get('scenario')!r}, controller {head.get('controller')!r}, "
                f"duration {head.get('duration_s')} s, seed {head.get('campaign_seed')}); "
                "resume with the options it was started with"
            )

    def rows(self) -> dict[int, dict]:
        """The kept rows by run index."""
        rows: dict[int, dict] = {}
        for path in sorted(self.folder.glob("batch-*.json")):
            for row in self._read(path).get("rows", []):
                rows[int(row["run"])] = row
        return rows

    def add(self, rows: list[dict]) -> None:
        """Keep a finished batch's rows."""
        from rwlab._io import write_json

        if rows:
            write_json(self.folder / f"batch-{rows[0]['run']:09d}.json", {"rows": rows})

    def retries(self) -> list[dict]:
        """Retries recorded so far."""
        path = self.folder / "retries.json"
        return list(self._read(path).get("retries", [])) if path.is_file() else []

    def lost_workers(self) -> list[dict]:
        """Workers lost so far."""
        path = self.folder / "retries.json"
        return list(self._read(path).get("lost_workers", [])) if path.is_file() else []

    def save_retries(self, retries: list[dict], lost_workers: list[dict] | None = None) -> None:
        """Record the retries and lost workers so far."""
        from rwlab._io import write_json

        write_json(
            self.folder / "retries.json",
            {"retries": retries, "lost_workers": list(lost_workers or [])},
        )

    @staticmethod
    def _read(path: Path) -> dict:
        try:
            data = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise FileFormatError(f"{path}: not readable JSON ({exc})") from None
        if not isinstance(data, dict):
            raise FileFormatError(f"{path}: not a campaign's runs file")
        return data


def _spread(x: np.ndarray) -> dict[str, float]:
    return {
        "mean": float(np.mean(x)),
        "std": float(np.std(x, ddof=1)) if x.size > 1 else 0.0,
        "p99_73": float(np.percentile(x, 99.73)),
        "mean_plus_3std": float(np.mean(x) + 3 * np.std(x, ddof=1)) if x.size > 1 else float(x[0]),
        "max": float(np.max(x)),
    }


def budget(rows: list[dict], campaign: Campaign) -> dict:
    """The pointing budget of a campaign's rows (``budget.json``, format ``rwlab.Budget/2``).

    It opens with what a reviewer signs: ``requirement`` (the APE bound, P,
    confidence, the RPE window and bound), ``interpretation`` (ECSS-E-ST-60-10C:
    ensemble, temporal or mixed, as a sentence), ``verdict`` (met, demonstrated at
    the confidence, the runs that set it) and ``steady_window`` (where the
    statistics start, how the runs started, when they converged). Then
    ``interpretations`` (the requirement under all three, see
    :mod:`rwlab.campaign.budget`) and ``indices`` (APE, MPE, RPE, PDE, AKE, MKE,
    KDE per axis: max, worst runs, quantiles with their order-statistic bounds).
    The fields of version 1 follow unchanged: over runs of each run's steady
    maximum, ``quantiles`` of :data:`STATISTIC`, ``meets_requirement`` with its
    Clopper–Pearson bound, per-axis ``APE``, ``RPE``, ``knowledge_error``,
    mean / std / 99.73rd percentile (numpy's interpolation: with fewer than ~370
    runs it lies between the largest values) / mean + 3σ / max, peaks and the
    worst seeds.

    Parameters
    ----------
    rows : list of dict
        One per run (:func:`fly_run`'s rows).
    campaign : Campaign
        The campaign flown.

    Returns
    -------
    dict
        ``budget.json``'s content (schema ``budget``).
    """
    if not rows:
        raise ConfigError("a budget needs at least one run")
    req = campaign.requirement
    bound = req.bound_deg(campaign.scenario.control.pointing_requirement_deg)
    col = {
        k: np.array([r[k] for r in rows], dtype=float)
        for k in rows[0]
        if k != "settling_time_s"
        and not isinstance(rows[0][k], str)
        and all(r.get(k) is not None for r in rows)
    }
    pointing = {a: _spread(col[f"steady_max_error_{a}_deg"]) for a in AXES}
    pointing["total"] = _spread(col["steady_max_error_deg"])
    order = np.argsort(-col["steady_max_error_deg"], kind="stable")[:WORST]

    def peak(key: str) -> dict:
        i = int(np.argmax(col[key]))
        return {"max": float(col[key][i]), "seed": rows[i]["seed"]}

    n = len(rows)
    met = int(np.sum(col[STATISTIC] <= bound))
    checked = interpretations(rows, req, bound)
    chosen = checked[req.interpretation]
    indices = index_table(rows, req)

    def v1(pattern: str) -> dict:  # version 1's per-axis entries
        out: dict[str, dict | None] = {}
        for a in AXES:
            values = [r.get(pattern.format(a)) for r in rows]
            if any(v is None for v in values):
                out[a] = None
                continue
            x = np.array(values, dtype=float)
            out[a] = {"max": float(np.max(x)), "quantiles": quantile_table(x)}
        return out

    return {
        "format": FORMAT,
        "requirement": {
            "ape_deg": bound,
            "applies_to": "the total pointing error (the rotation angle), steady window",
            "probability": req.probability,
            "confidence": req.confidence,
            "rpe_deg": req.rpe_deg,
            "rpe_window_s": req.rpe_window_s,
            "drift_window_s": req.drift_window_s,
            "drift_separation_s": req.drift_separation_s,
        },
        "interpretation": {
            "name": req.interpretation,
            "statement": chosen["statement"],
            "reference": REFERENCE,
        },
        "verdict": {
            "met": bool(chosen["met"]),
            "demonstrated": bool(chosen["demonstrated"]),
            "estimate": chosen["estimate"],
            "lower_bound": chosen["lower_bound"],
            "confidence": req.confidence,
            "runs": n,
            "runs_needed": chosen["runs_needed"],
            "worst_runs": chosen["worst_runs"],
            "rpe": rpe_verdict(rows, req),
            "text": _verdict_text(chosen, req, bound, n),
        },
        "steady_window": _steady_window(rows, campaign),
        "interpretations": checked,
        "indices": indices,
        "runs": n,
        "scenario": campaign.scenario.name,
        "epoch": campaign.epoch or campaign.scenario.sky.epoch,
        "epoch_spread_days": campaign.epoch_spread_days,
        "statistic_column": STATISTIC,
        "quantiles": quantile_table(col[STATISTIC], req.confidence),
        "meets_requirement": {
            "fraction": met / n,
            "lower_bound_95": clopper_pearson_lower(met, n, 0.95),
        },
        "APE": v1(COLUMNS["APE"]),
        "RPE": {"window_s": req.rpe_window_s, **v1(COLUMNS["RPE"])},
        "knowledge_error": v1(COLUMNS["AKE"]),
        "shadow_s": {
            "min": float(np.min(col["eclipse_s"])),
            "max": float(np.max(col["eclipse_s"])),
        },
        "controller": campaign.controller,
        "duration_s": campaign.duration,
        "campaign_seed": campaign.seed,
        "dispersed": [d.field for d in campaign.dispersions],
        "requirement_deg": bound,
        "pointing_error_deg": pointing,
        "pointing_statistic": "per run: the steady-state maximum |error| (total from every "
        "step, axes from the logged trace); across runs: mean, std, 99.73rd percentile, max",
        "meets_requirement_fraction": met / n,
        "torque_peak_Nm": peak("torque_peak_Nm"),
        "wheel_momentum_peak_fraction": peak("wheel_momentum_peak_fraction"),
        "torque_saturated_fraction": peak("torque_saturated_fraction"),
        "worst_seeds": [
            {
                "seed": rows[i]["seed"],
                "run": rows[i].get("run"),
                "steady_max_error_deg": float(col["steady_max_error_deg"][i]),
            }
            for i in order
        ],
    }


def _verdict_text(chosen: dict, req: PointingRequirement, bound: float, n: int) -> str:
    """The verdict in one sentence."""
    if chosen["demonstrated"]:
        word = f"MET and demonstrated at {req.confidence:.0%} confidence"
    elif chosen["met"]:
        word = (
            f"MET by the estimate, not demonstrated at {req.confidence:.0%} confidence "
            f"({n} runs; {chosen['runs_needed']} runs without a miss would)"
        )
    else:
        word = "NOT MET"
    if req.interpretation == "temporal":
        return (
            f"APE ≤ {bound:g}° for {req.probability:.4g} of the time in the worst run "
            f"(temporal interpretation): {word}; the worst run's {req.probability:.4g}-quantile "
            f"is {chosen['estimate']:.4g}°"
        )
    return (
        f"APE ≤ {bound:g}° for {req.probability:.4g} ({req.interpretation} interpretation): "
        f"{word}; estimate {chosen['estimate']:.4g}, {req.confidence:.0%} lower bound "
        f"{chosen['lower_bound']:.4g}"
    )


def _steady_window(rows: list[dict], campaign: Campaign) -> dict:
    """Where the statistics start, how the runs started, and when they converged."""
    start = steady_from(campaign)

    def latest(key: str) -> dict:
        known = [r for r in rows if r.get(key) is not None]
        never = [r.get("run") for r in rows if r.get(key) is None]
        if not known:
            return {"max_s": None, "run": None, "not_converged_runs": never}
        worst = max(known, key=lambda r: r[key])
        return {"max_s": float(worst[key]), "run": worst.get("run"), "not_converged_runs": never}

    settled = latest("settled_s")
    filt = latest("filter_converged_s")
    late = [
        r.get("run")
        for r in rows
        if r.get("settled_s") is None
        or r["settled_s"] > start
        or (r.get("filter_converged_s") or 0.0) > start
    ]
    return {
        "start_s": start,
        "source": "steady_after"
        if campaign.steady_after is not None
        else "default: half the run, at most its first hour",
        "start": campaign.start,
        "settled": settled,
        "filter_converged": filt,
        "runs_converged_after_start": late,
        "definition": "settled: the time after which the total error stays within the APE bound "
        "to the end; filter converged: the first time every σ the filter logs (attitude, and "
        "rate or gyro bias) is within 1.5× its median over the run's second half",
    }
