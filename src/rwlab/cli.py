"""The ``rwlab`` command line."""

from __future__ import annotations

import contextlib
import functools
import json
import math
import sys
import threading
import warnings
from pathlib import Path
from typing import NoReturn

import click

from rwlab import __version__
from rwlab.errors import ConfigError, RwlabError

# -- shared plumbing -------------------------------------------------------------------


def _message(exc: BaseException) -> str:
    """One line for an error a user caused (an OS error names its file)."""
    if isinstance(exc, OSError) and exc.strerror:
        where = exc.filename if exc.filename is not None else ""
        return f"{where}: {exc.strerror}" if where else exc.strerror
    return " ".join(str(exc).split()) or type(exc).__name__


def _fail(exc: BaseException) -> NoReturn:
    click.echo(f"error: {_message(exc)}", err=True)
    sys.exit(2)


def _friendly_errors(func):
    """Turn rwlab's typed errors and OS errors into a one-line message and exit status 2."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except (RwlabError, OSError) as exc:
            _fail(exc)

    return wrapper


class _Cli(click.Group):
    """The ``rwlab`` group: a usage error is one line and exit status 2, like any other."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        try:
            return super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click.UsageError as exc:
            where = f"{exc.ctx.command_path}: " if exc.ctx is not None else ""
            hint = f" (see {exc.ctx.command_path} --help)" if exc.ctx is not None else ""
            _fail(RwlabError(f"{where}{exc.format_message()}{hint}"))
        except click.ClickException as exc:
            _fail(RwlabError(exc.format_message()))
        except (RwlabError, OSError) as exc:
            _fail(exc)
        except click.Abort:
            click.echo("interrupted", err=True)
            sys.exit(130)


@contextlib.contextmanager
def _stop_signals():
    """SIGTERM and SIGHUP stop a run the way Ctrl-C does (KeyboardInterrupt).

    So ``kill`` or a closed terminal also idles the wheel, closes the record and
    stops the monitor. Only the first signal interrupts; later ones are ignored
    so that the clean-up they would cut short can finish.
    """
    import signal

    stops = (signal.SIGTERM, signal.SIGHUP)

    def interrupt(signum, frame):
        for s in stops:
            signal.signal(s, signal.SIG_IGN)
        raise KeyboardInterrupt(signal.Signals(signum).name)

    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set from the main thread
        return
    previous = {s: signal.signal(s, interrupt) for s in stops}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def _check_folder(folder) -> None:
    """Fail now, not after minutes of work, if files cannot be written into ``folder``."""
    import errno
    import os

    path = Path(folder).absolute()
    while not path.exists():
        path = path.parent
    if not path.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, "not a directory", str(path))
    if not os.access(path, os.W_OK | os.X_OK):
        raise PermissionError(errno.EACCES, "permission denied", str(path))
    target = Path(folder).absolute()
    if not target.exists():  # e.g. /proc passes the access test: try, and leave nothing
        target.mkdir(parents=True)
        while target != path:
            target.rmdir()
            target = target.parent


def _columns_option(func):
    for option in reversed(
        [
            click.option(
                "--input",
                "input_col",
                help="Input column(s) or .mat variable(s), several as a,b (records: command).",
            ),
            click.option(
                "--output",
                "output_col",
                help="Output column(s) or .mat variable(s), several as a,b (records: speed_rpm).",
            ),
        ]
    ):
        func = option(func)
    return func


def _engine_options(func):
    """--workers / --scheduler: where a campaign's tasks run (rwlab.campaign.engine)."""
    func = click.option(
        "--scheduler",
        help="Address of an existing Dask scheduler, e.g. tcp://host:8786.",
    )(func)
    return click.option(
        "--workers",
        type=click.IntRange(min=1),
        help="Worker processes of the local Dask cluster [default: the cores].",
    )(func)


def _data_options(func):
    """Options every identification command takes to load and preprocess a record."""
    options = [
        click.argument("file"),
        click.option(
            "--Ts", "Ts", type=float, help="Sample time in seconds (when the file has none)."
        ),
        _columns_option,
        click.option(
            "--detrend",
            type=click.Choice(["none", "constant", "linear"]),
            default="none",
            show_default=True,
            help="Remove means or lines before estimation (MATLAB habit).",
        ),
        click.option("--normalize", is_flag=True, help="Scale every channel to [0, 1] (paper A)."),
    ]
    for option in reversed(options):
        func = option(func)
    return func


def _load(file, Ts, input_col, output_col, detrend="none", normalize=False):
    """A bundled data set by name, or any file rwlab reads (.mcap records included)."""
    from rwlab import datasets
    from rwlab.data import load

    if not Path(file).exists() and file in datasets.NAMES:
        if input_col or output_col:
            raise ConfigError(f"{file} is a bundled data set: it has one input and one output")
        data = datasets.get(file)
    else:
        data = load(file, Ts, input_columns=input_col, output_columns=output_col)
    if detrend != "none":
        data = data.detrend(detrend)
    if normalize:
        data = data.normalize()
    return data


def _echo_json(obj) -> None:
    click.echo(
        json.dumps(obj, indent=2, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
    )


# -- commands --------------------------------------------------------------------------


@click.group(cls=_Cli, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="rwlab")
def main() -> None:
    """rwlab: test a reaction wheel, identify it, and control a satellite with it."""


@main.group()
def ident() -> None:
    """System identification (MATLAB System Identification Toolbox semantics).

    FILE is a .csv, .dat, .parquet or .mat record, or the name of a bundled
    data set (see `rwlab datasets`).
    """
    warnings.showwarning = _one_line_warning


def _one_line_warning(message, category, *_args, **_kwargs) -> None:
    """Show a warning as ``warning: message`` on stderr (no file, line or source)."""
    click.echo(f"warning: {message}", err=True)


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
                type=click.Choice(["auto", "CVA", "MOESP", "N4SID"]),
                default="auto",
                show_default=True,
                help="n4sid's SVD weighting (auto: CVA).",
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
    def command(file, Ts, input_col, output_col, detrend, normalize, nx, weighting, feedthrough,
                split, as_json, save, force):  # fmt: skip
        import numpy as np

        from rwlab import ident as idm

        if save:
            _check_folder(Path(save).parent)
        data = _load(file, Ts, input_col, output_col, detrend, normalize)
        est, val = (data, None) if split >= 1 else data.split(split)
        options = {"weighting": weighting, "feedthrough": feedthrough}
        if name == "n4sid":
            model = idm.n4sid(est, nx, **options)
        else:
            model = idm.ssest(
                est, nx, feedthrough=feedthrough, n4sid_options={"weighting": weighting}
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


def _write_json(path, payload: dict, force: bool) -> None:
    from rwlab.data import atomic_write_bytes

    if Path(path).exists() and not force:
        raise FileExistsError(f"{path} exists; use --force to overwrite")
    text = json.dumps(payload, indent=2)
    atomic_write_bytes(Path(path), lambda tmp: tmp.write_text(text))


def _response_table(fr, rows: int = 16) -> None:
    """A few frequencies of every input→output pair: |G| in dB with ±1σ, phase in degrees."""
    import numpy as np

    mag, phase = fr.magnitude_db(), fr.phase_deg()
    sd = fr.magnitude_sd()
    for i in range(fr.response.shape[1]):
        for j in range(fr.response.shape[2]):
            click.echo(f"output {i + 1} / input {j + 1}:")
            click.echo(f"{'omega rad/s':>12} {'|G| dB':>9} {'± dB (1σ)':>10} {'phase deg':>10}")
            for k in np.unique(np.linspace(0, len(fr.omega) - 1, rows).astype(int)):
                g = abs(fr.response[k, i, j])
                pm = "" if sd is None else f"{20 * np.log10(1 + sd[k, i, j] / g):10.2f}"
                click.echo(
                    f"{fr.omega[k]:12.4g} {mag[k, i, j]:9.2f} {pm:>10} {phase[k, i, j]:10.1f}"
                )


@ident.command("spa")
@_data_options
@click.option(
    "--window", type=click.IntRange(min=1), help="Hann lag window [default: min(N/10, 30)]."
)
@click.option("--json", "as_json", is_flag=True, help="Print the whole estimate as JSON.")
@click.option("--save", type=click.Path(dir_okay=False), help="Write the estimate as JSON here.")
@click.option("--force", is_flag=True, help="Overwrite --save's file.")
@_friendly_errors
def ident_spa(file, Ts, input_col, output_col, detrend, normalize, window, as_json, save, force):
    """Frequency response by spectral analysis (MATLAB spa): Blackman–Tukey, Hann window."""
    from rwlab.ident import spa

    if save:
        _check_folder(Path(save).parent)
    data = _load(file, Ts, input_col, output_col, detrend, normalize)
    fr = spa(data, window)
    if save:
        _write_json(save, fr.to_dict(), force)
    if as_json:
        _echo_json(fr.to_dict())
        return
    click.echo(f"data: {data!r}; spa at {len(fr.omega)} frequencies")
    _response_table(fr)
    if save:
        click.echo(f"estimate written to {save}")


@ident.command("impulse")
@_data_options
@click.option("--n", "n_coef", type=click.IntRange(min=1), default=70, show_default=True,
              help="Number of FIR coefficients.")  # fmt: skip
@click.option("--nk", type=click.IntRange(min=0), default=0, show_default=True, help="Delay.")
@click.option("--kernel", type=click.Choice(["TC", "none"]), default="TC", show_default=True,
              help="TC (MATLAB's default) or none (least squares).")  # fmt: skip
@click.option("--json", "as_json", is_flag=True, help="Print the coefficients as JSON.")
@click.option("--save", type=click.Path(dir_okay=False), help="Write the estimate as JSON here.")
@click.option("--force", is_flag=True, help="Overwrite --save's file.")
@_friendly_errors
def ident_impulse(file, Ts, input_col, output_col, detrend, normalize, n_coef, nk, kernel,
                  as_json, save, force):  # fmt: skip
    """Impulse response as a regularised FIR model (MATLAB impulseest), with ±3σ."""
    import numpy as np

    from rwlab.ident import impulseest

    if save:
        _check_folder(Path(save).parent)
    data = _load(file, Ts, input_col, output_col, detrend, normalize)
    m = impulseest(data, n_coef, nk, kernel=kernel)
    payload = {
        "Ts": m.Ts,
        "lags": m.lags.tolist(),
        "coefficients": m.coefficients.tolist(),
        "sd": m.sd.tolist(),
        "noise_variance": m.noise_variance.tolist(),
        "report": m.report,
    }
    if save:
        _write_json(save, payload, force)
    if as_json:
        _echo_json(payload)
        return
    click.echo(f"data: {data!r}; FIR with {n_coef} coefficients from lag {nk} ({kernel} kernel)")
    for i in range(m.coefficients.shape[1]):
        for j in range(m.coefficients.shape[2]):
            g, s = m.coefficients[:, i, j], m.sd[:, i, j]
            big = np.flatnonzero(np.abs(g) > 3 * s)
            click.echo(
                f"output {i + 1} / input {j + 1}: {big.size} coefficients outside ±3σ of zero"
                + (
                    f", the first at lag {m.lags[big[0]]} ({g[big[0]]:.4g} ± {s[big[0]]:.2g})"
                    if big.size
                    else ""
                )
            )
            for k in range(min(10, len(g))):
                click.echo(f"  g[{m.lags[k]:>3}] = {g[k]:+.4g} ± {3 * s[k]:.2g} (3σ)")
    if save:
        click.echo(f"estimate written to {save}")


@main.command("datasets")
def datasets_cmd() -> None:
    """List the identification data sets bundled with rwlab."""
    from rwlab import datasets

    for name, loader in datasets.NAMES.items():
        data = loader()
        summary = (loader.__doc__ or "").strip().splitlines()[0]
        click.echo(f"{name:<18} N={data.N:<5} Ts={data.Ts:<5g} {summary}")


# -- the wheel ------------------------------------------------------------------------


def _bus_options(func):
    from rwlab.wheel.bus import INTERFACES

    for option in reversed(
        [
            click.option(
                "--interface",
                type=click.Choice(INTERFACES),
                default="virtual",
                show_default=True,
                help="python-can interface (serial = RS-232 with SLIP).",
            ),
            click.option(
                "--channel",
                default=None,
                help="Bus channel (vcan0, a multicast group, /dev/ttyUSB0, ...).",
            ),
            click.option("--node-id", type=click.IntRange(0, 15), default=0, show_default=True),
        ]
    ):
        func = option(func)
    return func


@main.group()
def wheel() -> None:
    """The reaction wheel: run a simulated RW90, or command a wheel on a bus."""


@wheel.command("serve")
@_bus_options
@click.option("--telemetry-rate", type=float, default=100.0, show_default=True, help="Hz.")
@click.option(
    "--latency-ms",
    type=float,
    default=20.0,
    show_default=True,
    help="Command-to-effect latency (paper A measured ~20 ms).",
)
@click.option(
    "--watchdog",
    type=float,
    default=1.0,
    show_default=True,
    help="Idle the wheel after this many seconds without a command (0: off).",
)
@click.option(
    "--params",
    type=click.Path(exists=True, dir_okay=False),
    help="Wheel parameters as TOML (default RW90).",
)
@click.option("--duration", type=float, default=None, help="Stop after this many seconds.")
@_friendly_errors
def wheel_serve(
    interface, channel, node_id, telemetry_rate, latency_ms, watchdog, params, duration
):
    """Run a simulated wheel on a bus, on the wall clock, until Ctrl-C."""
    import time

    from rwlab.wheel import RW90, WheelNode, WheelParams
    from rwlab.wheel.bus import DEFAULT_CHANNELS, open_bus

    wheel_params = WheelParams.from_toml(params) if params else RW90
    channel = channel or DEFAULT_CHANNELS[interface]
    bus = open_bus(interface, channel)
    node = WheelNode(
        bus,
        node_id,
        wheel_params,
        telemetry_rate=telemetry_rate,
        latency=latency_ms / 1000,
        watchdog=watchdog,
    ).start()
    click.echo(f"simulated wheel {node_id} on {interface}:{channel}; Ctrl-C to stop", err=True)
    start = time.monotonic()
    try:
        with _stop_signals():
            while duration is None or time.monotonic() - start < duration:
                time.sleep(min(1.0, duration or 1.0))
                w = node.wheel
                click.echo(
                    f"t={time.monotonic() - start:7.1f} s mode={w.mode.name:<12} "
                    f"speed={w.measured_speed_rpm():8.1f} rpm faults={w.faults!s}",
                    err=True,
                )
    except KeyboardInterrupt:
        pass
    finally:
        node.stop()
        bus.shutdown()


@wheel.command("cmd")
@_bus_options
@click.argument("action", type=click.Choice(["speed", "accel", "idle", "clear"]))
@click.argument("value", type=float, required=False, default=0.0)
@click.option(
    "--watch",
    type=float,
    default=2.0,
    show_default=True,
    help="Seconds to print telemetry after the command.",
)
@click.option("--timeout", type=float, default=0.5, show_default=True)
@_friendly_errors
def wheel_cmd(interface, channel, node_id, action, value, watch, timeout):
    """Send one command (speed rpm, accel rpm/s, idle, clear) and print telemetry.

    On the virtual interface an in-process simulated wheel answers. The wheel is
    idled when the command ends unless the action was idle or clear.
    """
    from rwlab.wheel import WheelClient, WheelNode
    from rwlab.wheel.bus import open_bus

    bus = open_bus(interface, channel)
    node = None
    if interface == "virtual":
        node = WheelNode(open_bus(interface, channel), node_id, latency=0.02).start()
    client = WheelClient(bus, node_id, timeout=timeout)
    with _stop_signals():  # SIGTERM too ends in the finally: the wheel idles
        try:
            send = {
                "speed": lambda: client.set_speed(value),
                "accel": lambda: client.set_acceleration(value),
                "idle": client.idle,
                "clear": client.clear_fault,
            }[action]
            seq = send()
            client.wait_ack(seq)
            t0 = client.clock.now()
            click.echo(
                f"acknowledged in {client.latency_of(seq, client.latest_time) * 1000:.1f} ms"
            )
            click.echo(f"{'t [s]':>7} {'speed [rpm]':>12} {'current [A]':>12} mode")
            next_print = next_send = t0
            while client.clock.now() - t0 <= watch:
                now = client.clock.now()
                if action in ("speed", "accel") and now >= next_send:
                    send()  # keep-alive: the wheel's watchdog idles it without commands
                    next_send += 0.25
                tel = client.telemetry()
                client.raise_if_faulted()
                if now >= next_print:
                    click.echo(
                        f"{now - t0:7.2f} {tel.speed_rpm:12.1f} {tel.current:12.3f} {tel.mode.name}"
                    )
                    next_print += 0.1
                client.clock.sleep(0.005)
        finally:
            if action not in ("idle", "clear"):
                client.close()
            if node is not None:
                node.stop()
                node.bus.shutdown()
            bus.shutdown()


# -- the testbed ----------------------------------------------------------------------


@main.command("experiment")
@click.option(
    "--config",
    "config_file",
    type=click.Path(dir_okay=False),
    help="Experiment TOML file ([experiment] table); flags override it.",
)
@click.option("--signal", type=click.Choice(["prbs", "chirp", "step", "multisine", "file"]))
@click.option("--mode", type=click.Choice(["speed", "acceleration"]))
@click.option("--amplitude", type=float, help="rpm in speed mode, rpm/s in acceleration mode.")
@click.option("--duration", type=float, help="Seconds of signal.")
@click.option("--Ts", "Ts", type=float, help="Command period, s.")
@click.option("--out", type=click.Path(dir_okay=False), required=True, help="Record file (.mcap).")
@click.option("--realtime", is_flag=True, default=None, help="Run on the wall clock.")
@click.option("--telemetry-rate", type=float, help="Simulated wheel's telemetry rate, Hz.")
@click.option("--seed", type=int)
@click.option(
    "--file",
    "setpoint_file",
    type=click.Path(dir_okay=False),
    help="CSV of setpoints for --signal file.",
)
@click.option("--interface", type=click.Choice(["virtual", "socketcan", "udp_multicast", "serial"]))
@click.option("--channel")
@click.option("--node-id", type=click.IntRange(0, 15))
@click.option("--raw-frames", is_flag=True, default=None, help="Also record every CAN frame.")
@click.option(
    "--fault",
    "faults",
    multiple=True,
    metavar="NAME[=VALUE]@SECONDS",
    help="Inject a fault into the simulated wheel (repeatable), e.g. friction=3@900: friction, "
    "torque_constant (factors), current_limit (A), speed_sensor_bias (rpm), speed_sensor_stuck, "
    "telemetry_dropout (s).",
)
@click.option(
    "--model",
    "model_file",
    type=click.Path(dir_okay=False),
    help="model.json: run the fault detector live; alarms become record events.",
)
@click.option("--monitor", is_flag=True, help="Serve the live monitor while the experiment runs.")
@click.option(
    "--port", type=click.IntRange(1, 65535), default=5006, show_default=True, help="Monitor port."
)
@click.option("--force", is_flag=True, help="Overwrite --out if it exists.")
@_friendly_errors
def experiment(
    config_file,
    signal,
    mode,
    amplitude,
    duration,
    Ts,
    out,
    realtime,
    telemetry_rate,
    seed,
    setpoint_file,
    interface,
    channel,
    node_id,
    raw_frames,
    faults,
    model_file,
    monitor,
    port,
    force,
):
    """Play a test signal into a wheel and record every command and telemetry frame.

    With the default virtual interface a simulated RW90 answers, on a simulated
    clock (a 20-minute experiment takes seconds) unless --realtime is given.
    Ctrl-C or any error leaves the wheel idle and the record closed.
    """
    from rwlab.testbed import ExperimentConfig, run_experiment

    overrides = dict(
        signal=signal,
        mode=mode,
        amplitude=amplitude,
        duration=duration,
        Ts=Ts,
        realtime=realtime,
        telemetry_rate=telemetry_rate,
        seed=seed,
        file=setpoint_file,
        interface=interface,
        channel=channel,
        node_id=node_id,
        raw_frames=raw_frames,
        faults=tuple(faults) or None,
        model=model_file,
    )
    if config_file:
        cfg = ExperimentConfig.from_toml(config_file, **overrides)
    else:
        cfg = ExperimentConfig(**{k: v for k, v in overrides.items() if v is not None})
    from rwlab.wheel import RW90

    cfg.check_limits(RW90)
    if Path(out).exists() and not force:
        raise FileExistsError(f"{out} exists; pass --force to replace it")
    _check_folder(Path(out).parent)
    realtime = cfg.realtime or cfg.interface != "virtual"
    label = f"{cfg.signal} ({cfg.mode}, {'real time' if realtime else 'simulated clock'})"
    server = None
    try:
        with _stop_signals():
            if monitor:
                from rwlab.testbed.monitor import start_process

                # its own process, following the file being written: it never slows the run
                server = start_process(out, port=port)
                click.echo(f"live monitor: http://127.0.0.1:{port}/", err=True)
            with contextlib.ExitStack() as stack:
                bars = []

                def progress(k: int, total: int) -> None:
                    if not bars:  # shown from the first command: a failed start prints nothing
                        bar = click.progressbar(
                            length=total, label=label, show_eta=True, file=sys.stderr
                        )
                        bars.append(stack.enter_context(bar))
                    bars[0].update(1)

                summary = run_experiment(cfg, out, force=force, progress=progress)
    except KeyboardInterrupt as exc:
        why = exc.args[0] if exc.args else "Ctrl-C"
        click.echo(f"\ninterrupted ({why}): the wheel is idle and {out} is closed", err=True)
        sys.exit(130)
    finally:
        if server is not None:
            from rwlab.testbed.monitor import stop_process

            stop_process(server)
    click.echo(
        f"{summary.path}: {summary.commands} commands, {summary.telemetry} telemetry "
        f"frames, {summary.lost_frames} lost, {summary.duration:.1f} s ({summary.status})"
    )


@main.command("export")
@click.argument("record", type=click.Path(dir_okay=False))
@click.option("--format", "fmt", type=click.Choice(["csv", "parquet", "mat"]), required=True)
@click.option("--out", type=click.Path(dir_okay=False), required=True)
@click.option("--Ts", "Ts", type=float, help="Sample time, s (default: the record's).")
@click.option(
    "--max-gap",
    type=float,
    default=None,
    help="Accept telemetry gaps up to this many seconds (default Ts).",
)
@click.option("--force", is_flag=True, help="Overwrite --out if it exists.")
@_friendly_errors
def export(record, fmt, out, Ts, max_gap, force):
    """Write a record as CSV, Parquet or MATLAB .mat, sampled at Ts.

    Columns: time_s, command, speed_rpm, acceleration_rpm_s, current_a.
    """
    from rwlab.testbed import load_record

    _check_folder(Path(out).parent)
    data = load_record(record, Ts, outputs=("speed", "acceleration", "current"), max_gap=max_gap)
    path = Path(out)
    if path.suffix.lower() != f".{fmt}":
        path = path.with_suffix(f".{fmt}") if not path.suffix else path
    data.write(path, overwrite=force, plain=True)
    click.echo(f"{path}: {data.N} samples at Ts = {data.Ts:g} s")


@main.command("monitor")
@click.argument("record", type=click.Path(dir_okay=False))
@click.option(
    "--host",
    default="127.0.0.1",
    show_default=True,
    help="Address to serve on (0.0.0.0 exposes it to the network).",
)
@click.option("--port", type=click.IntRange(1, 65535), default=5006, show_default=True)
@click.option("--replay", is_flag=True, help="Play a finished record back instead of following it.")
@click.option(
    "--speed",
    type=click.FloatRange(0, min_open=True),
    default=1.0,
    show_default=True,
    help="Replay speed factor.",
)
@_friendly_errors
def monitor_cmd(record, host, port, replay, speed):
    """Serve the live monitor page for a record that is being written (or replay one)."""
    from rwlab.errors import ConfigError
    from rwlab.testbed.monitor import check_port, serve

    if not host.strip():
        raise ConfigError("--host must name an address, e.g. 127.0.0.1")
    check_port(host, port)
    if replay:
        from rwlab.testbed import read_record

        read_record(record)  # a clear error now rather than a blank page later
    click.echo(f"rwlab monitor on http://{host}:{port}/ (Ctrl-C to stop)", err=True)
    try:
        serve(record, host=host, port=port, replay=replay, speed=speed)
    except KeyboardInterrupt:
        pass


@main.command("identify")
@click.argument("file")
@click.option("--out", type=click.Path(file_okay=False), required=True, help="Output folder.")
@click.option("--Ts", "Ts", type=float, help="Sample time, s (a record's own by default).")
@_columns_option
@click.option(
    "--preprocess",
    type=click.Choice(["normalize", "detrend", "none"]),
    default="normalize",
    show_default=True,
    help="normalize to [0, 1] (paper A) or remove means (MATLAB habit).",
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
    from rwlab.ident.study import identification_study, load_study_data, physical_model
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


# -- attitude control -----------------------------------------------------------------


@main.group()
def attitude() -> None:
    """GEO attitude control with reaction wheels (paper B): LQR, LQG, LQG/LTR."""
    _single_thread_blas()


def _single_thread_blas() -> None:
    """Pin BLAS to one thread: on 3×3 to 18×18 matrices its threads only wait for each
    other, and on a busy machine they make every Riccati solve ~7× slower (measured)."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")


_EPOCH = click.option(
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
@click.option("--duration", type=float, default=1800.0, show_default=True, help="Seconds.")
@click.option(
    "--wheel-model",
    type=click.Path(exists=True, dir_okay=False),
    help="model.json from `rwlab identify`: also fly it as the actuator.",
)
@click.option("--rho", type=float, default=0.7692, show_default=True, help="LTR ρ.")
@click.option("--seed", type=click.IntRange(min=0), default=None)
@click.option(
    "--relinearize",
    type=float,
    default=None,
    help="Re-design the LQR about the current state every this many seconds (paper B).",
)
@_EPOCH
@click.option("--force", is_flag=True, help="Overwrite outputs in --out.")
@_friendly_errors
def attitude_compare(scenario, out, duration, wheel_model, rho, seed, relinearize, epoch, force):
    """Run LQR, LQG and LQG/LTR on one scenario with the same noise; write report + metrics."""
    from rwlab.attitude.control import compare, ltr_study
    from rwlab.attitude.design import DesignError
    from rwlab.attitude.scenario import load_scenario
    from rwlab.errors import ConfigError
    from rwlab.report.attitude import check_outputs, write_comparison

    if not (math.isfinite(rho) and rho > 0):
        raise DesignError(f"--rho must be a positive number, got {rho:g}")
    _check_run(duration, relinearize)
    sc = load_scenario(scenario, **({"epoch": epoch} if epoch else {}))
    if wheel_model and sc.epoch:
        raise ConfigError("--epoch needs ideal wheels: it cannot be combined with --wheel-model")
    if wheel_model:
        from rwlab.wheel.identified import IdentifiedWheel

        IdentifiedWheel.from_json(wheel_model)  # a clear error now, not after the runs
    _check_folder(out)
    check_outputs(out, ["report.html", "metrics.json", "sigma.json"], force)
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
    paths = write_comparison(comp, out, force=force, ltr_result=ltr_study(sc))
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
    click.echo(f"wrote {', '.join(str(p) for p in paths.values())}")


@attitude.command("ltr")
@click.option("--scenario", default="geo-smallsat", show_default=True)
@click.option(
    "--rho",
    type=float,
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
    from rwlab.attitude.control import ltr_study
    from rwlab.attitude.scenario import load_scenario
    from rwlab.report.attitude import ltr_rows, write_ltr

    _check_folder(out)
    sc = load_scenario(scenario)
    res = ltr_study(sc, rhos=rho)
    paths = write_ltr(res, sc.name, out, force=force)
    click.echo("rho        gap 1e-3..1e-1 [dB]  gap to crossover [dB]  crossover / LQR [rad/s]")
    for rho, gap, gap_c, w, w_c in ltr_rows(res):
        click.echo(f"{rho:<10} {gap:19.2f} {gap_c:22.2f}  {w:.3g} / {w_c:.3g}")
    click.echo(f"wrote {', '.join(str(p) for p in paths.values())}")


def _check_run(duration: float, relinearize: float | None) -> None:
    from rwlab.errors import ConfigError

    if not (math.isfinite(duration) and duration > 0):
        raise ConfigError(f"--duration must be a positive number of seconds, got {duration:g}")
    if relinearize is not None and not (math.isfinite(relinearize) and relinearize > 0):
        raise ConfigError(
            f"--relinearize must be a positive number of seconds, got {relinearize:g}"
        )


@contextlib.contextmanager
def _steps_progress(steps: int, label: str, unit: str = "steps"):
    """A progress callback k ↦ …: a bar on a terminal, a line every 10 % otherwise."""
    if sys.stderr.isatty():
        with click.progressbar(length=max(steps, 1), label=label, file=sys.stderr) as bar:
            done = [0]

            def update(k):
                bar.update(k - done[0])
                done[0] = k

            yield update
        return
    shown = [0]

    def report(k):
        tenth = 10 * k // max(steps, 1)
        if tenth > shown[0]:
            shown[0] = tenth
            click.echo(f"{label}: {10 * tenth} % ({k} of {steps} {unit})", err=True)

    yield report


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
@click.option("--dt", type=float, help="Control and physics step, s (the scenario's by default).")
@click.option("--duration", type=float, required=True, help="Seconds.")
@click.option("--seed", type=click.IntRange(min=0), default=None)
@click.option("--rho", type=float, default=0.7692, show_default=True, help="LTR ρ (lqg_ltr).")
@click.option(
    "--relinearize", type=float, default=None, help="Re-design the LQR every this many seconds."
)
@_EPOCH
@click.option("--out", type=click.Path(file_okay=False), required=True)
@click.option("--force", is_flag=True, help="Overwrite outputs in --out.")
@_friendly_errors
def attitude_simulate(
    scenario, controller, estimator, dt, duration, seed, rho, relinearize, epoch, out, force
):
    """One controller on one scenario for any duration: metrics.json, trace.parquet, report.html."""
    from rwlab.attitude.control import fly
    from rwlab.attitude.scenario import load_scenario
    from rwlab.attitude.sim import disturbance_state
    from rwlab.errors import ConfigError
    from rwlab.report.attitude import check_outputs, write_simulation

    _check_run(duration, relinearize)
    overrides = {"dt": dt} if dt is not None else {}
    sc = load_scenario(scenario, **overrides, **({"epoch": epoch} if epoch else {}))
    _check_folder(out)
    check_outputs(out, ["metrics.json", "trace.parquet", "report.html"], force)
    steps = round(duration / sc.dt)
    if steps > 1e9:
        raise ConfigError(f"--duration {duration:g} s is {steps:.3g} steps: more than 1e9")
    log_every = max(10, -(-steps // 100_000))
    with _steps_progress(steps, f"{controller} on {sc.name}") as progress:
        run, metrics = fly(
            sc,
            controller,
            estimator=estimator,
            duration=duration,
            seed=seed,
            rho=rho,
            update_period=relinearize,
            log_every=log_every,
            progress=progress,
        )
    config = {
        "scenario": sc.name,
        "controller": controller,
        "estimator": estimator or ("truth" if controller in ("pd", "lqr") else "ekf"),
        "seed": sc.seed if seed is None else seed,
        "dt_s": sc.dt,
        "duration_s": duration,
        "rho": rho if controller == "lqg_ltr" else None,
        "relinearize_period_s": relinearize,
        "disturbances_known_to_filter": sc.disturbances_known_to_filter,
        "filter_disturbance_state": disturbance_state(sc) if controller.startswith("lqg") else None,
        "momentum_unloading": sc.momentum_unloading,
        "wheel_model": sc.wheel_model,
        "wheel_faults": list(sc.wheel_faults),
        "epoch": sc.epoch,
        "station_longitude_deg": sc.station_longitude_deg,
    }
    paths = write_simulation(run, metrics, config, sc, out, force=force)
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
    click.echo(f"wrote {', '.join(str(p) for p in paths.values())}")


@attitude.command("montecarlo")
@click.option("--scenario", default="geo-comsat", show_default=True)
@click.option("--runs", type=click.IntRange(min=1), required=True, help="Number of runs.")
@click.option("--duration", type=float, required=True, help="Seconds per run.")
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
@click.option("--out", type=click.Path(file_okay=False), required=True)
@click.option("--force", is_flag=True, help="Overwrite outputs in --out.")
@_friendly_errors
def attitude_montecarlo(
    scenario, runs, duration, controller, dispersions, workers, scheduler, seed, out, force
):
    """A Monte Carlo campaign on Dask: results.parquet, budget.json, report.html.

    Every run flies the controller (designed on the nominal scenario) on a
    scenario dispersed from its own seed, a child of --seed: a run is the same
    whatever the number of workers.
    """
    from rwlab.attitude.scenario import load_scenario
    from rwlab.campaign.dispersions import load_dispersions
    from rwlab.campaign.engine import dask_client
    from rwlab.campaign.montecarlo import Campaign, budget, check_runs, fly_run, run_campaign
    from rwlab.report.attitude import check_outputs
    from rwlab.report.campaign import CAMPAIGN_FILES, write_campaign

    _check_run(duration, None)
    sc = load_scenario(scenario)
    campaign = Campaign(sc, load_dispersions(dispersions), duration, controller, seed, runs)
    check_runs(campaign)  # before the cluster starts
    _check_folder(out)
    check_outputs(out, CAMPAIGN_FILES, force)
    where = scheduler or f"a local Dask cluster of {workers or 'one per core'} worker processes"
    click.echo(f"{runs} runs of {duration:g} s on {where} (workers load the loop)...", err=True)
    with (
        dask_client(workers, scheduler) as client,
        _steps_progress(runs, f"{controller} on {sc.name}", unit="runs") as progress,
    ):
        rows = run_campaign(campaign, client, progress=progress)
    stats = budget(rows, campaign)
    worst, _ = fly_run(campaign, stats["worst_seeds"][0]["seed"])
    paths = write_campaign(rows, stats, campaign, worst, out, force=force)
    click.echo(f"{'axis':<6} {'mean [°]':>10} {'std [°]':>10} {'99.73% [°]':>11} {'max [°]':>10}")
    for axis, s in stats["pointing_error_deg"].items():
        click.echo(
            f"{axis:<6} {s['mean']:10.4g} {s['std']:10.4g} {s['p99_73']:11.4g} {s['max']:10.4g}"
        )
    click.echo(
        f"meeting ±{sc.pointing_requirement_deg:g}°: {stats['meets_requirement_fraction']:.1%}"
    )
    click.echo(f"wrote {', '.join(str(p) for p in paths.values())}")


@main.command("demo")
@click.option("--out", type=click.Path(file_okay=False), default="rwlab-demo", show_default=True)
@click.option("--realtime", is_flag=True, help="Run the experiments on the wall clock (slow).")
@click.option("--monitor", is_flag=True, help="Serve the live monitor during the experiments.")
@click.option("--quick", is_flag=True, help="Shortened records and runs (a quick look).")
@click.option("--force", is_flag=True, help="Overwrite a previous demo in --out.")
@_friendly_errors
def demo(out, realtime, monitor, quick, force):
    """The whole system: test a simulated wheel, identify it, fly it on a GEO satellite.

    Writes OUT/index.html (start here) and OUT/summary.json.
    """
    import dataclasses

    from rwlab.demo import DemoConfig, run_demo

    _single_thread_blas()
    _check_folder(out)
    cfg = DemoConfig.quick() if quick else DemoConfig()
    cfg = dataclasses.replace(cfg, realtime=realtime, monitor=monitor)

    def progress(label, n):
        return click.progressbar(length=n, label=f"  {label}", show_eta=True, file=sys.stderr)

    try:
        with _stop_signals():
            summary = run_demo(
                out, cfg, force=force, echo=lambda t: click.echo(t, err=True), progress=progress
            )
    except KeyboardInterrupt as exc:
        why = exc.args[0] if exc.args else "Ctrl-C"
        click.echo(f"\ninterrupted ({why}): the wheel is idle and every record is closed", err=True)
        sys.exit(130)
    cm = summary["chosen_model"]
    click.echo(f"wheel model: {cm['structure']} (validation fit {cm['fit_percent']:.2f} %)")
    for name, m in summary["controllers"].items():
        click.echo(f"  {name:<24} steady max error {m['steady_max_error_deg']:.4f} deg")
    click.echo(f"open {Path(out) / 'index.html'}")


if __name__ == "__main__":  # pragma: no cover
    main()
