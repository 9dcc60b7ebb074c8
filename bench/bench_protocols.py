"""One wheel, every protocol profile: the same 20-minute PRBS recorded and identified through each.

Run:  python bench/bench_protocols.py [--duration 1200] [--seed 3] [--out DIR] [--only NAME ...]

For each protocol in the registry (``rwlab.wheel.link.protocol_names``: rwlab's
DBC, CANopen and its profiles on a virtual CAN bus, NSP and its profiles over a
pseudo-terminal pair, and any a package registers) the command
``rwlab experiment --protocol P --duration D --seed S`` runs against that
protocol's twin on the simulated clock, then ``rwlab identify`` chooses a model
from the record. The table gives per protocol: commands, telemetry frames,
lost telemetry frames, lost commands (commands whose sequence the wheel never
echoed), wall time of the experiment, the chosen structure and its validation
fit (%), and the fit's difference to the rwlab protocol's. It ends with the
spread of the fits and the total of lost commands (the targets: 0 lost, fits
within 0.1 point of each other).
"""

from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rwlab.testbed import read_record
from rwlab.wheel.link import protocol_names


def lost_commands(record_path: Path) -> int:
    """Commands whose sequence never came back in the telemetry's echo."""
    record = read_record(record_path)
    echoed = {t["sequence_echo"] for t in record.topic("/telemetry")}
    return sum(1 for c in record.topic("/command") if c["sequence"] not in echoed)


def run(protocol: str, duration: float, seed: int, out: Path) -> dict:
    rwlab = [sys.executable, "-m", "rwlab.cli"]
    record = out / f"{protocol.replace('/', '_')}.mcap"
    start = time.perf_counter()
    subprocess.run(
        [*rwlab, "experiment", "--protocol", protocol, "--duration", str(duration),
         "--seed", str(seed), "--out", str(record), "--force"],
        check=True, capture_output=True, text=True,
    )  # fmt: skip
    wall = time.perf_counter() - start
    study = out / f"ident-{protocol.replace('/', '_')}"
    subprocess.run(
        [*rwlab, "identify", str(record), "--out", str(study), "--force"],
        check=True, capture_output=True, text=True,
    )  # fmt: skip
    summary = json.loads((study / "study.json").read_text())
    rec = read_record(record)
    return {
        "protocol": protocol,
        "commands": len(rec.topic("/command")),
        "telemetry": len(rec.topic("/telemetry")),
        "lost_frames": _lost_frames(rec),
        "lost_commands": lost_commands(record),
        "wall_s": wall,
        "chosen": summary["chosen"]["structure"],
        "fit": summary["chosen"]["fit_percent"],
    }


def _lost_frames(rec) -> int:
    counters = [t["counter"] for t in rec.topic("/telemetry")]
    return sum((b - a - 1) % 256 for a, b in itertools.pairwise(counters))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=1200.0)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--only", nargs="*", help="These registered protocols only.")
    args = parser.parse_args()
    protocols = args.only or list(protocol_names())
    out = args.out or Path(tempfile.mkdtemp(prefix="rwlab-protocols-"))
    out.mkdir(parents=True, exist_ok=True)
    rows = [run(p, args.duration, args.seed, out) for p in protocols]
    ref = rows[0]["fit"]
    print(f"{args.duration:g} s PRBS, seed {args.seed}, simulated clock; records in {out}")
    print(
        f"{'protocol':<16} {'commands':>8} {'telemetry':>9} {'lost tel.':>9} {'lost cmd':>8} "
        f"{'wall s':>7}  {'chosen':<10} {'fit %':>7} {'Δfit':>6}"
    )
    for r in rows:
        print(
            f"{r['protocol']:<16} {r['commands']:>8} {r['telemetry']:>9} {r['lost_frames']:>9} "
            f"{r['lost_commands']:>8} {r['wall_s']:>7.1f}  {r['chosen']:<10} {r['fit']:>7.2f} "
            f"{r['fit'] - ref:>+6.2f}"
        )
    fits = [r["fit"] for r in rows]
    print(
        f"fit spread {max(fits) - min(fits):.3f} points (target ≤ 0.1); lost commands "
        f"{sum(r['lost_commands'] for r in rows)} (target 0)"
    )


if __name__ == "__main__":
    main()
