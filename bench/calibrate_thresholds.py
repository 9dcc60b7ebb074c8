"""Measure the detectors' false-alarm rates over their thresholds: the package's thresholds.json.

Run:  python bench/calibrate_thresholds.py [--cache DIR] [--out FILE]

The model is bench_diagnose's (``rwlab identify`` with the defaults on unit 0's
fault-free 20-minute stepped PRBS); the healthy records are the tune set's
(``bench_diagnose.records('tune')``: units 1–6 and 101–136, 20 minutes each,
PRBS, chirp, multisine and steps in turn), never the eval sets' units (21–44, 201–224),
on which ``bench_diagnose.py --set eval`` judges the thresholds. Each detector
runs restarted after every alarm over every record; the counts per threshold
go to ``--out`` (default: src/rwlab/diagnose/thresholds.json). Simulated clock:
~10 s per record to make (cached in ``--cache``), ~1 s to count.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from bench_diagnose import _model, _record, records
from rwlab.diagnose import HealthyReference
from rwlab.diagnose.diagnoser import measure_calibration
from rwlab.testbed import load_record
from rwlab.wheel import IdentifiedWheel

OUT = Path(__file__).resolve().parents[1] / "src" / "rwlab" / "diagnose" / "thresholds.json"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, help="folder keeping the records (default: temp)")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cache = args.cache or Path(tmp)
        cache.mkdir(parents=True, exist_ok=True)
        model = _model(cache, Path(tmp))
        wheel = IdentifiedWheel.from_json(model)
        ref = HealthyReference.from_model_file(model)
        specs = {k: v for k, v in records("tune").items() if not v[5]}
        data = [
            load_record(
                _record(cache, name, spec),
                wheel.Ts,
                outputs=("speed", "current", "age", "lost"),
                max_gap=np.inf,
            )
            for name, spec in specs.items()
        ]
        units = sorted(spec[0] for spec in specs.values())
        origin = (
            f"python bench/calibrate_thresholds.py: {len(data)} healthy 20-minute records of "
            f"twin units {', '.join(map(str, units))} (bench_diagnose.records('tune'); PRBS, "
            "chirp, multisine, steps in turn), model identified with the defaults on unit 0"
        )
        cal = measure_calibration(data, wheel, ref, origin=origin)
        cal.save(args.out)
    print(f"{cal.hours:.2f} h of healthy records, {len(data)} records -> {args.out}")
    print(f"{'detector':<16} {'k':>6} {'decisions/h':>12} {'max alarms/h':>13}")
    for name, c in cal.curves.items():
        per_hour = c.decisions / cal.hours
        print(f"{name:<16} {c.k:>6.3g} {per_hour:>12.1f} {cal.max_per_hour(name):>13.3g}")


if __name__ == "__main__":
    main()
