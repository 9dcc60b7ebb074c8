"""Why a speed-reading bias on a chirp is missed: two signatures that were tried, measured.

Run:  python bench/bench_fdi_chirp_bias.py --wheel W --cache DIR --model model.json \
          --calibrate tune_h0 ... --judge w7_f9407 w7_f9409 ... [--onset 600]

A chirp's fast end never holds a speed, so the GLR's bias detector (constant-speed
samples only) reads no sample there. Two ways to read a bias during motion, per record
(``bench_fdi.py``'s cache and names), before and after ``--onset`` (s):

- ``regression``: the speed residual over a 60/150/300-s window of moving samples,
  weighted by the noise model (1/σ²κ), least squares on [1, ω_model, sign ω_model,
  α_model]: the intercept b and its log-LR b²/(2·var b), the largest over windows ending
  every 5 s (rank-deficient windows, no zero crossing, are skipped);
- ``rest``: the firmware's reading where no Hall edge came (the model's speed within
  the band where the calibration records read exactly 0, their 95th percentile): a
  bias makes it the same non-zero value at each pass; the binomial GLR of the most
  repeated non-zero value's share of the fresh readings there against the healthy
  records' repeat probability, over 60/150/300-s windows.

Each row prints the largest log-LR and its b (rpm). A benchmark, not a test.
"""

from __future__ import annotations

import math
import sys
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_fdi import record_arguments, record_features
from rwlab.diagnose.features import STEADY_SHARE, WheelScales
from rwlab.diagnose.noise import NoiseModel
from rwlab.wheel import IdentifiedWheel

WINDOWS_S = (60.0, 150.0, 300.0)
EVERY_S = 5.0


def windows(f):
    """(start, end) sample index pairs: every EVERY_S, each of WINDOWS_S back."""
    Ts = f.scales.Ts
    for k in range(round(EVERY_S / Ts), f.N + 1, round(EVERY_S / Ts)):
        for w in WINDOWS_S:
            yield max(0, k - round(w / Ts)), k


def regression(f, noise: NoiseModel) -> list[tuple[float, float, float]]:
    """(end time s, log-LR, intercept rpm) per window of the nuisance regression."""
    w = np.where(~f.steady(STEADY_SHARE) & (f.speed_rpm != 0), noise.weights(f)["speed"], 0.0)
    X = np.column_stack([np.ones(f.N), f.model_rpm, np.sign(f.model_rpm), f.model_accel_rpm_s])
    r = np.nan_to_num(f.speed_residual_rpm)
    out = []
    for a, k in windows(f):
        Xw = X[a:k] * w[a:k, None]
        A = Xw.T @ X[a:k]
        if np.linalg.matrix_rank(A, tol=1e-9 * max(np.abs(A).max(), 1e-300)) < 4:
            continue
        cov = np.linalg.inv(A)
        b = float((cov @ (Xw.T @ r[a:k]))[0])
        out.append((float(f.t_s[k - 1]), 0.5 * b * b / cov[0, 0], b))
    return out


def rest_band(records) -> tuple[float, float]:
    """The band (rpm) where healthy records read exactly 0 while the model moves, and the
    probability that a fresh non-zero reading there repeats an earlier one (Laplace)."""
    zero = np.concatenate(
        [np.abs(f.model_rpm[(f.speed_rpm == 0) & f.usable & (f.model_rpm != 0)]) for f in records]
    )
    band = float(np.quantile(zero, 0.95))
    repeats = total = 0
    for f in records:
        z = rest_samples(f, band) & (f.speed_rpm != 0)
        repeats += sum(c - 1 for c in Counter(f.speed_rpm[z]).values())
        total += int(z.sum())
    return band, (repeats + 1) / (total + 2)


def rest_samples(f, band: float) -> np.ndarray:
    return f.usable & (np.abs(f.model_rpm) <= band) & ~f.repeated


def rest(f, band: float, p: float) -> list[tuple[float, float, float]]:
    """(end time s, log-LR, repeated value rpm) per window of the rest-reading GLR."""
    z = rest_samples(f, band)
    out = []
    for a, k in windows(f):
        v = f.speed_rpm[a:k][z[a:k]]
        nonzero = v[v != 0]
        if not nonzero.size:
            continue
        values, counts = np.unique(nonzero, return_counts=True)
        i = int(counts.argmax())
        x, n = int(counts[i]), v.size
        q = x / n
        if q <= p:
            continue
        llr = x * math.log(q / p) + ((n - x) * math.log((1 - q) / (1 - p)) if q < 1 else 0.0)
        out.append((float(f.t_s[k - 1]), llr, float(values[i])))
    return out


def largest(rows, before: bool, onset: float) -> str:
    rows = [r for r in rows if (r[0] < onset) == before]
    if not rows:
        return f"{'-':>16s}"
    _, llr, b = max(rows, key=lambda r: r[1])
    return f"{llr:8.1f} {b:7.1f}"


def main() -> None:
    p = record_arguments(__doc__.splitlines()[0])
    p.add_argument("--onset", type=float, default=600.0)
    args = p.parse_args()
    scales = WheelScales.from_model_file(args.model)
    wheel = IdentifiedWheel.from_json(args.model)

    def features(name: str):
        return record_features(args.cache / f"{name}.mcap", wheel, scales)

    healthy = [features(n) for n in args.calibrate]
    noise = NoiseModel.measure(healthy)
    band, p_repeat = rest_band(healthy)
    print(f"{args.wheel}: rest band {band:.1f} rpm, repeat probability {p_repeat:.4f}")
    print(f"{'record':12s} {'regression before':>17s} {'after':>16s} {'rest before':>17s} after")
    for name in args.calibrate + args.judge:
        f = features(name)
        reg, rst = regression(f, noise), rest(f, band, p_repeat)
        cells = [largest(rows, before, args.onset) for rows in (reg, rst) for before in (1, 0)]
        print(f"{name:12s} " + "  ".join(cells))


if __name__ == "__main__":
    main()
