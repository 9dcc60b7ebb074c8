"""Wheel zero crossings on the real sky: friction at zero speed and the momentum bias (issue 24).

Run:  python bench/wheel_zero_crossings.py [--days 30] [--epoch 2027-09-01T00:00:00]
      [--only N ...]

geo-comsat-gyro (its wheel model, ``wheels.spec``), LQG, RW physics wheels, real sky
from ``--epoch``, steady window from 1 h; one row per wheel configuration:

1. the plain Coulomb + viscous law (``wheels.stiction = false``: the law before
   issue 24, friction the drive's feed-forward cancels, invisible at zero);
2. the twin's law (the default: breakaway + Stribeck + Coulomb + viscous, stuck
   at rest until the motor beats the breakaway torque);
3. the same with the pitch wheel biased (three orthogonal wheels: only pitch can be)
   by 0.45 of the wheels' momentum limit h_max (above the pitch momentum's daily swing);
4. four wheels in a pyramid, no bias (the scenario's own wheels);
5. four wheels with a null-space bias of 0.48 h_max (each wheel 0.24 h_max off zero)
   and the unloading window at 0.2 of the limit, stop at 0.05, so that a window opens
   before a wheel's swing reaches its bias;
6. row 4 with ideal wheels (torque sources, no friction): the unloading alone.

Rows 1-3 fly the scenario's wheel model on three orthogonal axes.

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

# biases as shares of the wheels' momentum limit. The real sky swings the pitch momentum
# by up to 2.9 N·m·s a day (bench/momentum_sky.py), 0.4 of an NRWA-T6's 7.1 N·m·s: a
# pitch bias of 0.2 or 0.4 leaves the pitch wheel crossing zero (30 days from 1 September:
# 60 and 54 logged crossings), 0.45 keeps it off (≥ 103 rpm). The null bias is the share
# that 24 N·m·s was of the 50 N·m·s wheels flown before.
PITCH_BIAS = 0.45
NULL_BIAS = 0.48
ORTHO = {"wheels.axes": "orthogonal"}
CASES = (
    ("3 orthogonal, Coulomb + viscous (before)", {**ORTHO, "wheels.stiction": False}),
    ("3 orthogonal, twin's friction (default)", ORTHO),
    (f"3 orthogonal, pitch bias {PITCH_BIAS:g} h_max", {**ORTHO, "momentum.bias": PITCH_BIAS}),
    ("4 pyramid, no bias", {"wheels.axes": "pyramid"}),
    (
        f"4 pyramid, null bias {NULL_BIAS:g} h_max, unload 0.2/0.05",
        {
            "wheels.axes": "pyramid",
            "momentum.bias": NULL_BIAS,
            "momentum.unload_start_fraction": 0.2,
            "momentum.unload_stop_fraction": 0.05,
        },
    ),
    ("4 pyramid, ideal wheels (no friction)", {"wheels.axes": "pyramid", "wheels.model": "ideal"}),
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
    parser.add_argument("--only", type=int, nargs="*", help="case numbers (1-6) to run")
    args = parser.parse_args()
    wheels = SCENARIOS["geo-comsat-gyro"].wheels
    print(
        f"geo-comsat-gyro ({wheels.spec}, h_max {wheels.max_momentum:.2f} N·m·s), LQG, physics "
        f"wheels (row 6: ideal), real sky from {args.epoch}, {args.days:g} days"
    )
    print(
        f"{'case':<48} {'crossings':>9} {'logged':>14} {'min |rpm|':>9} "
        f"{'steady max °':>12} {'windows':>7} {'impulse':>8} {'wall s':>6}"
    )
    for i, (name, change) in enumerate(CASES, 1):
        if args.only and i not in args.only:
            continue
        base = SCENARIOS["geo-comsat-gyro"]
        if "momentum.bias" in change:  # a share of the limit: N·m·s
            change = {**change, "momentum.bias": change["momentum.bias"] * base.wheels.max_momentum}
        sc = base.with_(**{"sky.epoch": args.epoch, "wheels.model": "physics", **change})
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
