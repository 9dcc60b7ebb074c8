"""Detection delay, isolation and false-alarm rate of ``rwlab diagnose`` over seeded runs.

Run:  python bench/bench_diagnose.py [--runs 5] [--healthy-hours 6] [--model linear|nonlinear]
                                     [--speed-test]

A model is identified (paper A's study) from a fault-free 20-minute PRBS
(seed 0). Then, on the simulated RW90 with PRBS commands of other seeds:

- fault-free 2-hour records (seeds 1, 2, …) give the false-alarm rate;
- 20-minute records with one injected fault each (``--runs`` seeds per fault)
  give the detection delay (first alarm − injection), how often the first alarm
  names the injected fault, and any alarm before the injection.

Everything runs on the simulated clock. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from rwlab.cli import main as cli
from rwlab.diagnose import diagnose
from rwlab.testbed import ExperimentConfig, load_record, run_experiment
from rwlab.wheel import IdentifiedWheel

FAULTS = {
    "friction=3@900": "friction",
    "speed_sensor_stuck@600": "speed_sensor_stuck",
    "torque_constant=0.5@600": "torque_constant",
    "current_limit=0.3@600": "current_limit",
    "speed_sensor_bias=50@600": "speed_sensor_bias",
    "telemetry_dropout=5@600": "telemetry_dropout",
}


def _alarms(path: Path, wheel: IdentifiedWheel, speed_test: bool):
    data = load_record(path, wheel.Ts, outputs=("speed", "current", "age"), max_gap=np.inf)
    return diagnose(data, wheel, speed_test=speed_test).alarms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="seeded runs per fault")
    parser.add_argument("--healthy-hours", type=float, default=6.0, help="in 2-hour records")
    parser.add_argument(
        "--model",
        choices=["linear", "nonlinear"],
        default=None,
        help="which model of model.json (default: the file's preferred one)",
    )
    parser.add_argument("--speed-test", action="store_true", help="also the speed CUSUM")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        run_experiment(ExperimentConfig(duration=1200, seed=0), out / "ident.mcap")
        result = CliRunner().invoke(cli, ["identify", str(out / "ident.mcap"), "--out", str(out)])
        assert result.exit_code == 0, result.output
        wheel = IdentifiedWheel.from_json(out / "model.json", model=args.model)
        print(f"model: {args.model or 'preferred'}; speed test: {args.speed_test}")

        start = time.perf_counter()
        n_healthy = max(1, round(args.healthy_hours / 2))
        false_alarms = []
        for seed in range(1, n_healthy + 1):
            path = out / f"healthy{seed}.mcap"
            run_experiment(ExperimentConfig(duration=7200, seed=seed), path)
            false_alarms += _alarms(path, wheel, args.speed_test)
        hours = 2 * n_healthy
        print(f"fault-free: {hours} h of PRBS (seeds 1..{n_healthy}), {len(false_alarms)} alarms")
        print(
            f"  measured false-alarm rate: {len(false_alarms) / hours:.3g} per hour "
            f"(designed: 1e-3 per hour per detector; {[a.to_dict() for a in false_alarms]})"
        )
        print()
        print(
            f"{'fault':<28} {'runs':>4} {'detected':>8} {'named':>6} {'early':>6} "
            f"{'delay median [s]':>16} {'delay max [s]':>13}"
        )
        for fault, name in FAULTS.items():
            t_fault = float(fault.split("@")[1])
            delays, named, early = [], 0, 0
            for seed in range(100, 100 + args.runs):
                path = out / "fault.mcap"
                cfg = ExperimentConfig(duration=1200, seed=seed, faults=(fault,))
                run_experiment(cfg, path, force=True)
                alarms = _alarms(path, wheel, args.speed_test)
                early += sum(a.t_s < t_fault for a in alarms)
                after = [a for a in alarms if a.t_s >= t_fault]
                if after:
                    delays.append(after[0].t_s - t_fault)
                    named += after[0].kind == name
            med = f"{np.median(delays):.1f}" if delays else "—"
            worst = f"{max(delays):.1f}" if delays else "—"
            print(
                f"{fault:<28} {args.runs:>4} {len(delays):>8} {named:>6} {early:>6} "
                f"{med:>16} {worst:>13}"
            )
        print(f"\n({time.perf_counter() - start:.0f} s of wall time for the records and diagnoses)")


if __name__ == "__main__":
    main()
