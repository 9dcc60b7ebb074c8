"""Monte Carlo campaign throughput: runs per second in one process and on 1 and 2 Dask workers.

Run:  python bench/bench_campaign.py [--runs 96] [--duration 600]

Each run: geo-smallsat with rwlab's default dispersions, the LQG loop (MEKF),
``--duration`` s at dt = 0.1 s, as ``rwlab attitude montecarlo`` flies it.
"in process" flies the runs one after the other without Dask (the floor of the
per-run cost); the Dask rows time a whole campaign on a local cluster after a
warm-up campaign that makes every worker load the compiled loop, and report
the cluster's start-up (processes + imports + loading numba's cache) apart.
A benchmark, not a test: numbers depend on the machine's load.
"""

from __future__ import annotations

import argparse
import time

from threadpoolctl import threadpool_limits

from rwlab.attitude.scenario import load_scenario
from rwlab.campaign.dispersions import load_dispersions
from rwlab.campaign.engine import dask_client
from rwlab.campaign.montecarlo import Campaign, fly_run, run_campaign, run_seeds


def in_process(campaign: Campaign) -> float:
    seeds = run_seeds(campaign.seed, campaign.runs)
    fly_run(campaign, seeds[0])  # compile / load the cache outside the timing
    t0 = time.perf_counter()
    for s in seeds:
        fly_run(campaign, s)
    return time.perf_counter() - t0


def on_dask(campaign: Campaign, workers: int) -> tuple[float, float]:
    t0 = time.perf_counter()
    with dask_client(workers) as client:
        warm = Campaign(campaign.scenario, campaign.dispersions, 10.0, campaign.controller, 1, 4)
        run_campaign(warm, client)
        startup = time.perf_counter() - t0
        t1 = time.perf_counter()
        rows = run_campaign(campaign, client)
        elapsed = time.perf_counter() - t1
    assert len(rows) == campaign.runs
    return startup, elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=96)
    parser.add_argument("--duration", type=float, default=600.0)
    args = parser.parse_args()
    c = Campaign(
        load_scenario("geo-smallsat"), load_dispersions(), args.duration, "lqg", 5, args.runs
    )
    print(f"{args.runs} runs, geo-smallsat, LQG, {args.duration:g} s each (dt 0.1 s)")
    print(f"{'engine':<22} {'start-up [s]':>12} {'campaign [s]':>13} {'runs/s':>8}")
    with threadpool_limits(1, user_api="blas"):
        serial = in_process(c)
    print(f"{'in process (no Dask)':<22} {'':>12} {serial:13.2f} {args.runs / serial:8.1f}")
    for workers in (1, 2):
        startup, elapsed = on_dask(c, workers)
        label = f"Dask, {workers} worker{'s' if workers > 1 else ''}"
        print(f"{label:<22} {startup:12.1f} {elapsed:13.2f} {args.runs / elapsed:8.1f}")


if __name__ == "__main__":
    main()
