"""``rwlab ident …`` and ``rwlab datasets``: single identification commands."""

from __future__ import annotations

from pathlib import Path

import click

from rwlab.cli._common import (
    _check_folder,
    _data_options,
    _echo_json,
    _friendly_errors,
    _load,
    main,
)
from rwlab.errors import ConfigError


@main.group()
def ident() -> None:
    """System identification (MATLAB System Identification Toolbox semantics).

    FILE is a .csv, .dat, .parquet or .mat record, or the name of a bundled
    data set (see `rwlab datasets`).
    """


def _estimate_command(name: str, order_names: list[str], estimator_name: str, doc: str):
    @_friendly_errors
    def command(
        file, Ts, input_col, output_col, detrend, normalize, split, as_json, save, force, **orders
    ):
        from rwlab import ident as idm

        _check_orders(name, orders)
        if save:
            _check_folder(Path(save).parent)
        data = _load(file, Ts, input_col, output_col, detrend, normalize)
        est, val = (data, None) if split >= 1 else data.split(split)
        extra = {"max_iter": orders.pop("max_iter")} if "max_iter" in orders else {}
        model = getattr(idm, estimator_name)(est, *[orders[o] for o in order_names], **extra)
        v, line = None, None
        if val is not None:
            cmp = idm.compare(model, val)
            res = idm.resid(model, val, max_lag=min(25, val.N // 2 - 1))
            v = {
                "fit_percent": cmp.fit_percent,
                "mse": cmp.mse,
                "residuals_white": res.white,
                "whiteness_p": res.whiteness_p,
                "residuals_independent_of_input": res.independent,
                "independence_p": res.independence_p,
            }
            line = (
                f"validation ({val.N} samples, simulation): fit {v['fit_percent']:.2f} %, "
                f"MSE {v['mse']:.4g}; residuals {'white' if v['residuals_white'] else 'NOT white'} "
                f"(p = {v['whiteness_p']:.3f}), "
                f"{'independent of' if v['residuals_independent_of_input'] else 'CORRELATED with'} "
                f"the input (p = {v['independence_p']:.3f})"
            )
        _show_model(model, data, est, v, line, save=save, force=force, as_json=as_json)

    for order in reversed(order_names):
        command = click.argument(order, type=click.IntRange(min=0))(command)
    if name != "arx":
        command = click.option(
            "--max-iter", type=click.IntRange(min=1), default=100, show_default=True
        )(command)
    command = click.option("--force", is_flag=True, help="Overwrite --save's file.")(command)
    command = click.option(
        "--save", type=click.Path(dir_okay=False), help="Write the model as JSON here."
    )(command)
    command = click.option(
        "--json", "as_json", is_flag=True, help="Print the model and scores as JSON."
    )(command)
    command = click.option(
        "--split",
        type=click.FloatRange(0, 1, min_open=True),
        default=0.7,
        show_default=True,
        help="Estimation share; the rest validates (1: no validation).",
    )(command)
    command = _data_options(command)
    command.__doc__ = doc
    return ident.command(name)(command)


def _check_orders(name: str, orders: dict[str, int]) -> None:
    """Refuse orders that leave nothing to estimate, before any data is read."""
    shown = ", ".join(f"{k}={v}" for k, v in orders.items())
    if not any(v for k, v in orders.items() if k != "nk"):
        raise ConfigError(f"{name.upper()}({shown}) has no parameters to estimate")
    if name in ("oe", "bj") and orders["nb"] == 0:
        raise ConfigError(f"{name.upper()}({shown}): nb must be ≥ 1, or the input never enters")


_estimate_command(
    "arx",
    ["na", "nb", "nk"],
    "arx",
    "Estimate ARX(NA, NB, NK) by least squares: A y = B u(t-NK) + e.",
)
_estimate_command(
    "armax",
    ["na", "nb", "nc", "nk"],
    "armax",
    "Estimate ARMAX(NA, NB, NC, NK) by prediction error: A y = B u + C e.",
)
_estimate_command(
    "oe", ["nb", "nf", "nk"], "oe", "Estimate output-error OE(NB, NF, NK): y = (B/F) u + e."
)
_estimate_command(
    "bj",
    ["nb", "nc", "nd", "nf", "nk"],
    "bj",
    "Estimate Box-Jenkins BJ(NB, NC, ND, NF, NK): y = (B/F) u + (C/D) e.",
)


def _show_model(model, data, est, validation, line, *, save, force, as_json) -> None:
    """Save the model if asked, then print it with its validation (JSON or text)."""
    result = {"model": model.to_dict()}
    if validation is not None:
        result["validation"] = validation
    if save:
        model.save(save, overwrite=force)
    if as_json:
        _echo_json(result)
        return
    click.echo(f"data: {data!r}, estimation {est.N} samples")
    click.echo(str(model))
    if line:
        click.echo(line)
    if save:
        click.echo(f"model written to {save}")


@ident.command("ar")
@_data_options
@click.argument("na", type=click.IntRange(min=0))
@click.option(
    "--approach",
    type=click.Choice(["fb", "ls"]),
    default="fb",
    show_default=True,
    help="Forward-backward (MATLAB's default) or forward least squares.",
)
@click.option(
    "--split",
    type=float,
    default=0.7,
    show_default=True,
    help="Estimation share; the rest validates (1: no validation).",
)
@click.option("--json", "as_json", is_flag=True, help="Print the model and scores as JSON.")
@click.option("--save", type=click.Path(dir_okay=False), help="Write the model as JSON here.")
@click.option("--force", is_flag=True, help="Overwrite --save's file.")
@_friendly_errors
def ident_ar(
    file, Ts, input_col, output_col, detrend, normalize, na, approach, split, as_json, save, force
):
    """Estimate an AR(NA) model A y = e of the output alone (a time series; inputs ignored)."""
    from rwlab import ident as idm
    from rwlab.data import IOData

    data = _load(file, Ts, input_col, output_col, detrend, normalize)
    data = IOData(
        None,
        data.y,
        data.Ts,
        output_names=data.output_names,
        output_units=data.output_units,
        tstart=data.tstart,
        name=data.name,
    )
    est, val = (data, None) if split >= 1 else data.split(split)
    model = idm.ar(est, na, approach)
    v, line = None, None
    if val is not None:
        cmp = idm.compare(model, val)  # a time series: 1-step prediction
        res = idm.resid(model, val, max_lag=min(25, val.N // 2 - 1))
        v = {
            "prediction_fit_percent": cmp.fit_percent,
            "mse": cmp.mse,
            "residuals_white": res.white,
            "whiteness_p": res.whiteness_p,
        }
        line = (
            f"validation ({val.N} samples, 1-step prediction): fit "
            f"{v['prediction_fit_percent']:.2f} %, MSE {v['mse']:.4g}; residuals "
            f"{'white' if v['residuals_white'] else 'NOT white'} (p = {v['whiteness_p']:.3f})"
        )
    _show_model(model, data, est, v, line, save=save, force=force, as_json=as_json)


@ident.command("delay")
@_data_options
@click.option("--na", type=int, default=2, show_default=True)
@click.option("--nb", type=int, default=2, show_default=True)
@click.option("--nk-min", type=int, default=0, show_default=True)
@click.option("--nk-max", type=int, default=None, help="Largest delay [default: nk-min + 20].")
@click.option("--json", "as_json", is_flag=True, help="Print the losses as JSON.")
@_friendly_errors
def delay(file, Ts, input_col, output_col, detrend, normalize, na, nb, nk_min, nk_max, as_json):
    """Estimate the input delay by scanning ARX(NA, NB, nk) losses (MATLAB delayest)."""
    from rwlab.ident import delay_scan

    data = _load(file, Ts, input_col, output_col, detrend, normalize)
    losses = delay_scan(data, na, nb, nk_min, nk_max)
    best = min(losses, key=losses.get)
    if as_json:
        _echo_json({"nk": best, "losses": {str(k): v for k, v in losses.items()}})
        return
    click.echo(f"{'nk':>4}  {'loss':>12}")
    for k, v in losses.items():
        click.echo(f"{k:>4}  {v:12.6g}{'  <- minimum' if k == best else ''}")
    click.echo(f"delay: nk = {best} samples ({best * data.Ts:g} s)")


@ident.command("struct")
@_data_options
@click.option("--na", "na_range", default="1:10", show_default=True, help="Range lo:hi of na.")
@click.option("--nb", "nb_range", default="1:10", show_default=True, help="Range lo:hi of nb.")
@click.option("--nk", "nk_range", default=None, help="Range lo:hi of nk (default: delayest's).")
@click.option(
    "--split",
    type=click.FloatRange(0, 1, min_open=True, max_open=True),
    default=0.5,
    show_default=True,
    help="Estimation share.",
)
@click.option(
    "--criterion",
    callback=lambda ctx, param, value: _criterion(value),
    default="0",
    show_default=True,
    help="0 (validation loss), aic, mdl, or a number c for V(1+c·d/N).",
)
@click.option("--json", "as_json", is_flag=True)
@_friendly_errors
def struct_(
    file,
    Ts,
    input_col,
    output_col,
    detrend,
    normalize,
    na_range,
    nb_range,
    nk_range,
    split,
    criterion,
    as_json,
):
    """Compare ARX orders on validation data and select one (MATLAB arxstruc + selstruc)."""
    from rwlab.ident import arxstruc, delayest, selstruc, struc

    data = _load(file, Ts, input_col, output_col, detrend, normalize)
    est, val = data.split(split)
    nks = _range(nk_range) if nk_range else [delayest(est)]
    table = arxstruc(est, val, struc(_range(na_range), _range(nb_range), nks))
    best = selstruc(table, criterion)
    if as_json:
        _echo_json(
            {
                "best": dict(zip(("na", "nb", "nk"), best, strict=True)),
                "losses": [s.__dict__ for s in table],
            }
        )
        return
    click.echo(f"{'na':>3} {'nb':>3} {'nk':>3}  {'validation loss':>16}")
    for s in sorted(table, key=lambda s: s.loss)[:15]:
        mark = "  <- selected" if (s.na, s.nb, s.nk) == best else ""
        click.echo(f"{s.na:>3} {s.nb:>3} {s.nk:>3}  {s.loss:16.6g}{mark}")
    click.echo(f"selected (criterion {criterion}): na={best[0]} nb={best[1]} nk={best[2]}")


def _criterion(text: str) -> str | float:
    """selstruc's criterion: 'aic', 'mdl', or a number c ≥ 0."""
    if text in ("aic", "mdl"):
        return text
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not (value >= 0 and value < float("inf")):
        raise click.BadParameter(f"expected 0, aic, mdl or a number c ≥ 0, got {text!r}")
    return value


def _range(text: str) -> list[int]:
    try:
        lo, _, hi = text.partition(":")
        values = list(range(int(lo), int(hi or lo) + 1))
    except ValueError:
        raise click.BadParameter(f"expected a range lo:hi, got {text!r}") from None
    if not values or values[0] < 0:
        raise click.BadParameter(f"expected a range lo:hi of orders ≥ 0, got {text!r}")
    return values


# -- state-space and non-parametric verbs (issue 13) -------------------------------------


def _ss_options(func):
    for option in reversed(
        [
            _data_options,
            click.argument("nx", type=click.IntRange(min=1)),
            click.option(
                "--weighting",
                type=click.Choice(["auto", "CVA", "MOESP", "N4SID", "SSARX"]),
                default="auto",
                show_default=True,
                help="n4sid's SVD weighting (auto: CVA; SSARX for closed-loop data).",
            ),
            click.option(
                "--enforce-stability",
                is_flag=True,
                help="Reflect unstable n4sid poles inside (MATLAB EnforceStability).",
            ),
            click.option("--feedthrough", is_flag=True, help="Estimate D (default D = 0)."),
            click.option(
                "--split",
                type=click.FloatRange(0, 1, min_open=True),
                default=0.7,
                show_default=True,
                help="Estimation share; the rest validates (1: no validation).",
            ),
            click.option("--json", "as_json", is_flag=True, help="Print the model as JSON."),
            click.option("--save", type=click.Path(dir_okay=False), help="Write the model here."),
            click.option("--force", is_flag=True, help="Overwrite --save's file."),
        ]
    ):
        func = option(func)
    return func


def _state_space_command(name: str, doc: str):
    @_ss_options
    @_friendly_errors
    def command(file, Ts, input_col, output_col, detrend, normalize, nx, weighting,
                enforce_stability, feedthrough, split, as_json, save, force):  # fmt: skip
        import numpy as np

        from rwlab import ident as idm

        if save:
            _check_folder(Path(save).parent)
        data = _load(file, Ts, input_col, output_col, detrend, normalize)
        est, val = (data, None) if split >= 1 else data.split(split)
        options = {
            "weighting": weighting,
            "feedthrough": feedthrough,
            "enforce_stability": enforce_stability,
        }
        if name == "n4sid":
            model = idm.n4sid(est, nx, **options)
        else:
            model = idm.ssest(
                est,
                nx,
                feedthrough=feedthrough,
                n4sid_options={"weighting": weighting, "enforce_stability": enforce_stability},
            )
        v, line = None, None
        if val is not None:
            e = model.residuals(val, initial="estimate")
            den = np.linalg.norm(val.y - val.y.mean(axis=0), axis=0)
            fits = [float(f) for f in 100 * (1 - np.linalg.norm(e, axis=0) / den)]
            v = {"prediction_fit_percent": fits, "mse": float(np.mean(e**2))}
            shown = ", ".join(f"{f:.2f}" for f in fits)
            line = f"validation ({val.N} samples, 1-step prediction): fit {shown} %"
            line += f", MSE {v['mse']:.4g}"
        _show_model(model, data, est, v, line, save=save, force=force, as_json=as_json)

    command.__doc__ = doc
    return ident.command(name)(command)


_state_space_command(
    "n4sid", "Estimate an NX-state innovations-form model by subspace identification (n4sid)."
)
_state_space_command(
    "ssest", "Estimate an NX-state innovations-form model by prediction error from n4sid (ssest)."
)


@main.command("datasets")
def datasets_cmd() -> None:
    """List the identification data sets bundled with rwlab."""
    from rwlab import datasets

    for name, loader in datasets.NAMES.items():
        data = loader()
        summary = (loader.__doc__ or "").strip().splitlines()[0]
        click.echo(f"{name:<18} N={data.N:<5} Ts={data.Ts:<5g} {summary}")
