"""Monte Carlo pointing campaigns: per-run seeds, dispersed runs in batches, the budget.

Run ``i`` of a campaign with seed ``S`` has the seed ``seed_i`` (the i-th child
of ``numpy.random.SeedSequence(S)``); from ``seed_i`` alone come its dispersed
scenario (:func:`rwlab.campaign.dispersions.draw`) and its noise (the
simulator's streams). The controller is designed on the nominal scenario and
flown on the dispersed one. A run is therefore the same whichever worker, batch
or worker count computes it, and any row can be re-flown with :func:`fly_run`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rwlab.attitude.control import CONTROLLERS, fly
from rwlab.attitude.scenario import Scenario
from rwlab.attitude.sim import SimResult
from rwlab.campaign.dispersions import Dispersion, apply, draw
from rwlab.campaign.engine import batches, map_batches, worker_count
from rwlab.errors import ConfigError

__all__ = [
    "AXES",
    "Campaign",
    "axis_errors_deg",
    "budget",
    "check_runs",
    "fly_run",
    "run_campaign",
    "run_seeds",
]

AXES = ("x", "y", "z")
WORST = 5  # seeds listed in the budget


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
    """

    scenario: Scenario
    dispersions: tuple[Dispersion, ...]
    duration: float
    controller: str = "lqg"
    seed: int = 0
    runs: int = 1

    def __post_init__(self) -> None:
        if self.controller not in CONTROLLERS:
            raise ConfigError(f"controller must be one of {CONTROLLERS}, got {self.controller!r}")
        if not (math.isfinite(self.duration) and self.duration >= self.scenario.dt):
            raise ConfigError(f"duration must be at least one step, got {self.duration!r} s")
        if isinstance(self.runs, bool) or not isinstance(self.runs, int) or self.runs < 1:
            raise ConfigError(f"runs must be a whole number ≥ 1, got {self.runs!r}")


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


def dispersed(campaign: Campaign, run_seed: int) -> tuple[Scenario, dict[str, float]]:
    """The run's scenario and its dispersed values."""
    values = draw(campaign.dispersions, campaign.scenario, run_seed)
    return apply(campaign.scenario, values), values


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


def _axis_metrics(run: SimResult) -> dict[str, float]:
    """Per axis over the steady window of the logged trace: max |error|, RMS and mean."""
    err = axis_errors_deg(run.q[run.t >= run.steady_from_s])
    out = {}
    for i, a in enumerate(AXES):
        e = err[:, i]
        out[f"steady_max_error_{a}_deg"] = float(np.max(np.abs(e))) if e.size else 0.0
        out[f"steady_rms_error_{a}_deg"] = float(np.sqrt(np.mean(e**2))) if e.size else 0.0
        out[f"steady_mean_error_{a}_deg"] = float(np.mean(e)) if e.size else 0.0
    return out


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
    steps = round(campaign.duration / sc.dt)
    run, metrics = fly(
        sc,
        campaign.controller,
        duration=campaign.duration,
        seed=run_seed,
        log_every=max(log_every, steps // 100_000),
        design=campaign.scenario,
    )
    return run, {"seed": run_seed, **values, **metrics, **_axis_metrics(run)}


def _run_batch(items: list[tuple[int, int]], campaign: Campaign) -> list[dict]:
    """Rows of a batch of (run index, seed) pairs (runs on a worker)."""
    return [{"run": i, **fly_run(campaign, s)[1]} for i, s in items]


def check_runs(campaign: Campaign) -> list[int]:
    """The runs' seeds, once every run's dispersed scenario is known to be valid.

    A dispersion that makes a scenario invalid (a negative inertia, the triangle
    inequality) fails here, naming the run, not minutes later on a worker.

    Parameters
    ----------
    campaign : Campaign
        The campaign.

    Returns
    -------
    list of int
        The runs' seeds.
    """
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


def run_campaign(campaign: Campaign, client, *, progress=None) -> list[dict]:
    """Every run's row, in run order, computed in batches on ``client``'s workers
    (``progress(runs done)`` after each batch).

    Parameters
    ----------
    campaign : Campaign
        The campaign.
    client : distributed.Client
        The cluster.
    progress : callable, optional
        ``progress(runs done)``.

    Returns
    -------
    list of dict
        One row per run.
    """
    seeds = check_runs(campaign)
    work = batches(list(enumerate(seeds)), worker_count(client))
    return map_batches(client, _run_batch, work, campaign, progress=progress)


def _spread(x: np.ndarray) -> dict[str, float]:
    return {
        "mean": float(np.mean(x)),
        "std": float(np.std(x, ddof=1)) if x.size > 1 else 0.0,
        "p99_73": float(np.percentile(x, 99.73)),
        "mean_plus_3std": float(np.mean(x) + 3 * np.std(x, ddof=1)) if x.size > 1 else float(x[0]),
        "max": float(np.max(x)),
    }


def budget(rows: list[dict], campaign: Campaign) -> dict:
    """The pointing budget of a campaign's rows (``budget.json``).

    For each axis and the total, the statistics are over runs of each run's
    steady-state maximum |error| (total: from every step; axes: from the logged
    trace). The 99.73rd percentile is numpy's linear interpolation: with fewer
    than ~370 runs it lies between the largest values, so ``mean_plus_3std`` (the
    Gaussian 3σ) is given next to it.

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
    req = campaign.scenario.pointing_requirement_deg
    col = {
        k: np.array([r[k] for r in rows], dtype=float) for k in rows[0] if k != "settling_time_s"
    }
    pointing = {a: _spread(col[f"steady_max_error_{a}_deg"]) for a in AXES}
    pointing["total"] = _spread(col["steady_max_error_deg"])
    order = np.argsort(-col["steady_max_error_deg"], kind="stable")[:WORST]

    def peak(key: str) -> dict:
        i = int(np.argmax(col[key]))
        return {"max": float(col[key][i]), "seed": rows[i]["seed"]}

    return {
        "runs": len(rows),
        "scenario": campaign.scenario.name,
        "controller": campaign.controller,
        "duration_s": campaign.duration,
        "campaign_seed": campaign.seed,
        "dispersed": [d.field for d in campaign.dispersions],
        "requirement_deg": req,
        "pointing_error_deg": pointing,
        "pointing_statistic": "per run: the steady-state maximum |error| (total from every "
        "step, axes from the logged trace); across runs: mean, std, 99.73rd percentile, max",
        "meets_requirement_fraction": float(np.mean(col["steady_max_error_deg"] <= req)),
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
