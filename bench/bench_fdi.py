"""The GLR pipeline (``rwlab.diagnose.pipeline``) on twin records: detection, naming, sizes.

Run:  python bench/bench_fdi.py --cache DIR --model model.json --calibrate NAME... \
          --judge NAME... [--rate 1e-3]

Records are read from ``--cache`` by name (``bench_diagnose.py``'s names and
specs, plus the held-out ``held_*`` set below, made by ``--make``). The
calibration is measured on the ``--calibrate`` records (healthy) and every
``--judge`` record is diagnosed with it; the table prints, per record, the
injected fault, the first alarm, whether it came within 300 s of onset, whether
its name is the injected fault's, and whether the 95 % interval holds the size.
A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import bench_diagnose as b
from rwlab.diagnose.features import RECORD_OUTPUTS, WheelScales, compute_features
from rwlab.diagnose.pipeline import run
from rwlab.diagnose.wheel_calibration import DiagnosisCalibration
from rwlab.testbed import load_record
from rwlab.wheel import IdentifiedWheel

# held out: sizes between the usual grid (friction x1.7, 0.55 A, k_t x0.85), faults
# from power-up, two at once, on units and seeds no other set uses
HELD = (
    ("friction=1.7", "prbs"),
    ("friction=1.7", "chirp"),
    ("current_limit=0.55", "prbs"),
    ("current_limit=0.55", "chirp"),
    ("torque_constant=0.85", "prbs"),
    ("torque_constant=0.85", "chirp"),
    ("speed_sensor_bias=25", "prbs"),
    ("speed_sensor_bias=10", "chirp"),
    ("speed_sensor_stuck", "chirp"),
    ("telemetry_dropout=0.3", "prbs"),
    ("friction=3", "chirp"),
    ("friction=1.5+current_limit=0.45", "prbs"),
    ("torque_constant=0.8+speed_sensor_bias=20", "chirp"),
    ("current_limit=0.5", "step"),
)
HELD_POWER_UP = ("friction=1.5", "torque_constant=0.8", "current_limit=0.45")


def held(first: int = 7000, tag: str = "held") -> dict[str, tuple]:
    """name → spec of a held-out set (as bench_diagnose.records): units first+1...

    ``held`` (units 7001-7104) was judged once and then looked at; ``fresh`` (units
    7201-7304) was made after the last change and judged once.
    """
    out = {}
    for i, (fault, signal) in enumerate(HELD):
        u = first + 1 + i
        out[f"{tag}_f{u}"] = (u, 70000 + u, signal, 900, b._faults(fault, 600.0), fault, 600.0)
    for i, fault in enumerate(HELD_POWER_UP):
        u = first + 51 + i
        out[f"{tag}_p{u}"] = (u, 70000 + u, "prbs", 600, b._faults(fault, 0.0), fault, 0.0)
    for i in range(4):
        u = first + 101 + i
        out[f"{tag}_h{i}"] = (u, 71000 + u, b.SIGNALS[i % 4], 1200, (), "", None)
    return out


def holds(fault: str, size: float | None, truth: dict[str, float]) -> str:
    """'yes'/'no' for an interval holding the injected size; '-' without one."""
    if size is None or fault not in truth or fault == "telemetry_dropout":
        return "-"
    return "yes" if size[0] <= truth[fault] <= size[1] else "no"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cache", type=Path, required=True)
    p.add_argument("--model", type=Path, required=True)
    p.add_argument("--calibrate", nargs="+", required=True)
    p.add_argument("--judge", nargs="+", required=True)
    p.add_argument("--rate", type=float, default=1e-3)
    p.add_argument("--make", action="store_true", help="simulate missing records")
    args = p.parse_args()
    specs = {**b.records("tune"), **held(), **held(7200, "fresh")}
    scales = WheelScales.from_model_file(args.model)
    wheel = IdentifiedWheel.from_json(args.model)

    def features(name):
        path = args.cache / f"{name}.mcap"
        if args.make and not path.exists():
            b._record(args.cache, name, specs[name])
        data = load_record(path, scales.Ts, outputs=RECORD_OUTPUTS, max_gap=np.inf)
        return compute_features(data, wheel, scales)

    cal = DiagnosisCalibration.measure(
        [features(n) for n in args.calibrate], sources=args.calibrate
    )
    print(f"calibration: {len(args.calibrate)} records, {cal.hours:.2f} h")
    tally = {"faulty": 0, "detected": 0, "named": 0, "ci": 0, "ci_n": 0, "healthy_h": 0.0}
    tally["false"] = 0
    print(f"{'record':12s} {'signal':9s} {'injected':42s} first alarm")
    for name in args.judge:
        _, _, signal, duration, _, text, onset = specs[name]
        res = run(features(name), cal, args.rate)
        truth = b._sizes(text) if text else {}
        if not text:
            tally["healthy_h"] += duration / 3600
            tally["false"] += len(res.events)
            print(f"{name:12s} {signal:9s} {'healthy':42s} {res.verdict()}")
            continue
        tally["faulty"] += 1
        before = [e for e in res.events if e.t_s < onset]
        after = [e for e in res.events if onset <= e.t_s <= onset + 300 or onset == 0]
        first = after[0] if after and not before else None
        named = first is not None and first.fault in b._truth(text)
        tally["detected"] += first is not None
        tally["named"] += named
        ci = None if first is None or math.isnan(first.fit.size) else first.fit.ci95
        h = holds(first.fault, ci, truth) if first else "-"
        tally["ci"] += h == "yes"
        tally["ci_n"] += h != "-"
        alarm = (
            "none" if first is None else f"{first.fault} {first.fit.size:.3g} {ci} at {first.t_s:g}"
        )
        alarm += f" (before onset: {before[0].fault})" if before else ""
        print(f"{name:12s} {signal:9s} {text:42s} {alarm}  named={'yes' if named else 'no'} ci={h}")
    t = tally
    print(
        f"\nfaults {t['faulty']}: detected in 300 s {t['detected']}, first named right "
        f"{t['named']}, intervals holding the truth {t['ci']}/{t['ci_n']}; healthy "
        f"{t['healthy_h']:.2f} h: {t['false']} alarms at {args.rate:g}/h"
    )


if __name__ == "__main__":
    main()
