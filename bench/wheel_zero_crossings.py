"""Wheel zero crossings on the real sky: friction at zero speed and the momentum bias (issue 24).

Run:  python bench/wheel_zero_crossings.py [--days 30] [--epoch 2027-09-01T00:00:00]
      [--only N ...]

geo-comsat-gyro, LQG, RW physics wheels, real sky from ``--epoch``, steady window
from 1 h; one row per wheel configuration:

1. the plain Coulomb + viscous law (``wheels.stiction = false``: the law before
   issue 24, friction the drive's feed-forward cancels, invisible at zero);
2. the twin's law (the default: breakaway + Stribeck + Coulomb + viscous, stuck
   at rest until the motor beats the breakaway torque);
3. the same with the pitch wheel biased (three orthogonal wheels: only pitch can be);
4. four wheels in a pyramid, no bias;
5. four wheels with a null-space bias and the unloading sized on the real sky's
   build-up (``bench/momentum_sky.py``: window at 0.2 of the limit, stop at 0.05).

Columns: ``wheel_zero_crossings`` (every change of a wheel's spin direction, every
step: a wheel dithering through zero counts each time), the crossings seen in
the one-minute log, the slowest |speed| any wheel passed, the steady maximum
error, unloading windows and thruster impulse.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from rwlab.attitude.control import fly
from rwlab.attitude.scenario import SCENARIOS

CASES = (
    ("3 orthogonal, Coulomb + viscous (before)", {"wheels.stiction": False}),
    ("3 orthogonal, twin's friction (default)", {}),
    ("3 orthogonal, pitch bias 10 N·m·s", {"momentum.bias": 10.0}),
    ("4 pyramid, no bias", {"wheels.axes": "pyramid"}),
    (
        "4 pyramid, null bias 24 N·m·s, unload 0.2/0.05",
        {
            "wheels.axes": "pyramid",
            "momentum.bias": 24.0,
            "momentum.unload_start_fraction": 0.2,
            "momentum.unload_stop_fraction": 0.05,
        },
    ),
)


def logged_crossings(rpm: np.ndarray) -> list[int]:
    """Sign changes of each wheel's logged speed (zeros skipped)."""
    out = []
    for s in np.sign(rpm).T:
        s = s[s != 0]
        out.append(int(np.sum(s[1:] != s[:-1])))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--days", type=float, default=30.0)
    parser.add_argument("--epoch", default="2027-09-01T00:00:00")
    parser.add_argument("--only", type=int, nargs="*", help="case numbers (1-5) to run")
    args = parser.parse_args()
    print(f"geo-comsat-gyro, LQG, physics wheels, real sky from {args.epoch}, {args.days:g} days")
    print(
        f"{'case':<48} {'crossings':>9} {'logged':>14} {'min |rpm|':>9} "
        f"{'steady max °':>12} {'windows':>7} {'impulse':>8} {'wall s':>6}"
    )
    for i, (name, change) in enumerate(CASES, 1):
        if args.only and i not in args.only:
            continue
        sc = SCENARIOS["geo-comsat-gyro"].with_(
            **change, **{"sky.epoch": args.epoch, "wheels.model": "physics"}
        )
        t0 = time.perf_counter()
        r, m = fly(sc, "lqg", duration=args.days * 86400, log_every=600, steady_after=3600)
        per = logged_crossings(r.wheel_speed_rpm)
        slowest = float(np.min(np.abs(r.wheel_speed_rpm[r.t >= 3600])))
        print(
            f"{name:<48} {m['wheel_zero_crossings']:>9} {per!s:>14} {slowest:9.0f} "
            f"{m['steady_max_error_deg']:12.4f} {m['desaturation_count']:>7} "
            f"{m['thruster_impulse_Nms']:8.1f} {time.perf_counter() - t0:6.0f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
