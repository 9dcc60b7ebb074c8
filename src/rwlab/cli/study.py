"""``rwlab identify`` and ``rwlab diagnose``: the identification study and fault diagnosis."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from rwlab.cli._common import (
    _check_folder,
    _columns_option,
    _engine_options,
    _friendly_errors,
    _message,
    main,
)
from rwlab.cli.attitude import _steps_progress
from rwlab.errors import ConfigError, RwlabError


@main.command("identify")
@click.argument("file")
@click.option("--out", type=click.Path(file_okay=False), required=True, help="Output folder.")
@click.option("--Ts", "Ts", type=float, help="Sample time, s (a record's own by default).")
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
    type=click.FloatRange(0, 1, min_open=True, max_open=True),
    default=0.7,
    show_default=True,
    help="Estimation share.",
)
@click.option(
    "--tolerance",
    type=click.FloatRange(min=0),
    default=3.0,
    show_default=True,
    help="Fit points within which the simplest model is chosen.",
)
@_engine_options
@click.option("--force", is_flag=True, help="Overwrite the outputs in --out.")
@_friendly_errors
def identify(
    file, out, Ts, input_col, output_col, preprocess, split, tolerance, workers, scheduler, force
):
    """Run paper A's whole identification study on a record or data file.

    Writes OUT/report.html (tables and figures, opens offline), OUT/study.json
    (every number) and OUT/model.json (the chosen model in physical units with
    the wheel's saturations, loadable by rwlab.wheel.IdentifiedWheel).

    FILE may be a folder of records (a wheel fleet's acceptance tests): each is
    studied in parallel on a Dask cluster (--workers, --scheduler), into
    OUT/<record name>/, with OUT/fleet.json and OUT/fleet.html summarising them.
    """
    _check_folder(out)
    options = dict(
        Ts=Ts,
        input_col=input_col,
        output_col=output_col,
        preprocess=preprocess,
        split=split,
        tolerance=tolerance,
        force=force,
    )
    if Path(file).is_dir():
        _identify_fleet(Path(file), Path(out), options, workers, scheduler, force)
        return
    if workers is not None or scheduler is not None:
        raise ConfigError("--workers and --scheduler apply to a folder of records")
    with click.progressbar(length=1, label="identification study", file=sys.stderr) as bar:

        def progress(done: int, total: int, label: str) -> None:
            bar.length = total
            bar.label = f"identification study: {label}"
            bar.update(1)

        study, paths = _identify_one(
            file, out, progress=progress, echo=lambda t: click.echo(t, err=True), **options
        )
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
            f"{nl['accel_limit_rpm_s']:.4g} (output unit)/s"
        )
    elif nl:
        click.echo(f"nonlinear servo: not fitted ({nl['error']})")
    click.echo(f"wrote {', '.join(str(p) for p in paths.values())}")


@main.command("diagnose")
@click.argument("record", type=click.Path(dir_okay=False))
@click.option(
    "--model", "model_file", type=click.Path(dir_okay=False), required=True, help="model.json."
)
@click.option("--out", type=click.Path(file_okay=False), required=True, help="Output folder.")
@click.option(
    "--calibration",
    "calibration_s",
    type=float,
    default=300.0,
    show_default=True,
    help="Healthy start of the record that calibrates the residuals, s.",
)
@click.option(
    "--false-alarms",
    "false_alarms_per_hour",
    type=click.FloatRange(0, min_open=True),
    default=1e-3,
    show_default=True,
    help="Wanted false alarms per hour per detector (sets the thresholds).",
)
@click.option("--speed-test", is_flag=True, help="Also test the speed residual (see docs).")
@click.option("--force", is_flag=True, help="Overwrite the outputs in --out.")
@_friendly_errors
def diagnose_cmd(record, model_file, out, calibration_s, false_alarms_per_hour, speed_test, force):
    """Detect and isolate wheel faults in a record with an identified model.

    Writes OUT/diagnosis.json (alarms, thresholds, residual statistics) and
    OUT/report.html (residuals and test statistics with the alarms marked).
    """
    import numpy as np

    from rwlab.diagnose import diagnose
    from rwlab.report.diagnosis import write_diagnosis
    from rwlab.testbed import load_record
    from rwlab.wheel import IdentifiedWheel

    _check_folder(out)
    wheel = IdentifiedWheel.from_json(model_file)
    data = load_record(record, wheel.Ts, outputs=("speed", "current", "age"), max_gap=np.inf)
    result = diagnose(
        data,
        wheel,
        calibration_s=calibration_s,
        false_alarms_per_hour=false_alarms_per_hour,
        speed_test=speed_test,
    )
    paths = write_diagnosis(result, out, title=Path(record).name, force=force)
    for a in result.alarms:
        click.echo(f"alarm at {a.t_s:.1f} s: {a.kind} ({a.detector} test, {a.statistic:.3g})")
    if not result.alarms:
        click.echo("no alarm")
    click.echo(f"wrote {', '.join(str(p) for p in paths.values())}")


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
    progress=None,
    echo=None,
):
    """`rwlab identify` on one record: the study written into ``out``; (study dict, paths)."""
    from rwlab.ident.study import (
        identification_study,
        load_current,
        load_study_data,
        physical_model,
    )
    from rwlab.report.identification import write_study

    data, saturation = load_study_data(file, Ts, input_col=input_col, output_col=output_col)
    if echo is not None:
        echo(f"data: {data!r}")
    result = identification_study(
        data,
        preprocess=preprocess,
        split=split,
        tolerance=tolerance,
        limits_rpm=(saturation["speed_limit_rpm"],) * 2,
        progress=progress,
        datasheet=None
        if "current_limit_a" not in saturation
        else {
            "current_limit": saturation["current_limit_a"],
            "max_speed_rpm": saturation["speed_limit_rpm"],
            "accel_limit_rpm_s": saturation["accel_limit_rpm_s"],
        },
        current=load_current(file, Ts),
    )
    model = physical_model(
        result,
        speed_limit_rpm=saturation["speed_limit_rpm"],
        accel_limit_rpm_s=saturation["accel_limit_rpm_s"],
        saturation_source=saturation["saturation_source"],
    )
    return result.to_dict(), write_study(result, model, out, force=force)


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
    from rwlab.report.attitude import check_outputs
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
    check_outputs(out, FLEET_FILES, force)
    for stem in stems:
        check_outputs(out / stem, ["report.html", "study.json", "model.json"], force)
    jobs = [[(str(p), str(out / p.stem))] for p in records]
    click.echo(f"identifying {len(records)} records on Dask...", err=True)
    with (
        dask_client(workers, scheduler) as client,
        _steps_progress(len(records), "fleet identification", unit="records") as progress,
    ):
        lines = map_batches(client, _identify_batch, jobs, options, progress=progress)
    paths = write_fleet(lines, out, force=force)
    for line in lines:
        fit = "" if line["fit_percent"] is None else f"{line['fit_percent']:8.2f}"
        click.echo(f"{line['record']:<32} {line['structure'] or 'failed':<12} {fit:>8}")
    click.echo(f"wrote {', '.join(str(p) for p in paths.values())}")
    failed = [line for line in lines if line["error"]]
    if failed:
        raise RwlabError(
            f"{len(failed)} of {len(lines)} records failed: "
            + "; ".join(f"{line['record']}: {line['error']}" for line in failed)
        )
