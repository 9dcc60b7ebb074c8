"""The GLR pipeline on ``rwlab hil`` flights' wheel telemetry (acceleration mode), per preset.

Run:  python bench/bench_fdi_hil.py --wheel rw90 --cache DIR --calibrate 101 102 103 \
          --judge 11/ 12/ 11/1:friction=4@800 11/3:current_limit=0.42@800 ...

Each ``--calibrate`` seed is a healthy flight of the preset's redundant scenario
(``geo-smallsat-pyramid``: RW90; ``geo-comsat``: NRWA-T6), each of its wheels one
healthy record; every ``--judge`` flight (``SEED/FAULT``, FAULT as ``rwlab hil
--fault``, empty: healthy) is diagnosed wheel by wheel with that calibration, after the
flight. The flights keep the health check's excitation (the null-space dither and the
capacity probes) but its own tests are muted, so that no alarm idles the faulty wheel
and the pipeline sees the whole fault (``rwlab hil`` runs the same pipeline in flight,
:mod:`rwlab.hil.live`; a wheel's telemetry is read as it feeds it, :func:`wheel_record`).
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

from rwlab.attitude.scenario import load_scenario
from rwlab.attitude.wheels import physics_params
from rwlab.data import IOData
from rwlab.diagnose.detectors import MODEL_BASED
from rwlab.diagnose.features import RECORD_OUTPUTS, WheelScales, compute_features
from rwlab.diagnose.pipeline import run
from rwlab.diagnose.wheel_calibration import DiagnosisCalibration
from rwlab.errors import RwlabWarning
from rwlab.hil.live import SAMPLE_S, sampled
from rwlab.testbed import load_record

SCENARIO = {"rw90": "geo-smallsat-pyramid", "nrwa-t6": "geo-comsat"}
DURATION_S = 1400.0
# design choice: a decision window of 5 s beside the bank's, so that a large fault (a
# dead motor, friction x 4) crosses at the first decision after it, as the loop's
# pointing needs (shortest 60 s: a dead motor at +15 s cost 0.123 deg; 10 s: friction x 4
# on the RW90 at +10 s cost 0.118 deg of the 0.1-deg requirement)
QUICK_S = 5.0
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


def wheel_record(path: Path, node: int) -> IOData:
    """One wheel's flight telemetry on the live diagnosis's grid from the flight's start
    (:func:`rwlab.hil.live.sampled`: what ``rwlab hil`` feeds its pipeline)."""
    data = load_record(path, None, node=node, outputs=RECORD_OUTPUTS, max_gap=np.inf)
    t = data.tstart + data.Ts * np.arange(data.N)
    first = int(np.searchsorted(t, -1e-9))
    return sampled(data.u[first:-1, 0], data.y[first:, :3], round(SAMPLE_S / data.Ts))


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
    params = physics_params(load_scenario(SCENARIO[args.wheel]))
    scales = WheelScales.from_params(params, SAMPLE_S)
    healthy = [
        compute_features(
            wheel_record(fly(args.cache, args.wheel, s) / "record.mcap", n), None, scales
        )
        for s in args.calibrate
        for n in (1, 2, 3, 4)
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
        for node in (1, 2, 3, 4):
            data = wheel_record(out / "record.mcap", node)
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
