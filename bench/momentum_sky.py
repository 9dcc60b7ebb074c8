"""Momentum the real sky builds up, and unloading sized on it (issue 24).

Run:  python bench/momentum_sky.py [--scenario geo-comsat-gyro] [--epoch 2027-09-01T00:00:00]
      [--days 3] [--interval-days 3]

Flies the scenario's LQG loop on the real sky (ephemerides from ``--epoch``) with
momentum unloading off and measures what the disturbances leave in the wheels:
the body momentum h = G h_w, per day, split into pitch (the orbit normal: fixed in
inertial space, it grows secularly) and roll/yaw (in the orbit plane: an inertially
fixed accumulation turns once a day in body axes, so the roll and yaw wheels swing
through zero with a daily amplitude that grows by the accumulation rate). Prints
the rates (N·m·s/day, least squares over the days' values) and the unloading those
rates ask for: the window start that the wheels reach after ``--interval-days`` of
accumulation, and for a momentum-biased 4-wheel pyramid the bias that keeps every
wheel off zero until that window opens; when the scenario's window opens, and the
longest interval a biased pyramid allows. The wheels must not saturate during the run
(it says when the fullest one did): geo-comsat-gyro's NRWA-T6 pyramid fills on the
fourth day from 1 September.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from rwlab.attitude.control import fly
from rwlab.attitude.scenario import SCENARIOS


def accumulation(name: str, epoch: str, days: float) -> tuple[float, float, np.ndarray, float]:
    """(pitch rate, roll/yaw rate) N·m·s/day, the daily peaks (days, 2) of |h_y|, |h_xz|
    and the fullest wheel's momentum, a share of its limit."""
    sc = SCENARIOS[name].with_(**{"sky.epoch": epoch, "momentum.unloading": False})
    r, m = fly(sc, "lqg", duration=days * 86400, log_every=600)
    hw = r.wheel_speed_rpm * math.pi / 30 * sc.wheels.inertia
    h = hw @ sc.wheel_matrix.T  # body momentum (K, 3)
    day = np.floor(r.t / 86400).astype(int)
    n = int(day.max()) + 1 if r.t[-1] % 86400 else int(day.max())
    peaks = np.array(
        [
            [np.max(np.abs(h[day == d, 1])), np.max(np.hypot(h[day == d, 0], h[day == d, 2]))]
            for d in range(n)
        ]
    )
    x = np.arange(n) + 1.0  # a day's peak is reached by its end
    rates = [float(np.polyfit(x, peaks[:, i], 1)[0]) for i in range(2)]
    return rates[0], rates[1], peaks, float(m["wheel_momentum_peak_fraction"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="geo-comsat-gyro")
    parser.add_argument("--epoch", default="2027-09-01T00:00:00")
    parser.add_argument("--days", type=float, default=3.0)
    parser.add_argument("--interval-days", type=float, default=3.0)
    args = parser.parse_args()
    pitch, plane, peaks, fullest = accumulation(args.scenario, args.epoch, args.days)
    sc = SCENARIOS[args.scenario]
    print(f"{args.scenario}, real sky from {args.epoch}, {args.days:g} days, unloading off")
    print(f"{'day':>4} {'peak |h_pitch| N·m·s':>22} {'peak |h_roll/yaw| N·m·s':>25}")
    for d, (a, b) in enumerate(peaks, 1):
        print(f"{d:>4} {a:22.2f} {b:25.2f}")
    print(f"accumulation: pitch {pitch:.2f} N·m·s/day, roll/yaw {plane:.2f} N·m·s/day")
    print(f"fullest wheel: {fullest:.2f} of its limit", end="")
    print(" (saturated: the last peaks are clipped, run fewer days)" if fullest > 0.999 else "")
    rate = max(abs(pitch), abs(plane))
    h_max = sc.wheels.max_momentum
    h_window = rate * args.interval_days
    # the fullest wheel carries |h| with three orthogonal wheels; with a pyramid at most
    # ‖G⁺ h‖∞ ≤ 0.75 |h| (G Gᵀ = 4/3 I), and a null bias b offsets each wheel by |b|/2:
    # it keeps every wheel off zero while 0.75 |h| < |b|/2
    share = 0.75 if sc.n_wheels == 4 else 1.0
    start = share * h_window / h_max
    bias = 2 * 0.75 * h_window * 1.2
    print(
        f"unloading every {args.interval_days:g} days: {h_window:.1f} N·m·s of body momentum, "
        f"window start at {start:.2f} of the {h_max:.2f} N·m·s wheels "
        f"(paper B's fixed Sun: 1.4 N·m·s/day in pitch); "
        f"4-wheel null-space bias ≥ {bias:.1f} N·m·s (20 % margin), "
        f"allowed below (1 − start) × limit = {(1 - start) * h_max:.1f} N·m·s"
    )
    s = sc.momentum.unload_start_fraction
    print(
        f"the scenario's window ({s:g} of the limit) opens after "
        f"{s * h_max / share / rate:.1f} days; the longest interval with a 4-wheel null "
        f"bias is {h_max / 2.55 / rate:.2f} days (bias + window: 1.8 h + 0.75 h < limit)"
    )


if __name__ == "__main__":
    main()
