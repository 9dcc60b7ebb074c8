"""False-alarm rates, detection and naming of ``rwlab diagnose`` on units it was not tuned on.

Run:  python bench/bench_diagnose.py [--healthy-records 6] [--runs 2] [--rates 1 10 100]

A model (with its healthy reference) is identified by ``rwlab identify`` on a
fault-free 20-minute PRBS of unit 0 of the realistic twin
(:meth:`rwlab.wheel.WheelParams.for_unit`). Everything else comes from units
1, 2, … with seeds the tests do not use (≥ 1000):

1. false alarms: healthy 20-minute records (PRBS, chirp, multisine, steps,
   in turn) diagnosed with restarting detectors (``latch=False``) at each
   requested rate; the table prints requested vs measured per detector and the
   hours behind each figure;
2. detection: each fault of issue 23 (and two at once), onset at 600 s, on a
   PRBS and a chirp; detected within 300 s of onset, named right, any alarm
   before onset; detection vs magnitude for friction and the sensor bias; a
   confusion matrix (injected fault → first name given after onset).

Simulated clock; the realistic twin makes a 20-minute record take ~10–30 s.
A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import tempfile
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from rwlab.cli import main as cli
from rwlab.diagnose import HealthyReference, diagnose
from rwlab.testbed import ExperimentConfig, load_record, run_experiment
from rwlab.wheel import RW90, IdentifiedWheel

SIGNALS = ("prbs", "chirp", "multisine", "step")
DETECTORS = ("friction", "friction_change", "motor", "speed", "lag", "stuck", "dropout")
FAULTS = {
    "friction=1.5": {"friction"},
    "torque_constant=0.8": {"torque_constant"},
    "speed_sensor_bias=15": {"speed_sensor_bias"},
    "current_limit=0.45": {"current_limit"},
    "speed_sensor_stuck": {"speed_sensor_stuck"},
    "telemetry_dropout=0.3": {"telemetry_dropout"},
    "friction=1.5+speed_sensor_bias=15": {"friction", "speed_sensor_bias"},
}
CURVES = {"friction": (1.2, 1.35, 1.5, 2.0), "speed_sensor_bias": (3, 6, 10, 20)}
ONSET, DURATION = 600.0, 1200.0


def _record(path: Path, unit: int, seed: int, signal: str, faults=()) -> Path:
    cfg = ExperimentConfig(signal=signal, duration=DURATION, seed=seed, faults=tuple(faults))
    run_experiment(cfg, path, params=RW90.for_unit(unit), force=True)
    return path


def _faults(text: str) -> list[str]:
    """'a=1+b=2' → ['a=1@600', 'b=2@600'] (dropouts: five, 60 s apart)."""
    out = []
    for part in text.split("+"):
        if part.startswith("telemetry_dropout"):
            out += [f"{part}@{ONSET + 60 * i:g}" for i in range(5)]
        else:
            out.append(f"{part}@{ONSET:g}")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--healthy-records", type=int, default=6, help="20-min healthy records")
    parser.add_argument("--runs", type=int, default=2, help="runs per fault and signal")
    parser.add_argument("--rates", type=float, nargs="+", default=[1.0, 10.0, 100.0])
    parser.add_argument("--part", choices=["all", "healthy", "faults"], default="all")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        _record(out / "ident.mcap", 0, 0, "prbs")
        result = CliRunner().invoke(cli, ["identify", str(out / "ident.mcap"), "--out", str(out)])
        assert result.exit_code == 0, result.output
        wheel = IdentifiedWheel.from_json(out / "model.json")
        ref = HealthyReference.from_model_file(out / "model.json")

        def run(path, **kw):
            data = load_record(
                path, wheel.Ts, outputs=("speed", "current", "age", "lost"), max_gap=np.inf
            )
            return diagnose(data, wheel, ref, **kw)

        if args.part != "faults":
            _healthy(args, run, out)
        if args.part != "healthy":
            _faults_part(args, run, out)


def _healthy(args, run, out: Path) -> None:
    counts: dict[float, Counter] = {rate: Counter() for rate in args.rates}
    latched = 0
    hours = 0.0
    for i in range(args.healthy_records):
        path = _record(out / "h.mcap", 1 + i, 1000 + i, SIGNALS[i % 4])
        hours += DURATION / 3600
        latched += len(run(path).alarms)
        for rate in args.rates:
            counts[rate].update(
                a.detector for a in run(path, false_alarms_per_hour=rate, latch=False).alarms
            )
    print(
        f"healthy: {hours:.2f} h on units 1..{args.healthy_records} "
        f"({', '.join(SIGNALS)} in turn); alarms at the default 1e-3/h: {latched}"
    )
    print(f"{'requested /h':>12} " + " ".join(f"{d:>15}" for d in DETECTORS))
    for rate in args.rates:
        print(f"{rate:>12g} " + " ".join(f"{counts[rate][d] / hours:>15.3g}" for d in DETECTORS))
    print(f"(measured per hour over {hours:.2f} h each)\n")


def _faults_part(args, run, out: Path) -> None:
    confusion: dict[str, Counter] = defaultdict(Counter)
    print(
        f"{'fault':<36} {'signal':<6} {'runs':>4} {'det≤300s':>8} {'named':>5} "
        f"{'early':>5} {'sizes (first alarm)'}"
    )
    unit = 10
    for fault, truth in FAULTS.items():
        for signal in ("prbs", "chirp"):
            det = named = early = 0
            sizes = []
            for _r in range(args.runs):
                unit += 1
                path = _record(out / "f.mcap", unit, 2000 + unit, signal, _faults(fault))
                alarms = run(path).alarms
                early += sum(a.t_s < ONSET for a in alarms)
                after = [a for a in alarms if ONSET <= a.t_s <= ONSET + 300]
                kinds = {a.kind for a in after}
                det += bool(after)
                named += bool(after) and truth <= kinds
                confusion[fault][after[0].kind if after else "none"] += 1
                sizes += [f"{a.kind}:{a.magnitude:.3g}" for a in after[:2] if a.magnitude]
            print(
                f"{fault:<36} {signal:<6} {args.runs:>4} {det:>8} {named:>5} {early:>5} "
                f"{' '.join(sizes)}"
            )
    print("\nconfusion (injected → first name within 300 s):")
    for fault, c in confusion.items():
        print(f"  {fault:<36} {dict(c)}")
    print("\ndetection vs magnitude (PRBS, one run each):")
    for name, values in CURVES.items():
        row = []
        for v in values:
            unit += 1
            path = _record(out / "c.mcap", unit, 3000 + unit, "prbs", _faults(f"{name}={v}"))
            after = [a for a in run(path).alarms if ONSET <= a.t_s <= ONSET + 300]
            row.append(f"{v:g}: {'%.0f s' % (after[0].t_s - ONSET) if after else 'missed'}")
        print(f"  {name:<20} " + ", ".join(row))


if __name__ == "__main__":
    main()
