"""``rwlab identify`` and ``rwlab diagnose``: the identification study and fault diagnosis."""

from __future__ import annotations

import contextlib
import dataclasses
import sys
from pathlib import Path

import click

from rwlab.cli._common import (
    POSITIVE,
    Number,
    _check_folder,
    _columns_option,
    _engine_options,
    _friendly_errors,
    _message,
    _output,
    _wrote,
    main,
)
from rwlab.cli.attitude import _steps_progress
from rwlab.errors import ConfigError, RwlabError


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
@_engine_options
@click.option("--force", is_flag=True, help="Overwrite the outputs in --out.")
@_friendly_errors
def identify(
    file,
    out,
    Ts,
    input_col,
    output_col,
    preprocess,
    split,
    tolerance,
    gaps,
    gain_tolerance,
    workers,
    scheduler,
    force,
):
    """Run paper A's whole identification study on a record or data file.

    Writes OUT/report.html (tables and figures, opens offline), OUT/study.json
    (every number) and OUT/model.json (the chosen model in physical units with
    the wheel's saturations, loadable by rwlab.wheel.IdentifiedWheel).

    FILE may be a folder of records (a wheel fleet's acceptance tests): each is
    studied in parallel on a Dask cluster (--workers, --scheduler), into
    OUT/<record name>/, with OUT/fleet.json and OUT/fleet.html summarising them.
    """
    options = dict(
        Ts=Ts,
        input_col=input_col,
        output_col=output_col,
        preprocess=preprocess,
        split=split,
        tolerance=tolerance,
        gaps=gaps,
        gain_tolerance=gain_tolerance,
        force=force,
    )
    if Path(file).is_dir():
        _identify_fleet(Path(file), Path(out), options, workers, scheduler, force)
        return
    if workers is not None or scheduler is not None:
        raise ConfigError("--workers and --scheduler apply to a folder of records")
    with (
        _output(out, STUDY_FILES, force, "identification study") as stage,
        contextlib.ExitStack() as stack,
    ):
        bars: list = []

        def progress(done: int, total: int, label: str) -> None:
            if not bars:  # from the first stage on: a refused record prints only its error
                bar = click.progressbar(length=total, label="identification study", file=sys.stderr)
                bars.append(stack.enter_context(bar))
            bars[0].label = f"identification study: {label}"
            bars[0].update(1)

        study, paths = _identify_one(
            file, stage, progress=progress, echo=lambda t: click.echo(t, err=True), **options
        )
    if study.get("segments"):
        parts = ", ".join(f"{a:.1f}–{b:.1f} s" for a, b in study["segments"])
        click.echo(f"split at telemetry gaps into {len(study['segments'])} experiments: {parts}")
    click.echo(f"delay nk = {study['delay']['nk']}")
    click.echo(f"{'model':<12} {'fit %':>8} {'MSE':>11}")
    for row in study["orders"] + study["others"]:
        fit = "unstable" if row["fit_percent"] is None else f"{row['fit_percent']:8.2f}"
        mse = "" if row["mse"] is None else f"{row['mse']:11.4g}"
        click.echo(f"{row['structure']:<12} {fit:>8} {mse:>11}")
    click.echo(f"chosen: {study['chosen']['reason']}")
    nl = study["nonlinear"]
    if nl and "error" not in nl:
        click.echo(
            f"nonlinear servo: fit {nl['fit_percent']:.2f} %, rate limit "
            f"{nl['accel_limit_rpm_s']:.4g} {_rate_unit(study)}"
        )
    elif nl:
        click.echo(f"nonlinear servo: not fitted ({nl['error']})")
    click.echo(_wrote(out, paths.values()))


STUDY_FILES = ("report.html", "study.json", "model.json")


def _rate_unit(study: dict) -> str:
    """The rate limit's unit: the output's unit per second (rpm/s for a wheel record)."""
    unit = (study.get("data") or {}).get("output_unit") or ""
    return f"{unit}/s" if unit else "(output unit)/s"


@main.command("diagnose")
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
@click.option("--force", is_flag=True, help="Overwrite the outputs in --out.")
@_friendly_errors
def diagnose_cmd(record, model_file, out, false_alarms_per_hour, force):
    """Detect, name and size wheel faults in a record with an identified model.

    The detectors compare the record, from its first sample, with the healthy
    reference that rwlab identify stored in model.json. Writes
    OUT/diagnosis.json (alarms with fault sizes and 95 % intervals, thresholds,
    residual statistics) and OUT/report.html.

    RECORD may be a folder of records of one wheel: each is diagnosed into
    OUT/<record name>/, and OUT/trend.json and OUT/trend.html follow each
    fault's size over the records (in the order of their start times).
    """
    from rwlab.diagnose import HealthyReference
    from rwlab.wheel import IdentifiedWheel

    _check_folder(out)
    wheel = IdentifiedWheel.from_json(model_file)
    reference = HealthyReference.from_model_file(model_file)
    if Path(record).is_dir():
        _diagnose_folder(Path(record), Path(out), wheel, reference, false_alarms_per_hour, force)
        return
    result, paths = _diagnose_one(record, out, wheel, reference, false_alarms_per_hour, force)
    for a in result.alarms:
        click.echo(f"alarm at {a.t_s:.1f} s: {_finding_text(a)} ({a.detector} test)")
    if not result.alarms:
        click.echo("no alarm")
    click.echo(_wrote(out, paths.values()))


def _finding_text(a) -> str:
    if a.magnitude is None:
        return a.kind
    ci = "" if a.ci is None else f" [{a.ci[0]:.4g}, {a.ci[1]:.4g}]"
    return f"{a.kind} {a.magnitude:.4g}{ci} {a.unit}"


def _diagnose_one(record, out, wheel, reference, false_alarms_per_hour, force):
    import numpy as np

    from rwlab.diagnose import diagnose
    from rwlab.report.diagnosis import write_diagnosis
    from rwlab.testbed import load_record

    with _output(out, ("diagnosis.json", "report.html"), force, "diagnosis") as stage:
        data = load_record(
            record, wheel.Ts, outputs=("speed", "current", "age", "lost"), max_gap=np.inf
        )
        result = diagnose(data, wheel, reference, false_alarms_per_hour=false_alarms_per_hour)
        paths = write_diagnosis(result, stage, title=Path(record).name, force=force)
    return result, paths


def _diagnose_folder(folder: Path, out: Path, wheel, reference, rate, force) -> None:
    """Every record of ``folder`` diagnosed, and the trend of each fault's size."""
    from rwlab.report.diagnosis import trend_point, write_trend
    from rwlab.testbed import read_record

    records = sorted(
        p for p in folder.iterdir() if p.suffix == ".mcap" and not p.name.endswith(".partial.mcap")
    )
    if not records:
        raise ConfigError(f"{folder}: no records (.mcap) in the folder")
    points = []
    for path in records:
        result, _ = _diagnose_one(path, out / path.stem, wheel, reference, rate, force)
        start = read_record(path).metadata.get("start_utc", "")
        points.append(trend_point(path.name, start, result))
        named = ", ".join(_finding_text(a) for a in result.alarms) or "no alarm"
        click.echo(f"{path.name:<32} {named}")
    paths = write_trend(points, out, force=force)
    click.echo(_wrote(out, paths.values()))


def _identify_one(
    file,
    out,
    *,
    Ts,
    input_col,
    output_col,
    preprocess,
    split,
    tolerance,
    force,
    gaps="refuse",
    gain_tolerance=2.0,
    progress=None,
    echo=None,
):
    """`rwlab identify` on one record: the study written into ``out``; (study dict, paths)."""
    from rwlab.ident.study import (
        identification_study,
        load_current,
        load_study_data,
        wheel_model,
    )
    from rwlab.report.identification import write_study

    data, saturation = load_study_data(
        file, Ts, input_col=input_col, output_col=output_col, gaps=gaps
    )
    segments = None
    if gaps == "split" and Path(file).suffix.lower() == ".mcap":
        from rwlab.testbed.load import gap_free_segments

        segments = gap_free_segments(file, data.Ts)
    if echo is not None:
        echo(f"data: {data!r}")
    result = identification_study(
        data,
        preprocess=preprocess,
        split=split,
        tolerance=tolerance,
        gain_tolerance=gain_tolerance / 100.0,
        limits_rpm=(saturation["speed_limit_rpm"],) * 2,
        progress=progress,
        datasheet=None
        if "current_limit_a" not in saturation
        else {
            "current_limit": saturation["current_limit_a"],
            "max_speed_rpm": saturation["speed_limit_rpm"],
            "accel_limit_rpm_s": saturation["accel_limit_rpm_s"],
        },
        current=load_current(file, Ts, gaps=gaps),
        segments=segments,
    )
    model = wheel_model(  # the owner class: the healthy reference is added below
        result,
        speed_limit_rpm=saturation["speed_limit_rpm"],
        accel_limit_rpm_s=saturation["accel_limit_rpm_s"],
        saturation_source=saturation["saturation_source"],
    )
    reference = _healthy_reference(file, model)
    if isinstance(reference, dict):
        model = dataclasses.replace(model, healthy_reference=reference)
    elif echo is not None:
        echo(f"no healthy reference for fault diagnosis: {reference}")
    paths = write_study(result, model, out, force=force)
    study = result.to_dict()
    study["data"]["output_unit"] = data.output_units[0]  # for the messages only
    return study, paths


def _healthy_reference(file, model) -> dict | str:
    """The healthy reference measured on a testbed record, or why there is none."""
    import numpy as np

    from rwlab.diagnose import healthy_reference
    from rwlab.testbed import load_record
    from rwlab.wheel import IdentifiedWheel

    if Path(file).suffix.lower() != ".mcap":
        return "not a testbed record (.mcap with motor current)"
    try:
        wheel = IdentifiedWheel.from_file(model)
        data = load_record(
            file, wheel.Ts, outputs=("speed", "current", "age", "lost"), max_gap=np.inf
        )
        return healthy_reference(data, wheel, source=Path(file).name).to_dict()
    except RwlabError as exc:
        return _message(exc)


_RECORD_SUFFIXES = (".mcap", ".csv", ".parquet", ".mat", ".dat", ".txt")


def _identify_batch(jobs: list[tuple[str, str]], options: dict) -> list[dict]:
    """One fleet line per (record, study folder): its chosen model, or why it failed."""
    lines = []
    for record, out in jobs:
        line = {"record": Path(record).name, "study": Path(out).name, "error": None}
        line |= {"nk": None, "structure": None, "fit_percent": None}
        try:
            study, _ = _identify_one(record, out, **options)
        except (RwlabError, OSError) as exc:
            line["error"] = _message(exc)
        else:
            chosen = study["chosen"]
            line |= {
                "nk": study["delay"]["nk"],
                "structure": chosen["structure"],
                "fit_percent": chosen["fit_percent"],
            }
        lines.append(line)
    return lines


def _identify_fleet(folder: Path, out: Path, options, workers, scheduler, force) -> None:
    """`rwlab identify FOLDER`: every record's study on the Dask engine, and a fleet summary."""
    from rwlab.campaign.engine import dask_client, map_batches
    from rwlab.report.campaign import FLEET_FILES, write_fleet

    records = sorted(
        p
        for p in folder.iterdir()
        if p.is_file()
        and p.suffix.lower() in _RECORD_SUFFIXES
        and not p.name.endswith(".partial.mcap")
    )
    if not records:
        raise ConfigError(f"{folder}: no records ({', '.join(_RECORD_SUFFIXES)}) in the folder")
    stems = [p.stem for p in records]
    twins = sorted({s for s in stems if stems.count(s) > 1})
    if twins:
        raise ConfigError(f"{folder}: records {twins} share a name; their studies would collide")
    with _output(out, [*FLEET_FILES, *stems], force, "fleet identification") as stage:
        jobs = [[(str(p), str(stage / p.stem))] for p in records]
        click.echo(f"identifying {len(records)} records on Dask...", err=True)
        with (
            dask_client(workers, scheduler) as client,
            _steps_progress(len(records), "fleet identification", unit="records") as progress,
        ):
            lines = map_batches(client, _identify_batch, jobs, options, progress=progress)
        paths = write_fleet(lines, stage, force=force)
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
