"""Monte Carlo campaign scaling: 1 and 2 Dask workers back to back, with the noise.

Run:  python bench/bench_campaign.py [--runs 24] [--duration 3600] [--repeats 3]

Each run: geo-smallsat with rwlab's default dispersions, the LQG loop (MEKF),
``--duration`` s at dt = 0.1 s, as ``rwlab attitude montecarlo`` flies it.
"in process" flies the runs one after the other without Dask (the floor).
Then, ``--repeats`` times, alternating, a campaign on a fresh local cluster of
1 worker and one of 2: start-up (processes, imports, every worker loading the
compiled loop from numba's cache: ``client.run`` warms each worker, so no
worker compiles or loads inside the timed campaign) and the campaign apart.
Workers are forked from a fork server that imported distributed and rwlab's
campaign modules once (``engine.WORKER_PRELOAD``); the first cluster of the
process starts that server (its imports are in that cluster's start-up), the
later ones reuse it: the table marks the first. ``--spawn`` starts every worker
as a fresh interpreter instead (distributed's default, the engine's before
issue 44), for comparison.
Besides wall time, each task reports its process CPU time: when the CPU
seconds per run stay the same on 2 workers but the wall time does not halve,
the cores were busy with something else (a shared machine), not with Dask.
The machine's 1-minute load average is printed beside each campaign.

A benchmark, not a test: numbers depend on the machine's load.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

from threadpoolctl import threadpool_limits

from rwlab.attitude.scenario import load_scenario
from rwlab.campaign.dispersions import load_dispersions
from rwlab.campaign.engine import WORKER_PRELOAD, batches, dask_client, map_batches
from rwlab.campaign.runs import Campaign, fly_run, run_seeds


def timed_batch(items, campaign):
    """A campaign batch that also reports its CPU seconds (runs on a worker)."""
    cpu = time.process_time()
    for _, seed in items:
        fly_run(campaign, seed)
    return [time.process_time() - cpu] + [0.0] * (len(items) - 1)


def warm(campaign):
    """Load the compiled loop on this worker (one short run)."""
    short = Campaign(campaign.scenario, campaign.dispersions, 10.0, campaign.controller, 1, 1)
    fly_run(short, run_seeds(1, 1)[0])
    return os.getpid()


def in_process(campaign: Campaign) -> float:
    seeds = run_seeds(campaign.seed, campaign.runs)
    fly_run(campaign, seeds[0])  # compile / load the cache outside the timing
    t0 = time.perf_counter()
    for s in seeds:
        fly_run(campaign, s)
    return time.perf_counter() - t0


def on_dask(campaign: Campaign, workers: int, spawn: bool) -> tuple[float, float, float]:
    """(start-up s, campaign wall s, worker CPU s) of one campaign on a new cluster."""
    t0 = time.perf_counter()
    with dask_client(workers, preload=None if spawn else WORKER_PRELOAD) as client:
        client.run(warm, campaign)
        startup = time.perf_counter() - t0
        work = batches(list(enumerate(run_seeds(campaign.seed, campaign.runs))), workers)
        t1 = time.perf_counter()
        cpu = map_batches(client, timed_batch, work, campaign)
        elapsed = time.perf_counter() - t1
    return startup, elapsed, sum(cpu)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=24)
    parser.add_argument("--duration", type=float, default=3600.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--spawn", action="store_true", help="spawn every worker afresh (no fork server)"
    )
    args = parser.parse_args()
    c = Campaign(
        load_scenario("geo-smallsat"), load_dispersions(), args.duration, "lqg", 5, args.runs
    )
    print(
        f"{args.runs} runs, geo-smallsat, LQG, {args.duration:g} s each (dt 0.1 s), "
        f"{os.cpu_count()} cores"
    )
    with threadpool_limits(1, user_api="blas"):
        serial = in_process(c)
    print(f"in process (no Dask): {serial:.2f} s, {args.runs / serial:.2f} runs/s")
    print(
        f"{'repeat':>6} {'workers':>7} {'start-up [s]':>12} {'campaign [s]':>12} "
        f"{'CPU/run [s]':>11} {'runs/s':>7} {'load':>5}"
    )
    walls: dict[int, list[float]] = {1: [], 2: []}
    starts: dict[int, list[float]] = {1: [], 2: []}
    for k in range(args.repeats):
        for workers in (1, 2):
            startup, elapsed, cpu = on_dask(c, workers, args.spawn)
            walls[workers].append(elapsed)
            starts[workers].append(startup)
            print(
                f"{k + 1:>6} {workers:>7} {startup:12.1f} {elapsed:12.2f} "
                f"{cpu / args.runs:11.3f} {args.runs / elapsed:7.2f} {os.getloadavg()[0]:5.1f}"
                + (
                    "  (starts the fork server)"
                    if k == 0 and workers == 1 and not args.spawn
                    else ""
                )
            )
    ratios = [a / b for a, b in zip(walls[1], walls[2], strict=True)]
    print(
        f"speed-up of 2 workers over 1, pair by pair: {', '.join(f'{r:.2f}' for r in ratios)}"
        f" (median {statistics.median(ratios):.2f}, range {min(ratios):.2f}–{max(ratios):.2f})"
    )
    print(
        f"start-up: 1 worker {statistics.median(starts[1]):.1f} s, "
        f"2 workers {statistics.median(starts[2]):.1f} s (median; "
        f"{'spawned' if args.spawn else 'forked from the fork server'})"
    )


if __name__ == "__main__":
    main()
