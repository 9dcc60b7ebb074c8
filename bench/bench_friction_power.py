"""How many σ friction × F moves the current balance in 300 s, on every test signal.

Run:  python bench/bench_friction_power.py --model model.json --cases cases.txt --rec DIR

A measurement for issue 23's "friction × 1.5 within 300 s on any signal", made
before building a detector: every usable sample (not only constant-speed ones)
whose acceleration is steady (|Δα| < ``--jerk`` rpm/s over the last two
intervals: the 2 Hz current snapshot and the interval's mean acceleration agree
only then) at |ω| ≥ ``--min-rpm`` gives the current balance's residual r (the
reference's current model's); r is regressed on the reference's friction current
at the sample's speed, its inertial current and 1 (r ≈ (F − 1)·i_f + (1/F_k − 1)
·i_α + offset). Block means of ``--block`` consecutive samples carry the
neighbours' correlation; the coefficient's σ comes from the blocks' scatter.

z = (F̂_window − F̂_baseline)/√(σ_w² + σ_b²): the window the 300 s after the
onset against the record's samples before it (a fault case), or every 300 s
window against the samples older than it (healthy records, each 30 s from
600 s on): the healthy excursions are the false-alarm side.

Cases file: one line per record, ``name unit seed signal duration faults``
(faults ``kind=value@onset,...`` or ``-``); records ``DIR/name.mcap``.
A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np

from rwlab.diagnose import HealthyReference
from rwlab.diagnose.diagnoser import Diagnoser
from rwlab.diagnose.diagnosis import RECORD_OUTPUTS, record_columns
from rwlab.errors import RwlabWarning
from rwlab.testbed import load_record
from rwlab.wheel import IdentifiedWheel

WINDOW_S = 300.0


def samples(path: Path, wheel, ref, jerk: float, min_rpm: float):
    """(t, residual A, friction A, inertial A) of the qualifying samples of a record."""
    data = load_record(path, wheel.Ts, outputs=RECORD_OUTPUTS, max_gap=np.inf)
    t, held, speed, current, age, _lost = record_columns(data, wheel)
    d = Diagnoser(wheel, ref, calibration=False)
    rows = []
    for k in range(data.N):
        rows.append(d.residuals.update(float(held[k]), speed[k], current[k]))
    res = np.array([r["current"] for r in rows])
    acc = np.array([r["accel_rpm_s"] for r in rows])
    c = np.asarray(ref.current_model)
    sign = np.sign(speed)
    stale = np.asarray(age) >= wheel.Ts
    usable = ~stale
    for lag in (1, 2, 3):  # this sample and the three before it fresh
        usable[lag:] &= ~stale[:-lag]
        usable[:lag] = False
    steady = np.zeros_like(usable)
    steady[2:] = (np.abs(np.diff(acc)[1:]) < jerk) & (np.abs(np.diff(acc)[:-1]) < jerk)
    same = np.r_[False, sign[1:] == sign[:-1]]
    ok = usable & steady & same & (np.abs(speed) >= min_rpm) & np.isfinite(res)
    fric = c[1] * speed + c[2] * sign
    return t[ok], res[ok], fric[ok], c[0] * acc[ok]


def coefficient(rows: tuple, block: int) -> tuple[float, float, int]:
    """F̂ − 1 and its σ from block means; (nan, inf, n) when too few blocks."""
    t, r, f, a = rows
    nb = len(t) // block
    if nb < 8:
        return np.nan, np.inf, nb
    m = lambda x: x[: nb * block].reshape(nb, block).mean(1)  # noqa: E731
    X = np.stack([m(f), m(a), np.ones(nb)], 1)
    y = m(r)
    b, *_ = np.linalg.lstsq(X, y, rcond=None)
    e = y - X @ b
    cov = e @ e / (nb - 3) * np.linalg.pinv(X.T @ X)
    return float(b[0]), float(np.sqrt(cov[0, 0])), nb


def _cut(rows, lo: float, hi: float):
    m = (rows[0] >= lo) & (rows[0] < hi)
    return tuple(x[m] for x in rows)


def z_between(rows, base: tuple, win: tuple, block: int):
    b0, s0, _ = coefficient(_cut(rows, *base), block)
    b1, s1, n = coefficient(_cut(rows, *win), block)
    return (b1 - b0) / np.hypot(s0, s1), b0, b1, n


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", type=Path, required=True)
    p.add_argument("--cases", type=Path, required=True)
    p.add_argument("--rec", type=Path, required=True)
    p.add_argument("--jerk", type=float, default=20.0, help="steady acceleration, rpm/s")
    p.add_argument("--min-rpm", type=float, default=300.0)
    p.add_argument("--block", type=int, default=5)
    p.add_argument("--only", default="", help="comma-separated kinds to judge (default all)")
    args = p.parse_args()
    warnings.simplefilter("ignore", RwlabWarning)
    wheel = IdentifiedWheel.from_json(args.model)
    ref = HealthyReference.from_model_file(args.model)
    healthy_z: list[float] = []
    print(f"jerk < {args.jerk} rpm/s, |ω| ≥ {args.min_rpm} rpm, block {args.block}")
    for line in args.cases.read_text().splitlines():
        if not line.strip() or line.startswith(("#", "M")):
            continue
        name, _, _, signal, _, faults = line.split()[:6]
        if args.only and not any(k in faults for k in args.only.split(",")) and faults != "-":
            continue
        path = args.rec / f"{name}.mcap"
        if not path.exists():
            continue
        rows = samples(path, wheel, ref, args.jerk, args.min_rpm)
        end = float(rows[0][-1]) if len(rows[0]) else 0.0
        if faults == "-":
            zs = [
                z_between(rows, (0, t - WINDOW_S), (t - WINDOW_S, t), args.block)[0]
                for t in np.arange(600.0, end + 1, 30.0)
            ]
            zs = [z for z in zs if np.isfinite(z)]
            healthy_z += zs
            top = max(zs, key=abs) if zs else np.nan
            print(f"{name:5s} {signal:9s} healthy: {len(zs)} windows, largest |z| {top:+.1f}")
            continue
        onset = min(float(f.split("@")[1]) for f in faults.split(","))
        if onset <= 0:
            print(f"{name:5s} {signal:9s} {faults}: at power-up (no own baseline)")
            continue
        z, b0, b1, n = z_between(rows, (0, onset), (onset, onset + WINDOW_S), args.block)
        print(
            f"{name:5s} {signal:9s} {faults[:40]:40s} F-1 before {b0:+.2f} after {b1:+.2f} "
            f"({n} blocks) z {z:+.1f}"
        )
    if healthy_z:
        hz = np.abs(healthy_z)
        print(
            f"healthy: {len(hz)} windows, |z| 99 % {np.percentile(hz, 99):.1f}, max {hz.max():.1f}"
        )


if __name__ == "__main__":
    main()
