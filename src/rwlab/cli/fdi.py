"""``rwlab diagnose calibrate`` and ``rwlab diagnose RECORD --calibration``: the GLR
pipeline (:mod:`rwlab.diagnose.pipeline`) from the command line."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import click

from rwlab.cli._common import _friendly_errors, _output, _wrote, main
from rwlab.errors import RwlabError, RwlabWarning

MIN_HOURS = 2.0  # issue 42: a lab calibrates on 2-4 h of its wheel's normal test signals

EXIT_ALARM = 1
"""``rwlab diagnose``'s exit status when a record raised an alarm (0: none; 2: an error),
as ``diff`` and ``grep`` tell a script what they found; the outputs are written either way."""


class _DiagnoseGroup(click.Group):
    """``rwlab diagnose RECORD ...`` runs the ``run`` subcommand; ``rwlab diagnose
    calibrate ...`` the calibration (a group whose default is its first command)."""

    def parse_args(self, ctx, args):
        if args and args[0] not in self.commands and args[0] not in ("--help", "-h"):
            args = ["run", *args]
        return super().parse_args(ctx, args)


@main.group("diagnose", cls=_DiagnoseGroup)
def diagnose_group():
    """Detect, name and size wheel faults: rwlab diagnose RECORD --model model.json --out
    FOLDER (the run command), or calibrate the detectors on a wheel's own healthy records:
    rwlab diagnose calibrate RECORDS... --model model.json --out calibration.json."""


def named_for_record(exc: RwlabError, record: Path) -> RwlabError:
    """The same error, its message naming the record."""
    try:
        return type(exc)(f"{record}: {exc}")
    except TypeError:  # an error class with another signature
        return RwlabError(f"{record}: {exc}")


def _fdi_features(record: Path, model_file):
    """A record's features for the GLR pipeline, an error naming the record."""
    import numpy as np

    from rwlab.diagnose.features import RECORD_OUTPUTS, WheelScales, compute_features
    from rwlab.testbed import load_record
    from rwlab.wheel import IdentifiedWheel

    scales = WheelScales.from_model_file(model_file)
    wheel = IdentifiedWheel.from_json(model_file)
    try:
        data = load_record(record, scales.Ts, outputs=RECORD_OUTPUTS, max_gap=np.inf)
        return compute_features(data, wheel, scales)
    except RwlabError as exc:
        if str(record) in str(exc) or record.name in str(exc):
            raise
        raise named_for_record(exc, record) from exc


def diagnose_fdi(record: Path, model_file, calibration_file, out, rate, force) -> None:
    """``rwlab diagnose RECORD --calibration FILE``: the GLR pipeline into OUT/fdi.json."""
    from rwlab._io import write_json
    from rwlab.diagnose.pipeline import run
    from rwlab.diagnose.wheel_calibration import DiagnosisCalibration
    from rwlab.report.fdi import fdi_page

    calibration = DiagnosisCalibration.load(calibration_file)
    result = run(_fdi_features(record, model_file), calibration, rate)
    files = ("fdi.json", "report.html")
    with _output(out, files, force, "diagnosis") as stage:
        write_json(stage / "fdi.json", result.to_dict(calibration_file))
        fdi_page(result, calibration, calibration_file, title=record.name).save(
            stage / "report.html"
        )
    click.echo(result.verdict())
    for e in result.events:
        runner = (
            ""
            if e.runner_up is None
            else f"; runner-up {e.runner_up}, ln LR {e.runner_up_log_lr:.3g}"
        )
        click.echo(f"alarm at {e.t_s:g} s: {e.fault} ({e.detector} crossed{runner})")
    click.echo(_wrote(out, files))
    if result.events:
        sys.exit(EXIT_ALARM)


@diagnose_group.command("calibrate")
@click.argument("records", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False))
@click.option(
    "--model",
    "model_file",
    type=click.Path(dir_okay=False),
    default=None,
    help="model.json (the bench's speed-mode records).",
)
@click.option(
    "--in-loop",
    is_flag=True,
    help="The records are healthy rwlab hil flights (record.mcap): every wheel of each, read "
    "as its pipeline reads it in flight, against the record's wheel model; use the file "
    "with rwlab hil --diagnosis-calibration.",
)
@click.option(
    "--out", type=click.Path(dir_okay=False), required=True, help="The calibration.json to write."
)
@click.option("--origin", default="", help="One line on whose wheel and which records.")
@_friendly_errors
def calibrate_cmd(records, model_file, in_loop, out, origin):
    """Measure the diagnosis's noise model, healthy zones and thresholds on a wheel's
    own healthy records (2-4 h of its normal test signals), each threshold with the
    false-alarm rate measured at it; use it with rwlab diagnose RECORD --calibration
    (or, --in-loop, with rwlab hil --diagnosis-calibration)."""
    from rwlab.diagnose.detectors import MODEL_BASED
    from rwlab.diagnose.wheel_calibration import DiagnosisCalibration

    quick = None
    if in_loop:
        from rwlab.hil.live import QUICK_S, flight_features

        wheels = {(r, n): f for r in records for n, f in flight_features(r).items()}
        features = list(wheels.values())
        names = [f"{r} node {n}" for r, n in wheels]
        quick = QUICK_S
    elif model_file is None:
        raise click.UsageError("--model is needed (or --in-loop for rwlab hil flights)")
    else:
        features = [_fdi_features(Path(r), model_file) for r in records]
        names = [Path(r).name for r in records]
    calibration = DiagnosisCalibration.measure(
        features, sources=names, origin=origin, quick_window_s=quick
    )
    if calibration.hours < MIN_HOURS:
        warnings.warn(
            f"{calibration.hours:.2g} h of healthy records: thresholds for rates under "
            f"{1 / calibration.hours:.2g}/h are extrapolated, and a unit's spread is thinly "
            f"sampled; calibrate on at least {MIN_HOURS:g} h of the wheel's normal test signals",
            RwlabWarning,
            stacklevel=2,
        )
    calibration.save(out)
    click.echo(f"{len(records)} records, {calibration.hours:.3g} h")
    for fault in (*MODEL_BASED, "speed_sensor_stuck"):
        t = calibration.threshold(fault, 1.0)
        lo, hi = t.ci95_per_hour
        click.echo(
            f"{fault}: at 1/h threshold {t.log_lr:.3g}, measured {t.measured_per_hour:.3g}/h "
            f"[{lo:.3g}, {hi:.3g}]{' (extrapolated)' if t.extrapolated else ''}"
        )
    click.echo(f"wrote {out}")


@diagnose_group.command("twin-calibration")
@click.option(
    "--model", "model_file", type=click.Path(dir_okay=False), required=True, help="model.json."
)
@click.option(
    "--out", type=click.Path(dir_okay=False), required=True, help="The calibration.json to write."
)
@_friendly_errors
def twin_calibration_cmd(model_file, out):
    """Write the package's twin-calibrated file for the model's wheel preset (measured on
    the twin's healthy records of that preset; its origin says which): a start before the
    lab's own rwlab diagnose calibrate. Use it with rwlab diagnose RECORD --calibration."""
    from rwlab._io import write_json
    from rwlab.diagnose.wheel_calibration import DiagnosisCalibration, twin_calibration_file
    from rwlab.errors import ConfigError
    from rwlab.ident.model_file import WheelModelFile

    spec = WheelModelFile.load(model_file).wheel_spec
    if spec is None:
        raise ConfigError(
            f"{model_file} carries no wheel spec (identified before the wheel models): "
            "identify again, or calibrate on the wheel's own healthy records"
        )
    calibration = DiagnosisCalibration.load(twin_calibration_file(spec.name))
    write_json(out, calibration.to_dict())
    click.echo(
        f"{spec.name}: {calibration.records} records, {calibration.hours:.3g} h "
        f"({calibration.origin})"
    )
    click.echo(f"wrote {out}")
