"""The GLR pipeline on ``rwlab hil`` flights' wheel telemetry (acceleration mode), per preset.

Run:  python bench/bench_fdi_hil.py --wheel rw90 --cache DIR --calibrate 101 102 103 \
          --judge 11/ 12/ 11/1:friction=4@800 11/3:current_limit=0.42@800 ...

Each ``--calibrate`` seed is a healthy flight of the preset's redundant scenario
(``geo-smallsat-pyramid``: RW90; ``geo-comsat``: NRWA-T6), each of its wheels one
healthy record; every ``--judge`` flight (``SEED/FAULT``, FAULT as ``rwlab hil
--fault``, empty: healthy) is diagnosed wheel by wheel with that calibration, after the
flight. The flights keep the health check's excitation (the null-space dither and the
capacity probes) but its own tests (pipeline included) are muted, so that no alarm
idles the faulty wheel and the pipeline sees the whole fault (``rwlab hil`` runs the
same pipeline in flight, :mod:`rwlab.hil.live`; a wheel's telemetry is read as it feeds
it: :func:`rwlab.hil.live.flight_features`).
The CubeSat's three orthogonal wheels have no null space to excite: the RW-0.01 is not
flown here. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np

from rwlab.diagnose.detectors import MODEL_BASED
from rwlab.diagnose.pipeline import run
from rwlab.diagnose.wheel_calibration import DiagnosisCalibration
from rwlab.errors import RwlabWarning
from rwlab.hil.live import QUICK_S, flight_features

SCENARIO = {"rw90": "geo-smallsat-pyramid", "nrwa-t6": "geo-comsat"}
DURATION_S = 1400.0
# the flight's own tests (its pipeline, the tracking test and the probes) muted, the
# excitation kept (run in a child: the patch stays there)
MUTED = (
    "import sys, rwlab.hil.health as h, rwlab.hil.live as live; "
    "h.TrackingTest.update = lambda self, *a, **k: None; "
    "live.PipelineWatch.update = lambda self, *a, **k: []; "
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


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--wheel", choices=sorted(SCENARIO), required=True)
    p.add_argument("--cache", type=Path, required=True)
    p.add_argument("--calibrate", type=int, nargs="+", required=True)
    p.add_argument("--judge", nargs="+", required=True)
    p.add_argument("--rate", type=float, default=1e-3)
    p.add_argument("--save-calibration", type=Path, help="write the calibration here")
    args = p.parse_args()
    warnings.simplefilter("ignore", RwlabWarning)
    args.cache.mkdir(parents=True, exist_ok=True)
    healthy = [
        f
        for s in args.calibrate
        for f in flight_features(fly(args.cache, args.wheel, s) / "record.mcap").values()
    ]
    flights = ", ".join(str(s) for s in args.calibrate)
    origin = (
        f"{len(healthy)} wheels of healthy rwlab hil flights of {SCENARIO[args.wheel]} "
        f"({DURATION_S:g} s, seeds {flights}; bench/bench_fdi_hil.py)"
    )
    names = [f"seed {s} node {n}" for s in args.calibrate for n in (1, 2, 3, 4)]
    cal = DiagnosisCalibration.measure(
        healthy, sources=names, origin=origin, quick_window_s=QUICK_S
    )
    if args.save_calibration:
        cal.save(args.save_calibration)
    limits = {n: round(cal.threshold(n, args.rate).log_lr, 1) for n in MODEL_BASED}
    print(f"{args.wheel}: calibrated on {cal.hours:.2f} wheel-hours, thresholds {limits}")
    print(f"{'flight':<32} {'node':>4}  first alarm")
    for spec in args.judge:
        seed, _, fault = spec.partition("/")
        out = fly(args.cache, args.wheel, int(seed), fault)
        onset = float(fault.rpartition("@")[2]) if fault else None
        for node, features in flight_features(out / "record.mcap").items():
            result = run(features, cal, args.rate)
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
