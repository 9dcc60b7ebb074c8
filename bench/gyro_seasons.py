"""The README's gyro table: geo-comsat-gyro (and paper B's suite) through the eclipse seasons.

Run:  nice -n 10 python bench/gyro_seasons.py [--quick]

Each row is one ``rwlab attitude simulate --controller lqg --steady-after 3600`` run
(the same as the command printed beside it), flown one at a time: 6 days from
2027-09-15 (the autumn eclipse season) for seeds 0–2; paper B's sun + earth suite
with each filter option on the same days; the star-tracker variant; 30 days from
1 March and 1 September (seed 3). ``--quick``: only the first row. Prints a table.
"""

from __future__ import annotations

import argparse
import time

from rwlab.attitude.control import fly
from rwlab.attitude.scenario import SCENARIOS

DAY = 86400.0
AUTUMN = "2027-09-15T00:00:00Z"
CASES = [
    ("geo-comsat-gyro", {}, AUTUMN, 6, 0),
    ("geo-comsat-gyro", {}, AUTUMN, 6, 1),
    ("geo-comsat-gyro", {}, AUTUMN, 6, 2),
    *[
        ("geo-comsat", {"filter.disturbance_state": o}, AUTUMN, 6, 0)
        for o in ("torque+srp", "srp", "torque", "none")
    ],
    ("geo-comsat-star", {}, AUTUMN, 6, 0),
    ("geo-comsat-gyro", {}, "2027-03-01T00:00:00Z", 30, 3),
    ("geo-comsat-gyro", {}, "2027-09-01T00:00:00Z", 30, 3),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the first row only")
    args = parser.parse_args()
    print(
        f"{'scenario':<18} {'filter':<11} {'from':<11} {'days':>4} {'seed':>4} "
        f"{'steady max [°]':>14} {'NEES/n':>10} {'in ±3σ':>7} {'in shadow [°]':>13} "
        f"{'shadow [h]':>10} {'wall [s]':>8}"
    )
    for name, changes, epoch, days, seed in CASES[:1] if args.quick else CASES:
        sc = SCENARIOS[name].with_(**changes, **{"sky.epoch": epoch})
        t0 = time.perf_counter()
        _, m = fly(sc, "lqg", duration=days * DAY, seed=seed, log_every=100, steady_after=3600)
        wall = time.perf_counter() - t0
        kind = "gyro" if sc.sensors.gyro else sc.filter.disturbance_state
        nees = f"{m['nees_mean']:.3g}/{m['nees_states']}" if m["nees_mean"] else "—"
        inside = m["inside_3sigma_fraction"]
        print(
            f"{name:<18} {kind:<11} {epoch[:10]:<11} {days:>4} {seed:>4} "
            f"{m['steady_max_error_deg']:>14.4f} {nees:>10} {inside:>7.3f} "
            f"{m['steady_max_error_in_eclipse_deg'] or 0:>13.4f} "
            f"{m['eclipse_s'] / 3600:>10.2f} {wall:>8.0f}"
        )


if __name__ == "__main__":
    main()
