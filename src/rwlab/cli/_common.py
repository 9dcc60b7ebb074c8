"""Plumbing shared by the ``rwlab`` command groups, and the ``main`` group."""

from __future__ import annotations

import contextlib
import functools
import json
import re
import sys
import threading
from pathlib import Path
from typing import NoReturn

import click

from rwlab import __version__
from rwlab.errors import ConfigError, RwlabError
from rwlab.interrupts import check_stop, clear, stop, stopped, uninterrupted

#: How the library names a parameter in a message → the flag the command line has for it.
FLAGS = {
    "force=True": "--force",
    "force_wheel=True": "--force-wheel",
    # testbed.record.SALVAGE_ADVICE (a test holds them equal)
    "pass salvage=True to read up to the damage (a workflow: call it within "
    "rwlab.testbed.record.salvaging())": "pass --salvage to read up to the damage",
    "max_gap=": "--max-gap",
    "node=": "--node",
    "input_columns=": "--input",
    "output_columns=": "--output",
    "raw_frames": "--raw-frames",
    "rt_priority": "--rt-priority",
    "realtime=True": "--realtime",
    "resume=True": "--resume",
    "steady_after": "--steady-after",
    "workers=": "--workers",
    "scheduler=": "--scheduler",
    "epoch_spread_days": "--epoch-spread-days",
    # the wheel client's advice, in the command line's words
    "call clear_fault()": "clear it (rwlab wheel cmd clear)",
    ", or (in Python) study lower orders (orders=, nk_max=)": "",  # no such flag
}
# not a quoted name: a config file's key (['raw_frames', ...]) is no flag
_PARAMETER = re.compile(
    r"(?<!['\"])\b("
    + "|".join(re.escape(k) + ("(?!\\w)" if k[-1].isalnum() or k[-1] == "_" else "") for k in FLAGS)
    + ")"
)


def _message(exc: BaseException) -> str:
    """One line for an error a user caused (an OS error names its file); the library's
    parameters are named by their flags."""
    if isinstance(exc, OSError) and exc.strerror:
        where = exc.filename if exc.filename is not None else ""
        return f"{where}: {exc.strerror}" if where else exc.strerror
    return _flags(" ".join(str(exc).split()) or type(exc).__name__)


def _flags(text: str) -> str:
    """``text`` with the library's parameters named by their command-line flags."""
    return _PARAMETER.sub(lambda m: FLAGS[m.group(1)], text)


def _only_with(option: str, applies: bool, when: str) -> None:
    """Refuse ``option`` given on the command line where it would have no effect.

    ``option`` is the parameter's name (``"rho"``); ``when`` says where it applies
    (``"with --controller lqg_ltr"``). Defaults never count as given.
    """
    from click.core import ParameterSource

    source = click.get_current_context().get_parameter_source(option)
    if not applies and source not in (None, ParameterSource.DEFAULT, ParameterSource.DEFAULT_MAP):
        raise ConfigError(f"--{option.replace('_', '-')} applies only {when}")


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
            _refuse_empty_paths(sys.argv[1:] if args is None else list(args))
            with _stop_signals(), _one_line_warnings():
                return super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click.UsageError as exc:
            where = f"{exc.ctx.command_path}: " if exc.ctx is not None else ""
            hint = f" (see {exc.ctx.command_path} --help)" if exc.ctx is not None else ""
            _fail(RwlabError(f"{where}{exc.format_message()}{hint}"))
        except click.ClickException as exc:
            _fail(RwlabError(exc.format_message()))
        except (RwlabError, OSError) as exc:
            _fail(exc)
        except click.Abort as exc:
            cause = exc.__cause__ or exc.__context__
            why = cause.args[0] if isinstance(cause, KeyboardInterrupt) and cause.args else ""
            click.echo(_flags(f"interrupted{f' ({why})' if why else ''}"), err=True)
            sys.exit(130)


#: Options that name a file or folder: an empty value would mean the current folder.
PATH_OPTIONS = (
    "--out",
    "--save",
    "--file",
    "--model",
    "--wheel-model",
    "--scenario",
    "--config",
    "--dispersions",
    "--params",
)


def _refuse_empty_paths(args: list[str]) -> None:
    """``--out ''`` (or ``--out=``): refused before any work, naming the option."""
    for k, arg in enumerate(args):
        name, eq, value = arg.partition("=")
        if name not in PATH_OPTIONS:
            continue
        if eq:
            empty = not value.strip()
        else:
            empty = k + 1 < len(args) and not args[k + 1].strip()
        if empty:
            raise ConfigError(f"{name} is empty: give it a file or folder name")


def _one_line_warning(message, category, *_args, **_kwargs) -> None:
    """Show a warning as ``warning: message`` on stderr (no file, line or source)."""
    click.echo(f"warning: {' '.join(str(message).split())}", err=True)


@contextlib.contextmanager
def _one_line_warnings():
    """While a command runs, every Python warning is one ``warning:`` line."""
    import warnings

    with warnings.catch_warnings():
        warnings.showwarning = _one_line_warning
        yield


@contextlib.contextmanager
def _imports_uninterrupted():
    """A stop signal waits for the block's imports to end, then takes effect.

    A KeyboardInterrupt raised inside an import leaves a half-imported module
    (measured: numpy's lazy f2py, an encodings module), after which the run went
    on, or the interpreter ended by SIGINT instead of exit status 130.
    """
    with uninterrupted():
        yield
    check_stop()


@contextlib.contextmanager
def _stop_signals():
    """Ctrl-C, SIGTERM and SIGHUP stop a run alike (KeyboardInterrupt), never inside a
    bus read or write, an import or the publishing of outputs
    (:func:`rwlab.interrupts.uninterrupted`).

    So ``kill`` or a closed terminal also idles the wheel, closes the record and
    stops the monitor. Only the first signal stops; a later SIGTERM or SIGHUP is
    ignored so that the clean-up it would cut short can finish, a later Ctrl-C
    interrupts at once (a user's way out of a clean-up that hangs).
    """
    import signal

    stops = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    clear()

    def ignore(signum, frame):
        """Not SIG_IGN: a signal already pending when the handler changes to SIG_IGN
        raises OSError ("ignored due to race condition") wherever the run then is."""

    def interrupt(signum, frame):
        for s in stops:
            signal.signal(s, signal.default_int_handler if s == signal.SIGINT else ignore)
        stop(signal.Signals(signum).name)

    def unraisable(info):
        """A stop raised inside a C callback (numba's compiler calls back into Python) is
        swallowed there and printed as a traceback: say nothing, the command's next
        :func:`check_stop` raises it again."""
        if not (isinstance(info.exc_value, KeyboardInterrupt) and stopped()):
            hook(info)

    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set from the main thread
        return
    previous = {s: signal.signal(s, interrupt) for s in stops}
    hook, sys.unraisablehook = sys.unraisablehook, unraisable
    try:
        yield
    finally:
        sys.unraisablehook = hook
        for s, handler in previous.items():
            signal.signal(s, handler)


class Number(click.ParamType):
    """A finite number within bounds: NaN, ±inf and absurd magnitudes are refused here.

    ``click.FloatRange`` lets NaN through (every comparison with NaN is false)
    and has no notion of "too large to mean anything"; this type says which
    values an option takes in its error, e.g. ``--rho: nan is not a number in
    (0, 1e+06]``. ``allow_inf`` admits +inf ("no limit").
    """

    name = "number"

    def __init__(self, low=None, high=None, *, low_open=False, high_open=False, allow_inf=False):
        self.low, self.high = low, high
        self.low_open, self.high_open, self.allow_inf = low_open, high_open, allow_inf

    def _range(self) -> str:
        lo = "(" if self.low_open else "["
        hi = ")" if self.high_open else "]"
        low = "-inf" if self.low is None else f"{self.low:g}"
        high = "inf" if self.high is None or self.allow_inf else f"{self.high:g}"
        return f"{lo}{low}, {high}{hi}"

    def convert(self, value, param, ctx):
        import math

        try:
            x = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        ok = not math.isnan(x) and (math.isfinite(x) or (self.allow_inf and x == math.inf))
        if ok and self.low is not None:
            ok = x > self.low if self.low_open else x >= self.low
        if ok and self.high is not None and not (self.allow_inf and x == math.inf):
            ok = x < self.high if self.high_open else x <= self.high
        if not ok:
            bounded = self.low is not None or self.high is not None
            where = f" in {self._range()}" if bounded else ""
            self.fail(f"{value} is not a finite number{where}", param, ctx)
        return x


SECONDS = Number(0, 1e9, low_open=True)  # > 0 and below 30 years
POSITIVE = Number(0, 1e6, low_open=True)


@contextlib.contextmanager
def _steps_progress(steps: int, label: str, unit: str = "steps"):
    """A progress callback k ↦ … (k: steps done so far): a bar on a terminal, otherwise a
    line each time k passes another tenth of ``steps``, with k's own percentage (2 of 12
    is 16 %, not the tenth's 10 %)."""
    if sys.stderr.isatty():
        with click.progressbar(length=max(steps, 1), label=label, file=sys.stderr) as bar:
            done = [0]

            def update(k):
                check_stop()
                bar.update(k - done[0])
                done[0] = k

            yield update
        return
    shown = [0]

    def report(k):
        check_stop()
        tenth = 10 * k // max(steps, 1)
        if tenth > shown[0]:
            shown[0] = tenth
            click.echo(f"{label}: {100 * k // max(steps, 1)} % ({k} of {steps} {unit})", err=True)

    yield report


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


@contextlib.contextmanager
def _output(
    out, names, force: bool, what: str = "rwlab run", *, replace_previous=False, keep_failed=False
):
    """The command's output folder, locked now and written whole or not at all.

    ``with _output(out, FILES, force, "simulation") as stage:`` around the whole
    command: a second run on ``out`` is refused at once, the files are written
    into ``stage`` and appear in ``out`` only when the block succeeds (see
    :func:`rwlab._io.output_folder`).
    """
    from rwlab._io import output_folder

    _check_folder(Path(out).absolute().parent)
    with output_folder(
        out,
        names,
        force=force,
        replace_previous=replace_previous,
        what=what,
        keep_failed=keep_failed,
    ) as stage:
        yield stage
        check_stop()  # a stop whose exception was lost: the outputs are not published


def _wrote(out, paths) -> str:
    """The "wrote …" line naming the files in ``out`` (not the staging folder)."""
    return "wrote " + ", ".join(str(Path(out) / Path(p).name) for p in paths)


#: --force-wheel, for the commands that fly a scenario's wheels (refused when they do not fit).
FORCE_WHEEL_OPTION = click.option(
    "--force-wheel",
    is_flag=True,
    help="Fly a wheel model that cannot deliver the scenario's torque, momentum or speed "
    "(else refused, exit 2); the report's first screen says what it lacks.",
)


def _flight_output_options(func):
    """--out, --force, --force-wheel: the folder a flight's outputs go to, whether they may
    replace what is there, and whether wheels that do not fit the scenario fly anyway."""
    func = FORCE_WHEEL_OPTION(func)
    func = click.option("--force", is_flag=True, help="Overwrite outputs in --out.")(func)
    return click.option("--out", type=click.Path(file_okay=False), required=True)(func)


def _salvage_option(func):
    """--salvage: a damaged record is read up to its damage instead of refused
    (:func:`rwlab.testbed.record.salvaging`, for every record the command reads)."""

    def turn_on(ctx: click.Context, _param, value: bool) -> bool:
        if value:
            from rwlab.testbed.record import salvaging

            ctx.with_resource(salvaging())
        return value

    return click.option(
        "--salvage",
        is_flag=True,
        expose_value=False,
        callback=turn_on,
        help="Read a damaged record up to its damage instead of refusing it "
        "(every output then says it was salvaged).",
    )(func)


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
            "--Ts", "Ts", type=POSITIVE, help="Sample time in seconds (when the file has none)."
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
        _salvage_option,
    ]
    for option in reversed(options):
        func = option(func)
    return func


def _load(file, Ts, input_col, output_col, detrend="none", normalize=False):
    """A bundled data set by name, or any file rwlab reads (.mcap records included)."""
    from rwlab import datasets
    from rwlab.data import load
    from rwlab.datafiles import check_magnitude

    if not Path(file).exists() and file in datasets.NAMES:
        if input_col or output_col:
            raise ConfigError(f"{file} is a bundled data set: it has one input and one output")
        data = datasets.get(file)
    else:
        data = load(file, Ts, input_columns=input_col, output_columns=output_col)
    check_magnitude(data, file)
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


def run() -> None:
    """The ``rwlab`` command as a process (the console script, ``python -m rwlab``):
    :func:`main`, then an exit that leaves what is still alive to the operating system.

    At exit the interpreter collects every object still alive, and finalising numba's
    compiled code and the plotting and fitting libraries' caches took 0.2–0.5 s of each
    command's wall time (measured: ``ident arx`` 2.1 → 1.8 s, ``identify`` 4.7 → 4.2 s
    on a 25-minute record). Frozen (``gc.freeze``) they are not collected: their memory
    goes back with the process. Every file rwlab writes is closed before a command ends.
    """
    import gc

    try:
        main(prog_name="rwlab")
    finally:
        gc.freeze()


@click.group(cls=_Cli, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="rwlab")
def main() -> None:
    """rwlab: test a reaction wheel, identify it, and control a satellite with it."""
