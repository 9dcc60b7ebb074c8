"""``rwlab attitude …``: GEO attitude control (paper B)."""

from __future__ import annotations

import math
from pathlib import Path

import click

from rwlab.cli._common import (
    FORCE_WHEEL_OPTION,
    POSITIVE,
    SECONDS,
    Number,
    _flight_output_options,
    _friendly_errors,
    _imports_uninterrupted,
    _only_with,
    _output,
    _steps_progress,
    _wrote,
    main,
)
from rwlab.errors import ConfigError

# -- attitude control -----------------------------------------------------------------


@main.group()
def attitude() -> None:
    """GEO attitude control with reaction wheels (paper B): LQR, LQG, LQG/LTR."""
    single_thread_blas()


def single_thread_blas() -> None:
    """Pin BLAS to one thread: on 3×3 to 18×18 matrices its threads only wait for each
    other, and on a busy machine they make every Riccati solve ~7× slower (measured)."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")


EPOCH_OPTION = click.option(
    "--epoch",
    help="UTC start, ISO 8601 (e.g. 2027-03-20T12:00:00Z): the real Sun, Moon and eclipses "
    "instead of the scenario's fixed vectors.",
)


@attitude.command("compare")
@click.option(
    "--scenario",
    default="geo-smallsat",
    show_default=True,
    help="geo-smallsat, geo-comsat, or a scenario TOML file.",
)
@click.option("--out", type=click.Path(file_okay=False), required=True)
@click.option("--duration", type=SECONDS, default=1800.0, show_default=True, help="Seconds.")
@click.option(
    "--wheel-model",
    type=click.Path(exists=True, dir_okay=False),
    help="model.json from `rwlab identify`: also fly it as the actuator.",
)
@click.option("--rho", type=POSITIVE, default=0.7692, show_default=True, help="LTR ρ.")
@click.option("--seed", type=click.IntRange(min=0), default=None)
@click.option(
    "--relinearize",
    type=SECONDS,
    default=None,
    help="Re-design the LQR about the current state every this many seconds (paper B).",
)
@EPOCH_OPTION
@click.option("--force", is_flag=True, help="Overwrite outputs in --out.")
@FORCE_WHEEL_OPTION
@_friendly_errors
def attitude_compare(
    scenario, out, duration, wheel_model, rho, seed, relinearize, epoch, force, force_wheel
):
    """Run LQR, LQG and LQG/LTR on one scenario with the same noise; write report + metrics."""
    if not (math.isfinite(rho) and rho > 0):
        raise ConfigError(f"--rho must be a positive number, got {rho:g}")
    check_run(duration, relinearize)
    # the folder is locked before the loop is loaded: a second run on it is refused at once
    with _output(out, ["report.html", "metrics.json", "sigma.json"], force, "comparison") as stage:
        with _imports_uninterrupted():
            from rwlab.attitude.control import compare, ltr_study
            from rwlab.attitude.scenario import load_scenario
            from rwlab.report.attitude import write_comparison
            from rwlab.wheel.identified import IdentifiedWheel

        sc = load_scenario(scenario, **({"sky.epoch": epoch} if epoch else {}))
        _check_steps(duration, sc)
        if wheel_model and sc.sky.epoch:
            raise ConfigError(
                "--epoch needs ideal wheels: it cannot be combined with --wheel-model"
            )
        if wheel_model:
            IdentifiedWheel.from_json(wheel_model)  # a clear error now, not after the runs
            sc = sc.with_(**{"wheels.spec": _with_wheel_model(sc, wheel_model).wheels.spec})
        forced = _wheel_check(_with_wheel_model(sc, wheel_model), force_wheel)
        click.echo(
            f"simulating {sc.name} for {duration:g} s (LQR, LQG, LQG/LTR"
            f"{', identified wheel' if wheel_model else ''}; the first run compiles the loop, "
            "~30 s)...",
            err=True,
        )
        comp = compare(
            sc,
            duration=duration,
            seed=seed,
            rho=rho,
            wheel_model_file=wheel_model,
            update_period=relinearize,
            progress=lambda name: click.echo(f"  flying {name}", err=True),
        )
        comp.config["wheel_forced"] = forced
        paths = write_comparison(comp, stage, force=force, ltr_result=ltr_study(sc))
    click.echo(
        f"{'controller':<22} {'max err [°]':>11} {'rms [°]':>9} {'settle [s]':>10} "
        f"{'τ-saturated':>11} {'crossover [rad/s]':>17}"
    )
    for name, m in comp.metrics.items():
        settle = "never" if m["settling_time_s"] is None else f"{m['settling_time_s']:.0f}"
        click.echo(
            f"{name:<22} {m['steady_max_error_deg']:11.3g} {m['steady_rms_error_deg']:9.3g} "
            f"{settle:>10} {m['torque_saturated_fraction']:11.3g} {m['crossover_rad_s']:17.3g}"
        )
    click.echo(_wrote(out, paths.values()))


@attitude.command("convert-scenario")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--out", type=click.Path(dir_okay=False), help="Write it here [default: print it].")
@click.option("--force", is_flag=True, help="Replace an existing --out file.")
@_friendly_errors
def attitude_convert_scenario(file, out, force):
    """Rewrite a flat (old-format) scenario FILE in section tables (comments are dropped)."""
    from rwlab._io import atomic_write_bytes
    from rwlab.attitude.scenario import convert_scenario_file

    text = convert_scenario_file(file)
    if out is None:
        click.echo(text, nl=False)
        return
    if Path(out).exists() and not force:
        raise ConfigError(f"{out} exists; give --force to replace it")
    atomic_write_bytes(out, lambda tmp: tmp.write_bytes(text.encode("utf-8")))
    click.echo(f"wrote {out}")


@attitude.command("ltr")
@click.option("--scenario", default="geo-smallsat", show_default=True)
@click.option(
    "--rho",
    type=POSITIVE,
    multiple=True,
    default=(76.92, 7.692, 0.7692, 0.007692),
    show_default=True,
    help="Repeat for each ρ (paper B's four by default).",
)
@click.option("--out", type=click.Path(file_okay=False), required=True)
@click.option("--force", is_flag=True)
@_friendly_errors
def attitude_ltr(scenario, rho, out, force):
    """Loop singular values at the plant input for each ρ next to LQR's (paper Fig. 8)."""
    with _output(out, ["sigma.json", "report.html"], force, "LTR study") as stage:
        with _imports_uninterrupted():
            from rwlab.attitude.control import ltr_study
            from rwlab.attitude.scenario import load_scenario
            from rwlab.report.attitude import ltr_rows, write_ltr

        sc = load_scenario(scenario)
        res = ltr_study(sc, rhos=rho)
        paths = write_ltr(res, sc.name, stage, force=force)
    click.echo("rho        gap 1e-3..1e-1 [dB]  gap to crossover [dB]  crossover / LQR [rad/s]")
    for rho, gap, gap_c, w, w_c in ltr_rows(res):
        click.echo(f"{rho:<10} {gap:19.2f} {gap_c:22.2f}  {w:.3g} / {w_c:.3g}")
    click.echo(_wrote(out, paths.values()))


def _check_steps(duration: float, sc) -> int:
    """The run's number of steps; more than 1e9 (years at 0.1 s) is a typo, refused now."""
    steps = round(duration / sc.run.dt)
    if steps > 1e9:
        raise ConfigError(f"--duration {duration:g} s is {steps:.3g} steps: more than 1e9")
    return steps


def check_run(duration: float, relinearize: float | None) -> None:

    if not (math.isfinite(duration) and duration > 0):
        raise ConfigError(f"--duration must be a positive number of seconds, got {duration:g}")
    if relinearize is not None and not (math.isfinite(relinearize) and relinearize > 0):
        raise ConfigError(
            f"--relinearize must be a positive number of seconds, got {relinearize:g}"
        )


def _with_wheel_model(sc, wheel_model: str | None):
    """The scenario flying ``model.json`` as its wheels: the model's own spec (inertia and
    limits) when it carries one."""
    if not wheel_model:
        return sc
    from rwlab.ident.model_file import WheelModelFile

    changes = {"wheels.model": "identified", "wheels.model_file": str(wheel_model)}
    if WheelModelFile.load(wheel_model).wheel_spec is not None:
        changes["wheels.spec"] = str(wheel_model)
    return sc.with_(**changes)


def _wheel_check(sc, force_wheel: bool) -> list[str]:
    """Refuse (exit 2) wheels that cannot deliver the scenario's needs; forced: the lines."""
    from rwlab.attitude.wheel_fit import check_wheel_fit

    forced = check_wheel_fit(sc, force=force_wheel)
    for line in forced:
        click.echo(line, err=True)
    return forced


def _simulation_config(sc, controller, estimator, seed, duration, rho, relinearize) -> dict:
    """The ``config`` of a simulation's metrics.json: what was flown, as flown."""
    from rwlab.attitude.sim import disturbance_state

    return {
        "scenario": sc.name,
        "controller": controller,
        "estimator": estimator or ("truth" if controller in ("pd", "lqr") else "ekf"),
        "seed": sc.run.seed if seed is None else seed,
        "dt_s": sc.run.dt,
        "duration_s": duration,
        "rho": rho if controller == "lqg_ltr" else None,
        "relinearize_period_s": relinearize,
        "disturbances_known_to_filter": sc.filter.disturbances_known,
        "filter_disturbance_state": disturbance_state(sc) if controller.startswith("lqg") else None,
        "momentum_unloading": sc.momentum.unloading,
        "wheel_model": sc.wheels.model,
        "wheel_spec": {"name": sc.wheels.wheel_spec.name, "hash": sc.wheels.wheel_spec.hash},
        "wheel_faults": list(sc.wheels.faults),
        "epoch": sc.sky.epoch,
        "station_longitude_deg": sc.sky.station_longitude_deg,
        "steady_from_s": None,  # the run's own, filled in after it
        "gyro": sc.sensors.gyro is not None,
        "star_tracker": sc.sensors.star_tracker is not None,
    }


@attitude.command("simulate")
@click.option("--scenario", default="geo-comsat", show_default=True)
@click.option(
    "--controller",
    type=click.Choice(["pd", "lqr", "lqg", "lqg_ltr"]),
    default="lqg",
    show_default=True,
)
@click.option(
    "--estimator",
    type=click.Choice(["ekf", "truth"]),
    help="Default: truth for pd and lqr, ekf for lqg and lqg_ltr.",
)
@click.option(
    "--dt",
    type=Number(0, 3600, low_open=True),
    help="Control and physics step, s (the scenario's by default).",
)
@click.option("--duration", type=SECONDS, required=True, help="Seconds.")
@click.option("--seed", type=click.IntRange(min=0), default=None)
@click.option("--rho", type=POSITIVE, default=0.7692, show_default=True, help="LTR ρ (lqg_ltr).")
@click.option(
    "--relinearize", type=SECONDS, default=None, help="Re-design the LQR every this many seconds."
)
@EPOCH_OPTION
@click.option(
    "--steady-after",
    type=float,
    default=None,
    help="Seconds after which the steady-state metrics start [default: half the run, at "
    "most its first hour].",
)
@click.option(
    "--wheel-model",
    type=click.Path(exists=True, dir_okay=False),
    help="model.json from `rwlab identify`: fly it as the actuator (with its wheel spec).",
)
@click.option(
    "--jitter/--no-jitter",
    default=None,
    help="The wheels' imbalance (the wheel spec's U_s, U_d) shakes the spacecraft at their "
    "spin rate (needs --dt of about 0.5 / top wheel speed in rad/s) [default: the "
    "scenario's wheels.jitter, off in the shipped ones].",
)
@_flight_output_options
@_friendly_errors
def attitude_simulate(
    scenario,
    controller,
    estimator,
    dt,
    duration,
    seed,
    rho,
    relinearize,
    epoch,
    steady_after,
    wheel_model,
    jitter,
    out,
    force,
    force_wheel,
):
    """One controller on one scenario for any duration: metrics.json, trace.parquet, report.html."""
    _only_with("rho", controller == "lqg_ltr", "with --controller lqg_ltr")
    _only_with(
        "relinearize", controller != "pd", "with an LQR design (--controller lqr, lqg, lqg_ltr)"
    )
    check_run(duration, relinearize)
    if steady_after is not None and not (
        math.isfinite(steady_after) and 0 <= steady_after < duration
    ):
        raise ConfigError(
            f"--steady-after must be in [0, --duration) seconds, got {steady_after:g}"
        )
    files = ["metrics.json", "trace.parquet", "report.html"]
    # the folder is locked before the loop is loaded and compiled: a second run on it is
    # refused at once
    with _output(out, files, force, "simulation") as stage:
        with _imports_uninterrupted():
            from rwlab.attitude.control import fly
            from rwlab.attitude.scenario import load_scenario
            from rwlab.report.attitude import write_simulation

        overrides = {"run.dt": dt} if dt is not None else {}
        if jitter is not None:
            overrides["wheels.jitter"] = jitter
        sc = load_scenario(scenario, **overrides, **({"sky.epoch": epoch} if epoch else {}))
        sc = _with_wheel_model(sc, wheel_model)
        forced = _wheel_check(sc, force_wheel)
        steps = _check_steps(duration, sc)
        config = _simulation_config(sc, controller, estimator, seed, duration, rho, relinearize)
        config["wheel_forced"] = forced
        with _steps_progress(steps, f"{controller} on {sc.name}") as progress:
            run, metrics = fly(
                sc,
                controller,
                estimator=estimator,
                duration=duration,
                seed=seed,
                rho=rho,
                update_period=relinearize,
                log_every=max(10, -(-steps // 100_000)),
                progress=progress,
                steady_after=steady_after,
            )
        config["steady_from_s"] = run.steady_from_s
        paths = write_simulation(run, metrics, config, sc, stage, force=force)
    for key in (
        "max_error_deg",
        "steady_max_error_deg",
        "max_error_deg_excluding_desaturation",
        "wheel_momentum_peak_fraction",
        "desaturation_count",
        "torque_saturated_fraction",
        "eclipse_s",
        "earth_sensor_blinded_s",
    ):
        click.echo(f"{key:<40} {metrics[key]:.6g}")
    click.echo(_wrote(out, paths.values()))
