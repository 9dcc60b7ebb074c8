"""Measure the detectors' false-alarm rates over their thresholds: the package's thresholds.json.

Run:  python bench/calibrate_thresholds.py [--cache DIR] [--out FILE] [--offset-sigma]
      [--model-units UNIT ...]

The models are bench_diagnose's (``rwlab identify`` with the defaults on a unit's
fault-free 20-minute stepped PRBS), one per ``--model-units`` unit (default:
:data:`MODEL_UNITS`, 16 units drawn at random from 137–199, which no other set
uses), each run over every healthy record, so the rates are those of a model of a
unit drawn as a user's is. A user's rate depends on where the model's unit sits in
the spread between units; the five units used before (0 and four chosen at the
friction tolerance's edges: 7, 89, 94, 100) over-weighted the edges, and on eval3
the friction test then alarmed 0 times an hour for 1 asked, 3.9 for 10. The healthy
records are the tune set's (``bench_diagnose.records('tune')``: units 1–6, 101–136
and 2000–2077, 20 minutes each, PRBS, chirp, multisine and steps in turn), never
the eval sets' units, on which ``bench_diagnose.py --set eval4`` judges the
thresholds. The 2000s came when the motor test's false alarms were traced to the
few units at the edge of the spread (I/k_t ≥ 1.045 × nominal: 5 of the 42 units
before, 8 % of the population): a rate made of a tail needs many units. Each detector
runs restarted after every alarm over every record; each CUSUM with each model's own
reference value k, over shares of its tolerance between units (``calibration.SHARES``:
what carries to a model of another unit, whatever its k); the counts per threshold
go to ``--out`` (default: src/rwlab/diagnose/thresholds.json). Simulated clock:
~10 s per record to make (cached in ``--cache``); about 10 min to count with 16 models
(records cached, two cores).
``--offset-sigma`` also prints the σ of the offset test's window intercepts on
these records (``OFFSET_SIGMA_RPM`` in src/rwlab/diagnose/detector_constants.toml).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from bench_diagnose import _model, healthy_tune, records
from rwlab.diagnose import HealthyReference
from rwlab.diagnose.diagnoser import Diagnoser
from rwlab.diagnose.diagnosis import measure_calibration, record_columns
from rwlab.diagnose.motion import OFFSET_SIGMA_RPM
from rwlab.wheel import IdentifiedWheel

OUT = Path(__file__).resolve().parents[1] / "src" / "rwlab" / "diagnose" / "thresholds.json"
# random.Random(2026).sample(range(137, 200), 16), sorted
MODEL_UNITS = (
    "143",
    "144",
    "151",
    "157",
    "163",
    "169",
    "172",
    "173",
    "175",
    "176",
    "178",
    "183",
    "187",
    "189",
    "192",
    "197",
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, help="folder keeping the records (default: temp)")
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--offset-sigma", action="store_true")
    parser.add_argument(
        "--model-units",
        nargs="+",
        default=list(MODEL_UNITS),
        help="units whose identified models the rates are counted with (never the records')",
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cache = args.cache or Path(tmp)
        cache.mkdir(parents=True, exist_ok=True)
        models = []
        for unit in args.model_units:
            path = _model(cache, Path(tmp) / f"u{unit}", unit)
            models.append((IdentifiedWheel.from_json(path), HealthyReference.from_model_file(path)))
        wheel, ref = models[0]
        specs = {k: v for k, v in records("tune").items() if not v[5]}
        if {str(v[0]) for v in specs.values()} & set(args.model_units):
            parser.error("a model unit is one of the healthy records' units")
        data = healthy_tune(cache, wheel.Ts)
        units = sorted(spec[0] for spec in specs.values())
        origin = (
            f"python bench/calibrate_thresholds.py: {len(data)} healthy 20-minute records of "
            f"twin units {', '.join(map(str, units))} (bench_diagnose.records('tune'); PRBS, "
            "chirp, multisine, steps in turn), each diagnosed with the models identified with "
            f"the defaults on units {', '.join(args.model_units)} (hours: records x models)"
        )
        cal = measure_calibration(data, wheel, ref, origin=origin, more_models=tuple(models[1:]))
        cal.save(args.out)
        if args.offset_sigma:
            _offset_sigma(data, wheel, ref)
    print(
        f"{cal.hours:.2f} h of healthy records x models, {len(data)} records, "
        f"{len(args.model_units)} models -> {args.out}"
    )
    print(f"{'curve':<16} {'k':>6} {'decisions/h':>12} {'max alarms/h':>13}")
    for name, c in cal.curves.items():
        if cal.max_per_hour(name) > 0 or c.kind == "count":
            per_hour = c.decisions / cal.hours
            print(f"{name:<16} {c.k:>6.3g} {per_hour:>12.1f} {cal.max_per_hour(name):>13.3g}")


def _offset_sigma(data, wheel, ref) -> None:
    values = []
    for d in data:
        diag = Diagnoser(wheel, ref, calibration=False, trace=True)
        for row in zip(*record_columns(d, wheel), strict=True):
            diag.update(*(float(x) for x in row))
        values += [z * OFFSET_SIGMA_RPM for z in diag.traces()["offset"]]
    x = np.array(values)
    print(
        f"offset: {x.size} windows, mean {x.mean():.2f} rpm, σ {x.std(ddof=1):.2f} rpm "
        f"(OFFSET_SIGMA_RPM = {OFFSET_SIGMA_RPM})"
    )


if __name__ == "__main__":
    main()
