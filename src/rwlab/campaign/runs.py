"""One run of a Monte Carlo campaign: what every run shares, its seed, its dispersed
scenario, its flight and its row.

Run ``i`` of a campaign with seed ``S`` has the seed ``seed_i`` (the i-th child
of ``numpy.random.SeedSequence(S)``); from ``seed_i`` alone come its dispersed
scenario (:func:`rwlab.campaign.dispersions.draw`) and its noise (the
simulator's streams). The controller is designed on the nominal scenario and
flown on the dispersed one. A run is therefore the same whichever worker, batch
or worker count computes it, and any row can be re-flown with :func:`fly_run`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from rwlab.attitude.control import CONTROLLERS, fly
from rwlab.attitude.scenario import Scenario
from rwlab.attitude.sim import SimResult, steady_start
from rwlab.campaign.dispersions import Dispersion, apply, draw
from rwlab.campaign.indices import AXES, PointingRequirement, run_indices
from rwlab.errors import ConfigError

__all__ = [
    "AXES",
    "MAX_RUNS",
    "STARTS",
    "Campaign",
    "axis_errors_deg",
    "check_runs",
    "check_size",
    "dispersed",
    "fly_run",
    "run_batch",
    "run_seeds",
    "steady_from",
]

STARTS = ("acquisition", "converged")
ROW_VERSION = 3  # what a row holds (a store of older rows belongs to another campaign)
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
    dispersed: the filter's model error a flight filter has.

    Parameters
    ----------
    campaign : Campaign
        The campaign.
    run_seed : int
        The run's seed.

    Returns
    -------
    scenario : Scenario
        The dispersed scenario the run flies.
    values : dict
        Each dispersed field's value by its dotted name (and ``epoch``), as flown.
    """
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


def run_batch(items: list[tuple[int, int]], campaign: Campaign) -> list[dict]:
    """Rows of a batch of runs (runs on a worker).

    Parameters
    ----------
    items : list of (int, int)
        (run index, run seed) pairs.
    campaign : Campaign
        The campaign.

    Returns
    -------
    list of dict
        One row per item, with its ``run`` index, in order.
    """
    return [{"run": i, **fly_run(campaign, s)[1]} for i, s in items]


def check_size(runs: int) -> None:
    """Refuse a number of runs that cannot end or whose rows would not fit in memory.

    Parameters
    ----------
    runs : int
        Number of runs.
    """
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
