"""Does paper B's re-linearisation pay? Steady pointing and wall time with and without it.

For each scenario: LQG (MEKF, disturbances unknown to the filter) designed once at the
reference, and re-designed about the current estimate every 1 s and every 10 s (lqrd
each time), on the same seed. Prints a table; a benchmark, not a test.

    python bench/bench_relinearize.py [--duration 1800]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

from rwlab.attitude.control import LQRController, metrics
from rwlab.attitude.scenario import SCENARIOS
from rwlab.attitude.sim import simulate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--duration", type=float, default=1800.0)
    args = parser.parse_args()
    threadpool_limits(1, user_api="blas")  # as the CLI does
    print(
        f"{'scenario':<14} {'re-design':>10} {'steady max [°]':>15} {'steady RMS [°]':>15} "
        f"{'max |ΔK|/|K|':>13} {'wall [s]':>9}"
    )
    for name in ("geo-smallsat", "geo-comsat"):
        sc = SCENARIOS[name]
        K0 = LQRController(sc).K
        simulate(sc, LQRController(sc), duration=10)  # compile outside the timing
        for period in (None, 10.0, 1.0):
            ctl = LQRController(sc, update_period=period)
            change = 0.0
            gain = ctl.gain

            def tracked(*a, gain=gain, K0=K0):
                nonlocal change
                K = gain(*a)
                change = max(change, float(np.linalg.norm(K - K0) / np.linalg.norm(K0)))
                return K

            ctl.gain = tracked
            t0 = time.perf_counter()
            m = metrics(simulate(sc, ctl, duration=args.duration))
            wall = time.perf_counter() - t0
            label = "once" if period is None else f"{period:g} s"
            print(
                f"{name:<14} {label:>10} {m['steady_max_error_deg']:15.4g} "
                f"{m['steady_rms_error_deg']:15.4g} {change:13.2e} {wall:9.2f}"
            )


if __name__ == "__main__":
    main()
