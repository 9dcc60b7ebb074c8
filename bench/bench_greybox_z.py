"""Are the grey-box wheel's standard deviations honest? (issue 22)

For each twin unit and seed: the default 20-minute PRBS (Ts = 0.5 s, steps) on the
simulated wheel, then the grey-box fit as ``rwlab identify`` runs it (the estimation
part's speed and current, the RW90 datasheet start values and the record's driver
limits). Printed per record and parameter: z = (estimate − the unit's true value)/σ,
with the unit's truth from its draw (``RW90.for_unit``):

- ``kt, τc, b``: the physical parameters, σ with J's datasheet tolerance;
- ``kt/J, τc/J, b/J``: the combinations the record identifies (J not needed);
- ``α, kp, ki``: the loop's rate limit and PI gains (firmware values, not drawn).

``--current-limit A`` runs units whose driver clamps the current at A (configured;
each unit's clamp is drawn within ±2 % of it): the clamp binds on the PRBS's large
steps, and the grey box estimates it (column ``imax``) when the current telemetry
shows it. ``--fixed-limit`` holds it at the configured value instead (its tolerance
then in σ).

``--calibrate`` prints the structure error from the records given, as the
``relative_error`` of a wheel model's entry in ``src/rwlab/ident/greybox_structure.json``
(put it there with this command line as its ``measurement``): run it on tuning records,
judge on others.

``--lags`` compares covariance choices: ``auto`` (Newey–West, Andrews' bandwidth: the
default), ``0`` (residuals taken as white: the sandwich alone) or a number of lags.
Breakaway is left out: the PRBS does not identify it (``unidentified``).

    python bench/bench_greybox_z.py --pairs 3:1 6:2 10:3 14:4 20:5 33:6
    python bench/bench_greybox_z.py --pairs n:0 1:7 2:3 --calibrate   # tuning records
    python bench/bench_greybox_z.py --pairs 3:1 --lags auto 0 --old
    python bench/bench_greybox_z.py --current-limit 0.35 --pairs 10:47 15:5
"""

from __future__ import annotations

import argparse
import tempfile
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from rwlab.ident.greybox import RPM, Uncertainty, greybox_fit
from rwlab.ident.study import DATASHEET, load_current, load_study_data
from rwlab.testbed import ExperimentConfig, run_experiment
from rwlab.wheel import RW90

COLUMNS = ("kt", "τc", "b", "kt/J", "τc/J", "b/J", "α", "kp", "ki", "imax")


def nominal(current_limit: float | None):
    """The RW90, its driver's current limit configured to ``current_limit`` (A) if given."""
    return RW90 if current_limit is None else replace(RW90, current_limit=current_limit)


def truth(unit: int | None, current_limit: float | None = None) -> dict:
    """The unit's true values, in the grey box's parameter names and SI units."""
    w = nominal(current_limit) if unit is None else nominal(current_limit).for_unit(unit)
    return {
        "kt": w.torque_constant,
        "τc": w.coulomb_friction,
        "b": w.viscous_friction,
        "kt/J": w.torque_constant / w.inertia,
        "τc/J": w.coulomb_friction / w.inertia,
        "b/J": w.viscous_friction / w.inertia,
        "α": w.max_accel_rpm_s * RPM,
        "kp": w.speed_kp,
        "ki": w.speed_ki,
        "imax": w.current_limit,
    }


def estimates(model) -> dict:
    """(value, σ) per column of a fitted grey box."""
    names = {"kt": "torque_constant", "τc": "coulomb", "b": "viscous"}
    out = {k: (getattr(model, v), model.std.get(v)) for k, v in names.items()}
    for k, v in names.items():
        r = (model.ratios or {}).get(f"{v}/inertia")
        out[f"{k}/J"] = (r["value"], r["std"]) if r else (getattr(model, v) / model.inertia, None)
    out["α"] = (model.accel_limit, model.std.get("accel_limit"))
    out["kp"] = (model.kp, model.std.get("kp"))
    out["ki"] = (model.ki, model.std.get("ki"))
    out["imax"] = (model.current_limit, model.std.get("current_limit"))
    return out


def record(unit: int | None, seed: int, folder: Path, current_limit: float | None = None):
    path = folder / f"u{unit}_s{seed}.mcap"
    params = None if current_limit is None else nominal(current_limit)
    run_experiment(ExperimentConfig(seed=seed, unit=unit), path, params=params, force=True)
    data, saturation = load_study_data(str(path))
    current = load_current(str(path))
    est = data.split(0.7)[0]
    sheet = {
        **DATASHEET,
        "current_limit": saturation["current_limit_a"],
        "max_speed_rpm": saturation["speed_limit_rpm"],
        "accel_limit_rpm_s": saturation["accel_limit_rpm_s"],
    }
    return est, current[: est.N], sheet


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", nargs="+", default=["3:1", "6:2", "10:3", "14:4", "20:5", "33:6"])
    ap.add_argument("--lags", nargs="+", default=["auto"], help="auto, or a number of lags")
    ap.add_argument(
        "--old",
        action="store_true",
        help="also the white sandwich alone (no lags, no J tolerance, no structure error)",
    )
    ap.add_argument(
        "--calibrate",
        action="store_true",
        help="print the RMS relative error of the J-free quantities: STRUCTURE_ERROR",
    )
    ap.add_argument(
        "--current-limit",
        type=float,
        default=None,
        help="the driver's configured current limit, A (default: the RW90's 0.7 A)",
    )
    ap.add_argument(
        "--fixed-limit",
        action="store_true",
        help="hold the current limit at its configured value (tolerance in σ)",
    )
    args = ap.parse_args()
    pairs = [(None if a == "n" else int(a), int(b)) for a, b in (p.split(":") for p in args.pairs)]
    limit = "RW90 0.7 A" if args.current_limit is None else f"{args.current_limit} A"
    print(f"z = (estimate − the unit's truth)/σ; 20-min default PRBS, Ts = 0.5 s; limit {limit}")
    print(f"{'unit':>4} {'seed':>4} {'σ':>10} {'lags':>5} " + " ".join(f"{c:>7}" for c in COLUMNS))
    zs: dict[str, dict] = {}
    errors: dict[str, list] = {}
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for unit, seed in pairs:
            est, current, sheet = record(unit, seed, Path(tmp), args.current_limit)
            true = truth(unit, args.current_limit)
            fix = False if args.fixed_limit else None
            choices = [(lag, 0.02) for lag in args.lags] + ([("white", 0.0)] if args.old else [])
            for lag, tol in choices:
                lags = None if lag == "auto" else 0 if lag == "white" else int(lag)
                shape = {} if lag == "white" else None
                m = greybox_fit(
                    est,
                    current=current,
                    uncertainty=Uncertainty(tol, lags, shape),
                    estimate_current_limit=fix,
                    **sheet,
                )
                label = "white only" if lag == "white" else f"lags {lag}"
                row, rel = [], []
                for c, (value, sd) in estimates(m).items():
                    z = np.nan if not sd else (value - true[c]) / sd
                    zs.setdefault(label, {}).setdefault(c, []).append(z)
                    row.append(f"{z:7.2f}")
                    rel.append(f"{100 * (value / true[c] - 1):+6.2f}%")
                    errors.setdefault(c, []).append(value / true[c] - 1)
                used = m.std_method.split(" with ")[1].split(" lags")[0]
                name = "-" if unit is None else unit
                print(f"{name:>4} {seed:>4} {label:>10} {used:>5} " + " ".join(row), flush=True)
                print(f"{'':>4} {'':>4} {'error':>10} {'':>5} " + " ".join(rel), flush=True)
    print("\nper choice: share of |z| < 3 over every record and parameter, and max |z|")
    for label, cols in zs.items():
        z = np.abs(np.concatenate([np.asarray(v) for v in cols.values()]))
        z = z[np.isfinite(z)]
        worst = {  # a column held on every record (α behind a binding clamp) has none
            c: float(np.nanmax(np.abs(v))) if np.isfinite(v).any() else np.nan
            for c, v in ((c, np.asarray(v, dtype=float)) for c, v in cols.items())
        }
        print(
            f"{label:>12}: {np.mean(z < 3):.0%} of {z.size} below 3, max "
            + ", ".join(f"{c} {v:.1f}" for c, v in worst.items())
        )
    if args.calibrate:
        calibration(errors, clamp=args.current_limit is not None and not args.fixed_limit)


def calibration(errors: dict, clamp: bool = False) -> None:
    """STRUCTURE_ERROR: RMS relative error of the J-free quantities over the records."""
    names = {"kt/J": "torque_constant", "τc/J": "coulomb", "b/J": "viscous", "α": "accel_limit"}
    names |= {"kp": "kp", "ki": "ki"}
    rms = {v: float(np.sqrt(np.mean(np.square(errors[k])))) for k, v in names.items()}
    rms["breakaway"] = rms["coulomb"]  # the same bearing, the same drift
    if clamp:
        rms["current_limit"] = float(np.sqrt(np.mean(np.square(errors["imax"]))))
    body = ", ".join(f'"{k}": {v:.4f}' for k, v in rms.items())
    print('\ngreybox_structure.json, this wheel model\'s "relative_error": {' + body + "}")


if __name__ == "__main__":
    main()
