"""``rwlab compare``: MATLAB's compare for a saved wheel model on any record."""

from __future__ import annotations

import click

from rwlab.cli._common import _echo_json, _friendly_errors, main


@main.command("compare")
@click.argument("model_json", type=click.Path(dir_okay=False))
@click.argument("record")
@click.option("--Ts", "Ts", type=float, help="Sample time, s (a record's own by default).")
@click.option("--json", "as_json", is_flag=True, help="Print {model name: {fit_percent, ...}}.")
@_friendly_errors
def compare_cmd(model_json, record, Ts, as_json):
    """Simulated fit of every model MODEL_JSON holds on RECORD, the record's wheel
    saturations applied (speed, acceleration and current limits).

    MODEL_JSON is a model.json written by `rwlab identify`; RECORD a testbed
    record (.mcap) or a data file with command and speed columns.
    """
    from rwlab.ident.study import load_study_data
    from rwlab.wheel.compare import compare_wheel_models

    data, saturation = load_study_data(record, Ts)
    scores = compare_wheel_models(model_json, data, saturation)
    table = {k: {f: v for f, v in row.items() if f != "yhat"} for k, row in scores.items()}
    if as_json:
        _echo_json(table)
        return
    click.echo(f"{data!r}; simulated from its first speed, saturations: {saturation}")
    for name, row in table.items():
        fit = "—" if row["fit_percent"] is None else f"{row['fit_percent']:.2f} %"
        click.echo(f"{name:<8} {row['structure']:<10} fit {fit}")
