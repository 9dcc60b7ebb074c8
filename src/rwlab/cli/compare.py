"""``rwlab compare``: MATLAB's compare for a saved wheel model on any record."""

from __future__ import annotations

import click

from rwlab.cli._common import (
    POSITIVE,
    _columns_option,
    _echo_json,
    _friendly_errors,
    _salvage_option,
    main,
)


@main.command("compare")
@click.argument("model_json", type=click.Path(dir_okay=False))
@click.argument("record")
@click.option("--Ts", "Ts", type=POSITIVE, help="Sample time, s (a record's own by default).")
@_columns_option
@click.option(
    "--current-limit",
    type=POSITIVE,
    help="The record's wheel's driver current limit, A (default: the record's metadata, "
    "else the model file's).",
)
@click.option(
    "--speed-limit",
    type=POSITIVE,
    help="The record's wheel's speed limit, rpm (default: the record's, else the model file's).",
)
@click.option(
    "--accel-limit",
    type=POSITIVE,
    help="The record's wheel's acceleration limit, rpm/s (default: the record's, else the "
    "model file's).",
)
@click.option(
    "--json", "as_json", is_flag=True, help="Print {model name: {fit_percent, saturation, ...}}."
)
@_salvage_option
@_friendly_errors
def compare_cmd(
    model_json, record, Ts, input_col, output_col, current_limit, speed_limit, accel_limit, as_json
):
    """Simulated fit of every model MODEL_JSON holds on RECORD, the record's wheel
    saturations applied (speed, acceleration and current limits).

    MODEL_JSON is a model.json written by `rwlab identify`; RECORD a testbed
    record (.mcap) or a data file (an `rwlab export` file: its command and
    speed_rpm columns unless --input/--output choose others). Each saturation
    comes from the option, else the record's metadata, else the model file (for
    the current limit: the grey box's); a plain data file has no metadata, so
    give --current-limit for a wheel whose driver limits the current differently.
    """
    from rwlab.wheel.compare import compare_record

    given = {
        "current_limit_a": current_limit,
        "speed_limit_rpm": speed_limit,
        "accel_limit_rpm_s": accel_limit,
    }
    data, scores = compare_record(
        model_json, record, Ts=Ts, input_col=input_col, output_col=output_col, saturation=given
    )
    table = {k: {f: v for f, v in row.items() if f != "yhat"} for k, row in scores.items()}
    if as_json:
        _echo_json(table)
        return
    click.echo(f"{data!r}; simulated from its first speed")
    for name, row in table.items():
        fit = "—" if row["fit_percent"] is None else f"{row['fit_percent']:.2f} %"
        limits = "; ".join(
            f"{k} {v['value']:g} ({v['source']})" for k, v in row["saturation"].items()
        )
        click.echo(f"{name:<8} {row['structure']:<10} fit {fit}  {limits or 'no saturation'}")
