"""The GLR pipeline (``rwlab.diagnose.pipeline``) on twin records: detection, naming, sizes.

Run:  python bench/bench_fdi.py --cache DIR --model model.json --calibrate NAME... \
          --judge NAME... [--rate 1e-3]

Records are read from ``--cache`` by name (``bench_diagnose.py``'s names and
specs, the held-out ``held_*``/``fresh_*`` sets and the per-wheel ``w5_*`` set
below, made by ``--make`` for ``--wheel``). The
calibration is measured on the ``--calibrate`` records (healthy) and every
``--judge`` record is diagnosed with it; the table prints, per record, the
injected fault, the first alarm, whether it came within 300 s of onset, whether
its name is the injected fault's, and whether the 95 % interval holds the size.
``--rules`` also runs the rule detectors (``rwlab diagnose`` without
``--calibration``) on the same records and scores them the same way;
``--save-calibration`` writes the calibration with its provenance. A
benchmark, not a test.

Every wheel model (``--wheel``): the ``w5`` set is made per preset on units
9001-9104, its current limits at 60-80 % of the preset's spec:

    python bench/bench_fdi.py --wheel nrwa-t6 --cache C/nrwa-t6 --model M/model.json \
        --calibrate tune_h0 ... tune_h5 --judge w5_f9001 ... w5_h1 --make --rules
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import bench_diagnose as b
from rwlab.diagnose.features import RECORD_OUTPUTS, WheelScales, compute_features
from rwlab.diagnose.pipeline import run
from rwlab.diagnose.wheel_calibration import DiagnosisCalibration
from rwlab.errors import RwlabWarning
from rwlab.testbed import ExperimentConfig, load_record, run_experiment
from rwlab.wheel import IdentifiedWheel
from rwlab.wheelspec import WheelSpec

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


def wheel_set(current_limit_a: float, first: int = 9000, tag: str = "w5") -> dict[str, tuple]:
    """name → spec of a per-wheel held-out set (``w5``: units 9001-9102; ``w6``: units
    9201-9302, made after the last change to judge it once; ``w7``: units 9401-9502,
    made to judge the weak motor's torque cap; ``w8``: units 9601-9702, made to judge the
    driver's acceleration cap in the fault models once; ``w9``: units 9801-9902, made to
    judge the clamp read off its flat top once; ``w10``: units 10001-10102, made to judge
    the frozen reading counted while moving once; ``w11``: units 10201-10302, made to
    judge readings of 0 left out of the bias test once; ``w12``: units 10401-10502, made
    to judge the one-sided rotor faults once), limits at 60-80 % of the
    wheel's specified clamp ``current_limit_a`` (A)."""
    limit = current_limit_a
    faults = (
        ("friction=1.5", "prbs"),
        ("friction=1.7", "chirp"),
        ("friction=3", "step"),
        ("torque_constant=0.8", "prbs"),
        ("torque_constant=0.85", "chirp"),
        ("speed_sensor_bias=15", "prbs"),
        ("speed_sensor_bias=25", "chirp"),
        (f"current_limit={0.7 * limit:.4g}", "prbs"),
        (f"current_limit={0.6 * limit:.4g}", "chirp"),
        ("speed_sensor_stuck", "chirp"),
        ("telemetry_dropout=0.3", "prbs"),
        ("torque_constant=0.8+speed_sensor_bias=20", "chirp"),
    )
    out = {}
    for i, (fault, signal) in enumerate(faults):
        u = first + 1 + i
        out[f"{tag}_f{u}"] = (u, 90000 + u, signal, 900, b._faults(fault, 600.0), fault, 600.0)
    for i, fault in enumerate(("friction=1.5", f"current_limit={0.8 * limit:.4g}")):
        u = first + 51 + i
        out[f"{tag}_p{u}"] = (u, 90000 + u, "prbs", 600, b._faults(fault, 0.0), fault, 0.0)
    for i in range(2):
        u = first + 101 + i
        out[f"{tag}_h{i}"] = (u, 91000 + u, b.SIGNALS[i % 4], 1200, (), "", None)
    return out


def healthy_set(first: int, tag: str, count: int) -> dict[str, tuple]:
    """name → spec of ``count`` healthy 20-min records on units ``first``+1..., the four
    signals in turn as the calibration's (``hr``: units 13001-13024, made to judge the
    rates on request on the calibration's signal mix)."""
    out = {}
    for i in range(count):
        u = first + 1 + i
        out[f"{tag}_h{i}"] = (u, 93000 + u, b.SIGNALS[i % 4], 1200, (), "", None)
    return out


def make(cache: Path, name: str, spec: tuple, wheel: str) -> Path:
    """Simulate one record of ``wheel`` into the cache (kept: made once)."""
    path = cache / f"{name}.mcap"
    if not path.exists():
        unit, seed, signal, duration, faults, _, _ = spec
        cfg = ExperimentConfig(
            signal=signal, duration=duration, seed=seed, unit=unit, faults=faults, wheel=wheel
        )
        run_experiment(cfg, cache / "tmp.mcap", force=True)
        (cache / "tmp.mcap").rename(path)
    return path


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


def holds(fault: str, size: tuple | None, truth: dict[str, float]) -> str:
    """'yes'/'no' for an interval holding the injected size; '-' without one."""
    if size is None or fault not in truth or fault == "telemetry_dropout":
        return "-"
    return "yes" if size[0] <= truth[fault] <= size[1] else "no"


class Tally:
    """Detections, namings and intervals of one detector family over the judged records."""

    def __init__(self) -> None:
        self.faulty = self.detected = self.named = self.ci = self.ci_n = self.false = 0
        self.healthy_h = 0.0

    def add(self, text: str, onset, duration: float, alarms: list[tuple]) -> str:
        """Score one record's alarms, (t_s, fault, ci or None) each; the table's cell."""
        if not text:
            self.healthy_h += duration / 3600
            self.false += len(alarms)
            return "healthy: no alarm" if not alarms else f"{alarms[0][1]} at {alarms[0][0]:g}"
        self.faulty += 1
        before = [a for a in alarms if a[0] < onset]
        after = [a for a in alarms if onset <= a[0] <= onset + 300 or onset == 0]
        first = after[0] if after and not before else None
        named = first is not None and first[1] in b._truth(text)
        self.detected += first is not None
        self.named += named
        h = holds(first[1], first[2], b._sizes(text)) if first else "-"
        self.ci += h == "yes"
        self.ci_n += h != "-"
        cell = "none" if first is None else f"{first[1]} {first[3]} at {first[0]:g}"
        cell += f" (before onset: {before[0][1]})" if before else ""
        return f"{cell}  named={'yes' if named else 'no'} ci={h}"

    def line(self, rate: str) -> str:
        return (
            f"faults {self.faulty}: detected in 300 s {self.detected}, first named right "
            f"{self.named}, intervals holding the truth {self.ci}/{self.ci_n}; healthy "
            f"{self.healthy_h:.2f} h: {self.false} alarms at {rate}"
        )


def record_arguments(description: str) -> argparse.ArgumentParser:
    """A parser with the arguments every GLR bench takes: the records, the model, the wheel."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--cache", type=Path, required=True)
    p.add_argument("--model", type=Path, required=True)
    p.add_argument("--calibrate", nargs="+", required=True)
    p.add_argument("--judge", nargs="+", required=True)
    p.add_argument("--wheel", default="rw90", help="the wheel model the records are made of")
    return p


def record_features(path: Path, wheel: IdentifiedWheel, scales: WheelScales):
    """The diagnosis features of one cached record against the identified ``wheel``."""
    data = load_record(path, scales.Ts, outputs=RECORD_OUTPUTS, max_gap=np.inf)
    return compute_features(data, wheel, scales)


def main() -> None:
    p = record_arguments(__doc__.splitlines()[0])
    p.add_argument("--rate", type=float, default=1e-3)
    p.add_argument("--make", action="store_true", help="simulate missing records")
    p.add_argument("--rules", action="store_true", help="also score the rule detectors")
    p.add_argument("--save-calibration", type=Path, help="write the calibration here")
    p.add_argument("--origin", default="", help="the calibration's provenance line")
    args = p.parse_args()
    warnings.simplefilter("ignore", RwlabWarning)
    reference = b.HealthyReference.from_model_file(args.model) if args.rules else None
    limit = WheelSpec.load(args.wheel).current_limit_a
    specs = {**b.records("tune"), **held(), **held(7200, "fresh"), **wheel_set(limit)}
    specs |= wheel_set(limit, 9200, "w6") | wheel_set(limit, 9400, "w7")
    specs |= wheel_set(limit, 9600, "w8") | wheel_set(limit, 9800, "w9")
    specs |= wheel_set(limit, 10000, "w10") | wheel_set(limit, 10200, "w11")
    specs |= wheel_set(limit, 10400, "w12") | wheel_set(limit, 10600, "w13")
    specs |= wheel_set(limit, 10800, "w14") | wheel_set(limit, 11000, "w15")
    specs |= wheel_set(limit, 11200, "w16") | wheel_set(limit, 11400, "w17")
    specs |= wheel_set(limit, 11600, "w18") | wheel_set(limit, 11800, "w19")
    specs |= wheel_set(limit, 12000, "w20") | wheel_set(limit, 12200, "w21")
    specs |= wheel_set(limit, 12400, "w22") | healthy_set(13000, "hr", 24)
    specs |= wheel_set(limit, 12600, "w23") | wheel_set(limit, 12800, "w24")
    # made at stop 61 to judge the pipeline as rwlab diagnose's default once
    specs |= wheel_set(limit, 13400, "w25") | wheel_set(limit, 13600, "w26")
    # made at stop 62 to judge, once, an alarm's onset and size re-read for its name
    specs |= wheel_set(limit, 13800, "w27")
    # made at stop 63 to judge, once, the clamp's binding test without rounding
    specs |= wheel_set(limit, 14000, "w28")
    scales = WheelScales.from_model_file(args.model)
    wheel = IdentifiedWheel.from_json(args.model)

    def path(name):
        if args.make:
            return make(args.cache, name, specs[name], args.wheel)
        return args.cache / f"{name}.mcap"

    def features(name):
        return record_features(path(name), wheel, scales)

    cal = DiagnosisCalibration.measure(
        [features(n) for n in args.calibrate], sources=args.calibrate, origin=args.origin
    )
    if args.save_calibration:
        cal.save(args.save_calibration)
    print(f"calibration: {len(args.calibrate)} records, {cal.hours:.2f} h")
    glr, rules = Tally(), Tally()
    print(f"{'record':12s} {'signal':9s} {'injected':42s} first alarm")
    for name in args.judge:
        _, _, signal, duration, _, text, onset = specs[name]
        res = run(features(name), cal, args.rate)
        # scored at the alarm, as the rule detectors are (the name and fit then; the
        # record's end, where the event was followed and perhaps re-labelled, after "end:")
        alarms = [
            (
                e.t_s,
                e.first,
                None if math.isnan(e.at_alarm.size) else e.at_alarm.ci95,
                f"{e.at_alarm.size:.3g} {None if math.isnan(e.at_alarm.size) else e.at_alarm.ci95}"
                + (f" (end: {e.fault} {e.fit.size:.3g})" if e.fit is not e.at_alarm else ""),
            )
            for e in res.events
        ]
        cell = glr.add(text, onset, duration, alarms)
        print(f"{name:12s} {signal:9s} {text or 'healthy':42s} {cell}")
        if args.rules:
            found = b.diagnose(b.load(path(name), wheel.Ts), wheel, reference).alarms
            alarms = [
                (a.t_s, a.kind, a.ci, f"{a.magnitude:.3g} {a.ci}" if a.magnitude else "")
                for a in found
            ]
            cell = rules.add(text, onset, duration, alarms)
            print(f"{'':12s} {'':9s} {'rule detectors':42s} {cell}")
    print("\nGLR pipeline:   " + glr.line(f"{args.rate:g}/h"))
    if args.rules:
        print("rule detectors: " + rules.line("their default rates"))


if __name__ == "__main__":
    main()
