"""``rwlab diagnose calibrate`` and ``rwlab diagnose RECORD --calibration``: the GLR
pipeline (:mod:`rwlab.diagnose.pipeline`) from the command line."""

from __future__ import annotations

import math
import sys
import warnings
from pathlib import Path

import click

from rwlab.cli._common import _friendly_errors, _output, _wrote, main
from rwlab.errors import ConfigError, DataError, RwlabError, RwlabWarning

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


def _fdi_features(record: Path, wheel, scales, spec=None):
    """A record's features for the GLR pipeline and the record (decoded once,
    :func:`rwlab.testbed.read_record`), an error naming the record; a record of another
    wheel than the model's ``spec`` (where both say) is refused."""
    import numpy as np

    from rwlab.diagnose.features import RECORD_OUTPUTS, compute_features
    from rwlab.testbed import load_record, read_record
    from rwlab.wheelspec import WheelSpec

    try:
        rec = read_record(record)
        own = rec.metadata.get("wheel_spec")
        if spec is not None and isinstance(own, dict) and WheelSpec.from_dict(own) != spec:
            raise DataError(
                f"a record of the wheel {own.get('name')!r} and a model of {spec.name!r} "
                "(another spec): diagnose a wheel's records with a model identified on that "
                "wheel (rwlab identify on one of its healthy records)"
            )
        data = load_record(rec, scales.Ts, outputs=RECORD_OUTPUTS, max_gap=np.inf)
        if data.input_units and data.input_units[0] == "rpm/s":
            raise DataError(
                "an acceleration-mode record: rwlab diagnose reads speed-mode test records "
                "against model.json; record the test in speed mode (rwlab hil diagnoses its "
                "acceleration-mode wheels in flight)"
            )
        return compute_features(data, wheel, scales), rec
    except RwlabError as exc:
        if str(record) in str(exc) or record.name in str(exc):
            raise
        raise named_for_record(exc, record) from exc


def _model(model_file):
    """The identified wheel, its scales and its wheel spec (or None) from ``model.json``
    (its errors first)."""
    from rwlab.diagnose.features import WheelScales
    from rwlab.ident.model_file import WheelModelFile
    from rwlab.wheel import IdentifiedWheel

    wheel = IdentifiedWheel.from_json(model_file)
    scales = WheelScales.from_model_file(model_file)
    return wheel, scales, WheelModelFile.load(model_file).wheel_spec


def _alarm_line(e) -> str:
    """An alarm's console line: the fault named at the alarm and its size then (and what
    re-labelled it), the detector that crossed, the runner-up at the alarm."""
    runner = "" if e.runner_up is None else f"; runner-up {e.runner_up}"
    if e.runner_up_log_lr is not None:
        runner += f", ln LR {e.runner_up_log_lr:.3g}"
    named = f"{e.first} {e.at_alarm.size_text()}".rstrip()
    if e.relabelled:
        named += f", re-labelled {e.fault} at {e.relabelled[-1][0]:g} s"
    return f"alarm at {e.t_s:g} s: {named} ({e.detector} crossed{runner})"


def _diagnose_one(record: Path, into: Path, model, calibration, calibration_file, rate):
    """One record through the pipeline into the folder ``into`` (fdi.json, report.html);
    the result and the record."""
    from rwlab._io import write_json
    from rwlab.diagnose.pipeline import run
    from rwlab.report.fdi import fdi_page

    features, rec = _fdi_features(record, *model)
    note = None if rec.complete else f"the record is truncated ({rec.problem})"
    if rec.damage is not None:  # read_record said so already, on the console
        note = f"the record was salvaged: {rec.damage.text()}; diagnosed up to the damage"
    elif note:
        warnings.warn(f"{record}: {note}: diagnosed up to where it stops", RwlabWarning, 2)
    result = run(features, calibration, rate)
    into.mkdir(parents=True, exist_ok=True)
    write_json(into / "fdi.json", result.to_dict(str(calibration_file)))
    page = fdi_page(
        result,
        calibration,
        calibration_file,
        title=record.name,
        record_note=note,
        features=features,
    )
    page.save(into / "report.html")
    return result, rec


def diagnose_fdi(record: Path, model_file, calibration_file, out, rate, force) -> None:
    """``rwlab diagnose RECORD``: the GLR pipeline into OUT/fdi.json and OUT/report.html
    (with ``calibration_file`` None, the model's preset's:
    :func:`rwlab.diagnose.wheel_calibration.model_calibration_file`);
    a folder of records into OUT/<record>/ each, and their trend."""
    from rwlab.report.diagnosis import write_trend

    records = [record]
    if record.is_dir():
        records = sorted(
            p
            for p in record.iterdir()
            if p.suffix == ".mcap" and not p.name.endswith(".partial.mcap")
        )
        if not records:
            raise ConfigError(f"{record}: no records (.mcap) in the folder")
        files = [p.stem for p in records] + ["trend.json", "trend.html"]
    else:
        files = ["fdi.json", "report.html"]
    lines, points, results = [], [], []
    with _output(out, files, force, "diagnosis") as stage:  # the lock before any work
        model = _model(model_file)
        calibration, calibration_file = _calibration(calibration_file, model_file)
        for path in records:
            into = stage / path.stem if record.is_dir() else stage
            result, rec = _diagnose_one(path, into, model, calibration, calibration_file, rate)
            start = rec.metadata.get("start_utc", "")
            results.append(result)
            points.append(_trend_point(path.name, start, result))
            lines.append((start, f"{path.name:<32} {result.verdict()}"))
        if record.is_dir():
            files = list(write_trend(points, stage))
    if record.is_dir():
        for _, line in sorted(lines, key=lambda row: row[0]):  # start-time order, as the trend
            click.echo(line)
    else:
        click.echo(results[0].verdict())
        for e in results[0].events:
            click.echo(_alarm_line(e))
    click.echo(_wrote(out, files))
    if any(r.events for r in results):
        sys.exit(EXIT_ALARM)


def _calibration(calibration_file, model_file):
    """The calibration given, else the model's preset's; and its path."""
    from rwlab.diagnose.wheel_calibration import DiagnosisCalibration, model_calibration_file

    path = calibration_file or model_calibration_file(model_file)
    return DiagnosisCalibration.load(path), path


def _trend_point(record: str, start_utc: str, result) -> dict:
    """One record's line of the trend (:func:`rwlab.report.diagnosis.write_trend`)."""
    faults = {
        e.fault: {
            "magnitude": e.fit.size,
            "unit": e.fit.unit,
            "ci95": list(e.fit.ci95),
            "t_s": e.t_s,
        }
        for e in result.events
        if result.confirmed(e) and not math.isnan(e.fit.size)  # a frozen reading has no size
    }
    return {"record": record, "start_utc": start_utc, "faults": faults, "estimates": {}}


def _healthy(record: Path, features, rec):
    """A calibration record's features; refused where the record says a fault was
    injected (a calibration on it would take the fault for the wheel's health)."""
    injected = [e["message"] for e in rec.topic("/event") if e["kind"] == "fault_injected"]
    if injected:
        raise DataError(
            f"{record}: a fault was injected ({', '.join(injected)}): calibrate on the "
            "wheel's healthy records only"
        )
    return features


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
@click.option("--force", is_flag=True, help="Overwrite --out if it exists.")
@_friendly_errors
def calibrate_cmd(records, model_file, in_loop, out, origin, force):
    """Measure the diagnosis's noise model, healthy zones and thresholds on a wheel's
    own healthy records (2-4 h of its normal test signals), each threshold with the
    false-alarm rate measured at it; use it with rwlab diagnose RECORD --calibration
    (or, --in-loop, with rwlab hil --diagnosis-calibration)."""
    from rwlab.diagnose.detectors import MODEL_BASED
    from rwlab.diagnose.wheel_calibration import DiagnosisCalibration

    if Path(out).exists() and not force:
        raise FileExistsError(f"{out} exists; pass --force to overwrite it")
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
        model = _model(model_file)
        features = [_healthy(Path(r), *_fdi_features(Path(r), *model)) for r in records]
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
        default = calibration.threshold(fault, 1e-3)  # rwlab diagnose's --false-alarms
        click.echo(
            f"{fault}: at 1/h threshold {t.log_lr:.3g}, measured {t.measured_per_hour:.3g}/h "
            f"[{lo:.3g}, {hi:.3g}]{' (extrapolated)' if t.extrapolated else ''}; at the "
            f"default 1e-3/h {default.log_lr:.3g}"
            + (" (extrapolated)" if default.extrapolated else "")
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
