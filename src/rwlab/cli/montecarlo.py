"""``rwlab attitude montecarlo``: a Monte Carlo pointing campaign and its budget, verdict first."""

from __future__ import annotations

from pathlib import Path

import click

from rwlab.cli._common import (
    SECONDS,
    Number,
    _check_folder,
    _engine_options,
    _flags,
    _friendly_errors,
    _steps_progress,
    _wrote,
)
from rwlab.cli.attitude import EPOCH_OPTION, attitude, check_run

#: The requirement's options → PointingRequirement's fields.
REQUIREMENT_FIELDS = {
    "requirement": "ape_deg",
    "rpe_requirement": "rpe_deg",
    "rpe_window": "rpe_window_s",
    "probability": "probability",
    "confidence": "confidence",
    "interpretation": "interpretation",
    "drift_window": "drift_window_s",
    "drift_separation": "drift_separation_s",
}


def requirement_options(func):
    """The requirement the budget checks, its statistical interpretation and its windows."""
    options = [
        click.option(
            "--requirement",
            type=Number(0, 180, low_open=True),
            default=None,
            help="APE bound on the total error, degrees [default: the scenario's].",
        ),
        click.option(
            "--probability",
            type=Number(0, 1, low_open=True, high_open=True),
            default=0.95,
            show_default=True,
            help="P_C: the share of runs, of time, or of both that must meet it.",
        ),
        click.option(
            "--confidence",
            type=Number(0, 1, low_open=True, high_open=True),
            default=0.95,
            show_default=True,
            help="Confidence level of every bound.",
        ),
        click.option(
            "--interpretation",
            type=click.Choice(["ensemble", "temporal", "mixed"]),
            default="ensemble",
            show_default=True,
            help="ECSS-E-ST-60-10C statistical interpretation of the verdict.",
        ),
        click.option(
            "--rpe-requirement",
            type=Number(0, 180, low_open=True),
            default=None,
            help="RPE bound per axis, degrees [default: reported, no verdict].",
        ),
        click.option(
            "--rpe-window",
            type=SECONDS,
            default=60.0,
            show_default=True,
            help="The RPE's window, s.",
        ),
        click.option(
            "--drift-window",
            type=SECONDS,
            default=600.0,
            show_default=True,
            help="PDE/KDE averaging window, s.",
        ),
        click.option(
            "--drift-separation",
            type=SECONDS,
            default=3600.0,
            show_default=True,
            help="Time between the PDE/KDE windows, s.",
        ),
    ]
    for option in reversed(options):
        func = option(func)
    return func


@attitude.command("montecarlo")
@click.option("--scenario", default="geo-comsat", show_default=True)
@click.option("--runs", type=click.IntRange(min=1), required=True, help="Number of runs.")
@click.option("--duration", type=SECONDS, required=True, help="Seconds per run.")
@click.option(
    "--controller",
    type=click.Choice(["pd", "lqr", "lqg", "lqg_ltr"]),
    default="lqg",
    show_default=True,
)
@click.option(
    "--dispersions",
    type=click.Path(dir_okay=False),
    help="Dispersion TOML file [default: rwlab's GEO set].",
)
@_engine_options
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@EPOCH_OPTION
@click.option(
    "--epoch-spread-days",
    type=float,
    default=0.0,
    show_default=True,
    help="Each run starts at --epoch plus a uniform draw of up to this many days "
    "(e.g. 30 for an eclipse season, 365 for a year).",
)
@click.option(
    "--steady-after",
    type=Number(0, 1e9),
    default=None,
    help="Seconds from which the budget counts (t ≥ this) [default: half the run, at most "
    "its first hour].",
)
@click.option(
    "--start",
    type=click.Choice(["acquisition", "converged"]),
    default="acquisition",
    show_default=True,
    help="converged: every run starts on target at the orbital rate with the filter's "
    "attitude at the truth (gyro bias and disturbance estimates still converge).",
)
@requirement_options
@click.option("--out", type=click.Path(file_okay=False), required=True)
@click.option("--force", is_flag=True, help="Overwrite outputs in --out (and start over).")
@click.option(
    "--resume",
    is_flag=True,
    help="Continue the interrupted campaign kept in OUT.partial (same options).",
)
@_friendly_errors
def attitude_montecarlo(out, force, resume, workers, scheduler, **options):
    """A Monte Carlo campaign on Dask: results.parquet, budget.json, report.html.

    Every run flies the controller (designed on the nominal scenario) on a
    scenario dispersed from its own seed, a child of --seed: a run is the same
    whatever the number of workers.

    Finished runs are kept in OUT.partial as they finish: an interrupted
    campaign (Ctrl-C, SIGTERM, SIGHUP, a lost cluster) continues with --resume,
    computing only the runs it lacks, with the results of an uninterrupted one.

    The budget checks the requirement (--requirement, --probability) under one
    ECSS-E-ST-60-10C statistical interpretation (--interpretation) at
    --confidence, over t ≥ --steady-after. The console opens with the verdict and
    its confidence.
    """
    from rwlab.campaign.indices import PointingRequirement
    from rwlab.report.montecarlo import CampaignOptions, montecarlo

    req = PointingRequirement(
        **{field: options.pop(option) for option, field in REQUIREMENT_FIELDS.items()}
    )
    spec = CampaignOptions(**options, requirement=req)
    check_run(spec.duration, None)
    _check_folder(Path(out).absolute().parent)
    with _steps_progress(spec.runs, f"{spec.controller} campaign", unit="runs") as progress:
        stats, paths = montecarlo(
            out,
            spec,
            workers=workers,
            scheduler=scheduler,
            force=force,
            resume=resume,
            progress=progress,
            echo=lambda text: click.echo(_flags(text), err=True),
        )
    echo_verdict(stats)
    echo_budget(stats)
    click.echo(_wrote(out, paths.values()))


def echo_verdict(stats: dict) -> None:
    """The verdict with its confidence, then the requirement and interpretation it answers:
    the first lines printed (no share of runs before it says what that share demonstrates)."""
    req, verdict = stats["requirement"], stats["verdict"]
    window = stats["steady_window"]
    click.echo(f"verdict: {verdict['text']}")
    worst = ", ".join(f"run {w['run']} ({w['value']:.4g})" for w in verdict["worst_runs"])
    click.echo(f"  set by: {worst}")
    click.echo(
        f"requirement: APE ≤ {req['ape_deg']:g}° on the total error, P = {req['probability']:g}, "
        f"confidence {req['confidence']:.0%}; steady window t ≥ {window['start_s']:g} s "
        f"({window['start']} start)"
    )
    click.echo(
        f"interpretation ({stats['interpretation']['name']}): "
        f"{stats['interpretation']['statement']}"
    )
    if verdict["rpe"] is not None:
        r = verdict["rpe"]
        state = (
            "MET, demonstrated"
            if r["demonstrated"]
            else ("NOT DEMONSTRATED" if r["met"] else "NOT MET")
        )
        click.echo(
            f"RPE ≤ {r['bound_deg']:g}° ({r['window_s']:g} s window, every axis): {state} at "
            f"{req['confidence']:.0%} confidence; {r['estimate']:.1%} of runs, at least "
            f"{r['lower_bound']:.1%}"
        )
    for line in late_warnings(window):
        click.echo(f"warning: {line}", err=True)


def late_warnings(window: dict) -> list[str]:
    """What each run named did after the steady window's start: acquired (first came within
    the bound) or had its filter converge; a later miss is the verdict's, not named here.

    Parameters
    ----------
    window : dict
        ``budget.json``'s ``steady_window``.

    Returns
    -------
    list of str
        One line per kind of lateness (none: nothing late).
    """
    out = []
    start = f"the steady window's start ({window['start_s']:g} s)"
    for key, what in (
        ("runs_acquired_after_start", "first came within the bound after"),
        ("runs_filter_converged_after_start", "had their filter converge after"),
    ):
        runs = window[key]
        if runs:
            shown = ", ".join(map(str, runs[:10])) + (" …" if len(runs) > 10 else "")
            out.append(
                f"{len(runs)} run(s) {what} {start}: runs {shown}; their steady statistics "
                "include acquisition (start the window later: steady_after)"
            )
    return out


def echo_budget(stats: dict) -> None:
    """Each run's steady maximum over runs per axis and total, its quantiles with their
    bounds, and the ECSS indices' maxima."""
    ape, total = stats["indices"]["APE"], stats["total_error"]
    click.echo(f"{'axis':<6} {'mean [°]':>10} {'std [°]':>10} {'max [°]':>10}   (steady maximum)")
    for axis, s in [*((a, ape[a]) for a in ("x", "y", "z")), ("total", total)]:
        click.echo(f"{axis:<6} {s['mean']:10.4g} {s['std']:10.4g} {s['max']:10.4g}")
    for q in total["quantiles"]:
        bound = (
            f"≤ {q['upper_bound']:.4g}° ({q['confidence']:.0%})"
            if q["upper_bound"] is not None
            else f"no {q['confidence']:.0%} bound: needs {q['runs_needed']} runs"
        )
        click.echo(f"  {q['p']:.2%} quantile of {total['column']}: {q['estimate']:.4g}°, {bound}")
    click.echo(f"{'index':<6} {'x [°]':>10} {'y [°]':>10} {'z [°]':>10}   (max over runs)")
    for name, entry in stats["indices"].items():
        cells = [
            f"{entry[a]['max']:10.4g}" if entry[a] is not None else f"{'n/a':>10}"
            for a in ("x", "y", "z")
        ]
        click.echo(f"{name:<6} {' '.join(cells)}")
