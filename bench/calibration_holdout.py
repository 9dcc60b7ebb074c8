"""Does a threshold calibration carry to a model of a unit it was not counted with?

Run:  python bench/calibration_holdout.py [--cache DIR] [--model-units UNIT ...]

Leaves each model unit out in turn: the calibration is counted with the other
models over the tune set's healthy records (``bench_diagnose.records('tune')``,
as ``calibrate_thresholds.py``), the left-out model's thresholds for 1, 10 and
100 false alarms per hour are taken from it, and its own alarms on the same
records are counted at them (measured / requested, per model). Two ways of
carrying a CUSUM's curve to a model whose reference value k differs:

- share: each model counted at its own k over shares of its tolerance between
  units; the left-out model takes its share (the package's way);
- k grid: every model's block means counted at one grid of k, interpolated at
  the left-out model's k (log-linear in k).

Prints, per detector and rate, the ratios and how many are within a factor 2.
~80 s per model with the records cached.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from bench_diagnose import _model, healthy_tune
from calibrate_thresholds import MODEL_UNITS
from rwlab.diagnose import HealthyReference
from rwlab.diagnose.calibration import (
    H_GRID,
    Curve,
    ThresholdCalibration,
    cusum_alarms_k,
    cusum_curves,
)
from rwlab.diagnose.diagnosis import model_traces
from rwlab.wheel import IdentifiedWheel

K_GRID = (0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.15, 1.3, 1.5, 1.75, 2.0, 2.3, 2.6, 3.0, 3.5, 4.0)
K_GRID += (4.6, 5.3, 6.0, 7.0, 8.0, 9.2, 10.6, 12.2, 14.0, 16.0, 18.5, 21.0, 24.0, 28.0)
DETECTORS = ("friction", "friction_change", "motor", "speed", "lag", "slew", "slew_change")
RATES = (1.0, 10.0, 100.0)


def _k_grid_setting(zs, sides, hours, k, per_hour):
    """Threshold and k from one grid of k (every model's block means pooled)."""
    counts = cusum_alarms_k(zs, K_GRID, sides)
    j = min(max(int(np.searchsorted(K_GRID, k)), 1), len(K_GRID) - 1)
    w = (k - K_GRID[j - 1]) / (K_GRID[j] - K_GRID[j - 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.exp((1 - w) * np.log(counts[j - 1]) + w * np.log(counts[j]))
    # the curve at k as if counted there: the package's threshold logic on one curve
    curve = Curve("cusum", H_GRID, tuple(int(x + 0.5) for x in np.nan_to_num(a)), k, 0)
    cal = ThresholdCalibration(0.5, hours, {"d@1": curve})
    if per_hour > cal.max_per_hour("d@1") and per_hour * hours >= 5:  # a smaller grid k
        for kk in reversed([x for x in K_GRID if x < k]):
            row = counts[K_GRID.index(kk)]
            if row[0] / hours >= per_hour or kk == K_GRID[0]:
                cal = ThresholdCalibration(
                    0.5, hours, {"d@1": Curve("cusum", H_GRID, tuple(row), kk)}
                )
                k = kk
                break
    return cal.setting("d", per_hour, 99.0, k).threshold, k


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, help="folder keeping the records (default: temp)")
    parser.add_argument("--model-units", nargs="+", default=list(MODEL_UNITS))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cache = args.cache or Path(tmp)
        cache.mkdir(parents=True, exist_ok=True)
        traces = {}
        loaded: dict[float, list] = {}  # per sample time: loaded once for every model
        for unit in args.model_units:
            path = _model(cache, Path(tmp) / f"u{unit}", unit)
            wheel = IdentifiedWheel.from_json(path)
            ref = HealthyReference.from_model_file(path)
            if wheel.Ts not in loaded:
                loaded[wheel.Ts] = healthy_tune(cache, wheel.Ts)
            data = loaded[wheel.Ts]
            traces[unit] = model_traces(data, wheel, ref)
        hours = sum(d.N * d.Ts for d in data) / 3600
    units = list(traces)
    print(f"leave one model out: {len(units)} models, {hours:.1f} h of tune records each")
    print(f"{'detector':<16} {'rate/h':>6}  {'share: measured/requested':<32} {'k grid':<32}")
    total = {"share": 0, "k grid": 0}
    cells = 0
    for d in DETECTORS:
        sides = traces[units[0]][1][d][1]
        for rate in RATES:
            ratios: dict[str, list[float]] = {"share": [], "k grid": []}
            for m in units:
                others = [u for u in units if u != m]
                k = traces[m][1][d][0]
                per_model = [(traces[u][0][d], traces[u][1][d][0]) for u in others]
                cal = ThresholdCalibration(
                    0.5, hours * len(others), cusum_curves(d, per_model, sides)
                )
                s = cal.setting(d, rate, 99.0, k)
                pooled = [z for u in others for z in traces[u][0][d]]
                h_grid, k_grid = _k_grid_setting(pooled, sides, hours * len(others), k, rate)
                for way, (h, kk) in (("share", (s.threshold, s.k)), ("k grid", (h_grid, k_grid))):
                    n = cusum_alarms_k(traces[m][0][d], (kk,), sides, (h,))[0, 0]
                    ratios[way].append(n / hours / rate)
            cells += len(units)
            line = f"{d:<16} {rate:>6g}  "
            for way in ("share", "k grid"):
                inside = sum(0.5 <= r <= 2 for r in ratios[way])
                total[way] += inside
                text = " ".join(f"{r:.2f}" for r in ratios[way]) + f" [{inside}/{len(units)}]"
                line += f"{text:<32} "
            print(line)
    print(f"within x2: share {total['share']}/{cells}, k grid {total['k grid']}/{cells}")


if __name__ == "__main__":
    main()
