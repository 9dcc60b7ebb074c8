"""``rwlab identify`` and ``rwlab diagnose``: the identification study and fault diagnosis."""

from __future__ import annotations

import contextlib
import sys
import warnings
from pathlib import Path

import click

from rwlab.cli._common import (
    POSITIVE,
    Number,
    _check_folder,
    _columns_option,
    _engine_options,
    _friendly_errors,
    _output,
    _salvage_option,
    _steps_progress,
    _wrote,
    main,
)
from rwlab.cli.fdi import EXIT_ALARM, diagnose_fdi, diagnose_group, named_for_record
from rwlab.errors import ConfigError, NoModelFitsError, RwlabError, RwlabWarning


@main.command("identify")
@click.argument("file")
@click.option("--out", type=click.Path(file_okay=False), required=True, help="Output folder.")
@click.option("--Ts", "Ts", type=POSITIVE, help="Sample time, s (a record's own by default).")
@_columns_option
@click.option(
    "--preprocess",
    type=click.Choice(["detrend", "scale", "normalize", "none"]),
    default="detrend",
    show_default=True,
    help="Statistics from the estimation part: remove means (default), scale without "
    "shifting, or normalize to [0, 1] as paper A (biases a model without intercept).",
)
@click.option(
    "--split",
    type=Number(0, 1, low_open=True, high_open=True),
    default=0.7,
    show_default=True,
    help="Estimation share.",
)
@click.option(
    "--tolerance",
    type=Number(0, 100),
    default=3.0,
    show_default=True,
    help="Fit points within which the simplest model is chosen.",
)
@click.option(
    "--gaps",
    type=click.Choice(["refuse", "split"]),
    default="refuse",
    show_default=True,
    help="A record with telemetry gaps: refuse it, or split it at the gaps into segments "
    "identified as separate experiments merged (MATLAB merge(iddata); reported as segments).",
)
@click.option(
    "--gain-tolerance",
    type=Number(0, 100, low_open=True),
    default=2.0,
    show_default=True,
    help="Percent within which the chosen model's DC gain must match the steady-state gain "
    "measured on the record's settled holds (a record without them: fit alone).",
)
@click.option(
    "--nonlinear-models",
    is_flag=True,
    help="Also fit the grey-box wheel and the NLARX (about twice the study's time; the "
    "servo model is always fitted). rwlab compare scores them; without them the GLR "
    "diagnosis takes its loop gain from the servo model.",
)
@_engine_options
@click.option("--force", is_flag=True, help="Overwrite the outputs in --out.")
@_salvage_option
@_friendly_errors
def identify(file, out, workers, scheduler, force, **options):
    """Run paper A's whole identification study on a record or data file.

    Writes OUT/report.html (tables and figures, opens offline), OUT/study.json
    (every number) and OUT/model.json (the chosen model in physical units with
    the wheel's saturations, loadable by rwlab.wheel.IdentifiedWheel).

    FILE may be a folder of records (a wheel fleet's acceptance tests): each is
    studied in parallel on a Dask cluster (--workers, --scheduler), into
    OUT/<record name>/, with OUT/fleet.json and OUT/fleet.html summarising them.

    Exit status 0 when a model was chosen, 1 when the study was written but no
    model fits (even the best validation fit is negative: the report says what was
    tried), 2 on an error (nothing written).
    """
    from rwlab.report.identify import identify as run_study

    if Path(file).is_dir():
        _identify_fleet(Path(file), Path(out), options, workers, scheduler, force)
        return
    if workers is not None or scheduler is not None:
        raise ConfigError("--workers and --scheduler apply to a folder of records")
    _check_folder(Path(out).absolute().parent)
    with contextlib.ExitStack() as stack:
        bars: list = []

        def progress(done: int, total: int, label: str) -> None:
            if not bars:  # from the first stage on: a refused record prints only its error
                bar = click.progressbar(length=total, label="identification study", file=sys.stderr)
                bars.append(stack.enter_context(bar))
            bars[0].label = f"identification study: {label}"
            bars[0].update(1)

        echo = lambda t: click.echo(t, err=True)  # noqa: E731
        try:
            study, paths = run_study(
                file, out, force=force, progress=progress, echo=echo, **options
            )
            unfit = None
        except NoModelFitsError as exc:  # the study is written: show it, then exit 1
            study, paths, unfit = exc.study or {}, exc.paths or {}, exc
    if study.get("segments"):
        parts = ", ".join(f"{a:.1f}–{b:.1f} s" for a, b in study["segments"])
        click.echo(f"split at telemetry gaps into {len(study['segments'])} experiments: {parts}")
    click.echo(f"delay nk = {study['delay']['nk']}")
    click.echo(f"{'model':<12} {'fit %':>8} {'MSE':>11}")
    for row in study["orders"] + study["others"] + study.get("constrained", []):
        fit = "unstable" if row["fit_percent"] is None else f"{row['fit_percent']:8.2f}"
        mse = "" if row["mse"] is None else f"{row['mse']:11.4g}"
        click.echo(f"{row['structure']:<12} {fit:>8} {mse:>11}")
    from rwlab.report.model_choice import reason_clauses

    click.echo(f"chosen: {study['chosen']['structure']}, because:")
    for clause in reason_clauses(study["chosen"]["reason"]):  # one line each, not one sentence
        click.echo(f"  - {clause}")
    if (study.get("parts") or {}).get("note"):
        click.echo(f"estimation vs validation part: {study['parts']['note']}")
    nl = study["nonlinear"]
    if nl and "skipped" in nl:
        click.echo(f"wheel models: none ({nl['skipped']})")
    elif nl and "error" not in nl:
        click.echo(
            f"nonlinear servo: fit {nl['fit_percent']:.2f} %, rate limit "
            f"{nl['accel_limit_rpm_s']:.4g} {_rate_unit(study)}"
        )
    elif nl:
        click.echo(f"nonlinear servo: not fitted ({nl['error']})")
    for name in ("greybox", "nlarx"):
        row = (nl or {}).get(name) or {}
        if row.get("fit_percent") is not None:
            click.echo(f"{name}: validation fit {row['fit_percent']:.2f} %")
        elif row.get("failed") or row.get("error"):
            click.echo(f"{name}: failed ({row.get('failed') or row.get('error')})")
    if (nl or {}).get("not_fitted"):
        click.echo("grey box, NLARX: not fitted (--nonlinear-models fits them)")
    ref = study.get("healthy_reference") or {}
    if ref.get("stored"):
        click.echo(
            f"healthy reference for fault diagnosis stored in model.json ({ref['samples']} "
            f"samples): rwlab diagnose RECORD --model {Path(out) / 'model.json'} --out FOLDER"
        )
    click.echo(_wrote(out, paths.values()))
    if unfit is not None:
        click.echo(f"error: {' '.join(str(unfit).split())}", err=True)
        sys.exit(1)


def _rate_unit(study: dict) -> str:
    """The rate limit's unit: the output's unit per second (rpm/s for a wheel record)."""
    unit = (study.get("data") or {}).get("output_unit") or ""
    return f"{unit}/s" if unit else "(output unit)/s"


@diagnose_group.command("run")
@click.argument("record", type=click.Path(exists=True))
@click.option(
    "--model", "model_file", type=click.Path(dir_okay=False), required=True, help="model.json."
)
@click.option("--out", type=click.Path(file_okay=False), required=True, help="Output folder.")
@click.option(
    "--false-alarms",
    "false_alarms_per_hour",
    type=POSITIVE,
    default=1e-3,
    show_default=True,
    help="Wanted false alarms per hour per detector: thresholds from the rates measured on "
    "healthy records of other units; a rate a detector cannot deliver is a warning.",
)
@click.option(
    "--calibration",
    "calibration_file",
    type=click.Path(dir_okay=False, exists=True),
    help="A calibration.json from rwlab diagnose calibrate (the wheel's own healthy "
    "records); default: the shipped twin calibration of the model's wheel preset.",
)
@click.option(
    "--rules",
    is_flag=True,
    help="Run the rule detectors instead (thresholds measured on the RW90 twin's units; "
    "OUT/diagnosis.json).",
)
@click.option("--force", is_flag=True, help="Overwrite the outputs in --out.")
@_salvage_option
@_friendly_errors
def diagnose_cmd(
    record, model_file, out, false_alarms_per_hour, force, calibration_file=None, rules=False
):
    """Detect, name and size wheel faults in a record with an identified model.

    The GLR pipeline (rwlab.diagnose.pipeline) compares the record with the
    healthy reference that rwlab identify stored in model.json, its thresholds
    from --calibration (rwlab diagnose calibrate on the wheel's own healthy
    records) or, for a model of a wheel preset, the preset's shipped twin
    calibration. Writes OUT/fdi.json (the verdict, each alarm with the fault
    named, its size and 95 % interval and the runner-up, the thresholds with
    their measured rates) and OUT/report.html. Exit status 1 when any record
    raised an alarm, 0 when none did, 2 on an error.

    The verdict names the faults the record cannot tell from healthy: "no alarm"
    says nothing of them.

    RECORD may be a folder of records of one wheel: each is diagnosed into
    OUT/<record name>/, and OUT/trend.json and OUT/trend.html list the faults
    named in each (in the order of their start times). OUT appears whole or not
    at all.

    --rules runs the earlier rule detectors into OUT/diagnosis.json instead
    (their trend also follows each record's friction, torque-constant and bias
    estimates, alarm or not).
    """
    from rwlab.diagnose import HealthyReference
    from rwlab.wheel import IdentifiedWheel

    _check_folder(out)
    if rules and calibration_file is not None:
        raise click.UsageError("--rules takes no --calibration (its thresholds are its own)")
    if not rules:
        diagnose_fdi(Path(record), model_file, calibration_file, out, false_alarms_per_hour, force)
        return
    wheel = IdentifiedWheel.from_json(model_file)
    reference = HealthyReference.from_model_file(model_file)
    if Path(record).is_dir():
        results = _diagnose_folder(
            Path(record), Path(out), wheel, reference, false_alarms_per_hour, force
        )
    else:
        with _output(out, _DIAGNOSIS_FILES, force, "diagnosis") as stage:
            result, rec = _diagnose_one(
                Path(record), stage, wheel, reference, false_alarms_per_hour
            )
        for line in diagnosis_lines(result, rec.topic("/event")):
            click.echo(line)
        click.echo(_wrote(out, _DIAGNOSIS_FILES))
        results = [result]
    if any(r.alarms for r in results):
        sys.exit(EXIT_ALARM)


_DIAGNOSIS_FILES = ("diagnosis.json", "report.html")


def _finding_text(a) -> str:
    if a.magnitude is None:
        return a.kind
    ci = "" if a.ci is None else f" [{a.ci[0]:.4g}, {a.ci[1]:.4g}]"
    return f"{a.kind} {a.magnitude:.4g}{ci} {a.unit}"


def diagnosis_lines(result, events: list[dict]) -> list[str]:
    """The console's account of one diagnosis.

    Parameters
    ----------
    result : Diagnosis
        What :func:`rwlab.diagnose.diagnose` found.
    events : list of dict
        The record's events (``{"t", "kind", "message"}``).

    Returns
    -------
    list of str
        The alarms, what each test decided on (so "no alarm" can be told from
        "nothing tested"), the faults no test could see, and the faults the record
        says were injected.
    """
    lines = [
        f"alarm at {a.t_s:.1f} s: {_finding_text(a)} ({a.detector} test)" for a in result.alarms
    ]
    if not result.alarms:
        lines.append(
            "no alarm"
            if result.model_tested()
            else f"no alarm, but no model-based test had anything to decide on in "
            f"{result.duration_s:g} s: this says nothing of the wheel's health"
        )
    decided = [f"{n} {_count(c['decided'], c['unit'])}" for n, c in result.coverage.items()]
    decided = [d for d, c in zip(decided, result.coverage.values(), strict=True) if c["decided"]]
    lines.append("decided on: " + (", ".join(decided) or "nothing"))
    if result.untested():
        lines.append("nothing to decide on: " + ", ".join(result.untested()))
    if result.unseen():
        lines.append("not tested (no test could decide): " + ", ".join(result.unseen()))
    blind = result.blind()
    if blind:
        lines.append(
            f"blind after {min(blind.values()):.1f} s (the speed reading froze, every "
            f"model-based test reads it): {', '.join(blind)} not seen from then on"
        )
    if result.estimates:
        lines.append(
            "estimates against a healthy unit (95 % interval with the spread between units): "
            + _estimates_text(result.estimates, "ci95_units")
        )
    injected = [
        f"{e['message']} (at {e['t']:.1f} s)" for e in events if e["kind"] == "fault_injected"
    ]
    if injected:
        lines.append("injected (record's events): " + ", ".join(injected))
    return lines


def _estimates_text(estimates: dict[str, dict], interval: str | None = None) -> str:
    """``friction 1.02 [0.9, 1.15], speed_sensor_bias 0.3 [-2, 2.6] rpm``: each estimate,
    with its ``interval`` (a key of the estimate) when one is named."""

    def text(kind: str, e: dict) -> str:
        ci = f" [{e[interval][0]:.3g}, {e[interval][1]:.3g}]" if interval else ""
        unit = "" if e["unit"] == "factor" else " " + e["unit"]
        return f"{kind} {e['magnitude']:.3g}{ci}{unit}"

    return ", ".join(text(kind, e) for kind, e in estimates.items())


def _count(n: int, unit: str) -> str:
    """``1 block``, ``3 blocks``, ``1 10-s block``: the unit's first plural word singular."""
    if n != 1:
        return f"{n} {unit}"
    first, _, rest = unit.partition(" ")
    return f"1 {first.removesuffix('s')}{' ' + rest if rest else ''}"


def _diagnose_one(record: Path, into: Path, wheel, reference, false_alarms_per_hour):
    """Diagnose ``record`` into the folder ``into`` (a staging folder); the result and
    the record, decoded once (:func:`rwlab.testbed.read_record`). An error names the
    record."""
    import numpy as np

    from rwlab.diagnose import diagnose
    from rwlab.report.diagnosis import write_diagnosis
    from rwlab.testbed import load_record, read_record

    try:
        rec = read_record(record)
        data = load_record(
            rec, wheel.Ts, outputs=("speed", "current", "age", "lost"), max_gap=np.inf
        )
        result = diagnose(data, wheel, reference, false_alarms_per_hour=false_alarms_per_hour)
    except RwlabError as exc:
        if str(record) in str(exc) or record.name in str(exc):
            raise
        raise named_for_record(exc, record) from exc
    events = rec.topic("/event")
    truncated = None if rec.complete else f"the record is truncated ({rec.problem})"
    if rec.damage is not None:  # read_record said so already, on the console
        truncated = f"the record was salvaged: {rec.damage.text()}; diagnosed up to the damage"
    elif truncated:
        warnings.warn(
            f"{record}: {truncated}: diagnosed up to where it stops", RwlabWarning, stacklevel=2
        )
    into.mkdir(parents=True, exist_ok=True)
    write_diagnosis(result, into, title=record.name, events=events, record_note=truncated)
    return result, rec


def _diagnose_folder(folder: Path, out: Path, wheel, reference, rate, force) -> list:
    """Every record of ``folder`` diagnosed, and the trend of each fault's size; the
    folder appears whole or not at all (a record that fails leaves nothing, and is named).
    Returns each record's diagnosis."""
    from rwlab.report.diagnosis import trend_point, write_trend

    records = sorted(
        p for p in folder.iterdir() if p.suffix == ".mcap" and not p.name.endswith(".partial.mcap")
    )
    if not records:
        raise ConfigError(f"{folder}: no records (.mcap) in the folder")
    names = [p.stem for p in records] + ["trend.json", "trend.html"]
    lines: list[tuple[str, str]] = []  # (start time, console line)
    with _output(out, names, force, "diagnosis trend") as stage:
        points, results = [], []
        for path in records:
            result, rec = _diagnose_one(path, stage / path.stem, wheel, reference, rate)
            results.append(result)
            start = rec.metadata.get("start_utc", "")
            points.append(trend_point(path.name, start, result))
            named = ", ".join(f"{_finding_text(a)} ({a.detector})" for a in result.alarms) or (
                "no alarm" if result.model_tested() else "no alarm (nothing tested)"
            )
            sizes = _estimates_text(result.estimates)
            line = f"{path.name:<32} {named}" + (f"  (estimates: {sizes})" if sizes else "")
            lines.append((start, line))
        paths = write_trend(points, stage)
    for _, line in sorted(lines, key=lambda row: row[0]):  # start-time order, as the trend
        click.echo(line)
    click.echo(_wrote(out, paths.values()))
    return results


def _identify_fleet(folder: Path, out: Path, options, workers, scheduler, force) -> None:
    """`rwlab identify FOLDER`: :func:`rwlab.report.identify.identify_fleet`, and its lines."""
    from rwlab.report.identify import fleet_records, identify_fleet

    count = len(fleet_records(folder))
    _check_folder(out.absolute().parent)
    click.echo(f"identifying {count} records on Dask...", err=True)
    with _steps_progress(count, "fleet identification", unit="records") as progress:
        lines, paths = identify_fleet(
            folder,
            out,
            workers=workers,
            scheduler=scheduler,
            force=force,
            progress=progress,
            **options,
        )
    for line in lines:
        fit = "" if line["fit_percent"] is None else f"{line['fit_percent']:8.2f}"
        click.echo(f"{line['record']:<32} {line['structure'] or 'failed':<12} {fit:>8}")
    click.echo(_wrote(out, paths.values()))
    failed = [line for line in lines if line["error"]]
    if failed:
        raise RwlabError(
            f"{len(failed)} of {len(lines)} records failed: "
            + "; ".join(f"{line['record']}: {line['error']}" for line in failed)
        )
