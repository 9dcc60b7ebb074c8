"""The GLR pipeline on ``rwlab hil`` flights' wheel telemetry (acceleration mode), per preset.

Run:  python bench/bench_fdi_hil.py --wheel rw90 --cache DIR --calibrate 101 102 103 \
          --judge 11/ 12/ 11/1:friction=4@800 11/3:current_limit=0.42@800 ...

Each ``--calibrate`` seed is a healthy flight of the preset's redundant scenario
(``geo-smallsat-pyramid``: RW90; ``geo-comsat``: NRWA-T6), each of its wheels one
healthy record; every ``--judge`` flight (``SEED/FAULT``, FAULT as ``rwlab hil
--fault``, empty: healthy) is diagnosed wheel by wheel with that calibration, after the
flight. The flights keep the health check's excitation (the null-space dither and the
capacity probes) but its own tests are muted, so that no alarm idles the faulty wheel
and the pipeline sees the whole fault; the pipeline does not run in flight yet. A wheel's
telemetry is read in blocks of the pipeline's 0.5 s: the mean command and current over
the block, the speed at its end (:func:`wheel_record`). The CubeSat's three orthogonal
wheels have no null space to excite: the RW-0.01 is not flown here. A benchmark, not a
test.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np

from rwlab.attitude.scenario import load_scenario
from rwlab.attitude.wheels import physics_params
from rwlab.data import IOData
from rwlab.diagnose.detectors import MODEL_BASED
from rwlab.diagnose.features import RECORD_OUTPUTS, WheelScales, compute_features
from rwlab.diagnose.pipeline import run
from rwlab.diagnose.wheel_calibration import DiagnosisCalibration
from rwlab.errors import RwlabWarning
from rwlab.testbed import load_record

SCENARIO = {"rw90": "geo-smallsat-pyramid", "nrwa-t6": "geo-comsat"}
TS = 0.5  # the pipeline's sample time, s (the flights' control period is 0.1 s)
DURATION_S = 1400.0
# the flight's own tests muted, the excitation kept (run in a child: the patch stays there)
MUTED = (
    "import sys, rwlab.hil.health as h; h.TrackingTest.update = lambda self, *a, **k: None; "
    "from rwlab.cli import main; sys.exit(main())"
)


def fly(cache: Path, wheel: str, seed: int, fault: str = "") -> Path:
    """The flight's folder, flown if missing."""
    tag = fault.replace(":", "n").replace("@", "at").replace("=", "")
    out = cache / f"{wheel}_s{seed}{'_' + tag if fault else ''}"
    if not (out / "record.mcap").exists():
        cmd = [sys.executable, "-c", MUTED, "hil", "--scenario", SCENARIO[wheel]]
        cmd += ["--duration", f"{DURATION_S:g}", "--seed", str(seed), "--no-reference"]
        cmd += ["--out", str(out)] + (["--fault", fault] if fault else [])
        subprocess.run(cmd, check=True, capture_output=True)
    return out


def wheel_record(path: Path, node: int, scales: WheelScales) -> IOData:
    """One wheel's flight telemetry in blocks of ``scales.Ts`` from the flight's start:
    the mean command in force over each block, the mean current over it, the speed and
    the lost-frame count at its end, the oldest telemetry age in it."""
    data = load_record(path, None, node=node, outputs=RECORD_OUTPUTS, max_gap=np.inf)
    t = data.tstart + data.Ts * np.arange(data.N)
    first = int(np.searchsorted(t, -1e-9))
    m = round(scales.Ts / data.Ts)
    u, y = data.u[first:, 0], data.y[first:]
    ends = m * np.arange((len(u) - 1) // m + 1)
    command = np.array([u[i : i + m].mean() for i in ends])
    current = np.array([y[max(0, i - m + 1) : i + 1, 1].mean() for i in ends])
    age = np.array([y[max(0, i - m + 1) : i + 1, 2].max() for i in ends])
    out = np.column_stack([y[ends, 0], current, age, y[ends, 3]])
    return IOData(
        command[:, None], out, scales.Ts, output_names=data.output_names, input_units=["rpm/s"]
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--wheel", choices=sorted(SCENARIO), required=True)
    p.add_argument("--cache", type=Path, required=True)
    p.add_argument("--calibrate", type=int, nargs="+", required=True)
    p.add_argument("--judge", nargs="+", required=True)
    p.add_argument("--rate", type=float, default=1e-3)
    args = p.parse_args()
    warnings.simplefilter("ignore", RwlabWarning)
    args.cache.mkdir(parents=True, exist_ok=True)
    params = physics_params(load_scenario(SCENARIO[args.wheel]))
    scales = WheelScales.from_params(params, TS)
    healthy = [
        compute_features(
            wheel_record(fly(args.cache, args.wheel, s) / "record.mcap", n, scales), None, scales
        )
        for s in args.calibrate
        for n in (1, 2, 3, 4)
    ]
    cal = DiagnosisCalibration.measure(healthy, origin=f"hil seeds {args.calibrate}")
    limits = {n: round(cal.threshold(n, args.rate).log_lr, 1) for n in MODEL_BASED}
    print(f"{args.wheel}: calibrated on {cal.hours:.2f} wheel-hours, thresholds {limits}")
    print(f"{'flight':<32} {'node':>4}  first alarm")
    for spec in args.judge:
        seed, _, fault = spec.partition("/")
        out = fly(args.cache, args.wheel, int(seed), fault)
        onset = float(fault.rpartition("@")[2]) if fault else None
        for node in (1, 2, 3, 4):
            data = wheel_record(out / "record.mcap", node, scales)
            result = run(compute_features(data, None, scales), cal, args.rate)
            alarm = "none"
            if result.events:
                e = result.events[0]
                lo, hi = e.fit.ci95
                size = "" if np.isnan(e.fit.size) else f" {e.fit.size:.3g} [{lo:.3g}, {hi:.3g}]"
                late = "" if onset is None else f" (+{e.t_s - onset:.1f} s)"
                named = e.fault if e.first == e.fault else f"{e.first} → {e.fault}"
                alarm = f"{named}{size} at {e.t_s:g} s{late}, runner-up {e.runner_up}"
            injected = fault.startswith(f"{node}:")
            print(f"{spec:<32} {node:>4}{' *' if injected else '  '} {alarm}")
    print(json.dumps({"thresholds": limits, "hours": cal.hours}))


if __name__ == "__main__":
    main()
