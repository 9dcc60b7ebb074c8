"""The ``rwlab identify`` workflows, callable from Python with the command's arguments.

:func:`identify` runs paper A's study on one record and writes its folder
(``report.html``, ``study.json``, ``model.json`` with the healthy reference of
the fault diagnosis when the record is a testbed record); :func:`identify_fleet`
does it for every record of a folder on a Dask cluster, one study folder per
record, and writes ``fleet.json`` and ``fleet.html``. Both write their output
folder whole or not at all, and refuse a second run on it at once
(:func:`rwlab._io.output_folder`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rwlab._io import output_folder
from rwlab.errors import ConfigError, NoModelFitsError, RwlabError

__all__ = [
    "RECORD_SUFFIXES",
    "STUDY_FILES",
    "fleet_records",
    "identify",
    "identify_fleet",
    "identify_into",
]

STUDY_FILES = ("report.html", "study.json", "model.json")
#: The files ``identify_fleet`` takes from a folder (partial records are left out).
RECORD_SUFFIXES = (".mcap", ".csv", ".parquet", ".mat", ".dat", ".txt")


def identify(
    file: str | os.PathLike,
    out: str | os.PathLike,
    *,
    Ts: float | None = None,
    input_col: str | None = None,
    output_col: str | None = None,
    preprocess: str = "detrend",
    split: float = 0.7,
    tolerance: float = 3.0,
    gaps: str = "refuse",
    gain_tolerance: float = 2.0,
    nonlinear_models: bool = False,
    force: bool = False,
    progress: Callable[[int, int, str], None] | None = None,
    echo: Callable[[str], None] | None = None,
) -> tuple[dict, dict[str, Path]]:
    """Paper A's identification study on one record, written into the folder ``out``.

    Parameters
    ----------
    file : str or os.PathLike
        A testbed record (.mcap) or a data file (.csv, .dat, .parquet, .mat).
    out : str or os.PathLike
        The output folder (locked while the study runs; written whole or not at all).
    Ts : float, optional
        Sample time, s (a record's own by default).
    input_col, output_col : str, optional
        Columns or .mat variables (records: command and speed_rpm).
    preprocess : {'detrend', 'scale', 'normalize', 'none'}
        See :func:`rwlab.ident.study.identification_study`.
    split : float
        Estimation share, in (0, 1).
    tolerance : float
        Fit points within which the simplest model is chosen.
    gaps : {'refuse', 'split'}
        A record with telemetry gaps: refuse it, or split it at the gaps into segments
        identified as separate experiments merged (MATLAB ``merge(iddata)``).
    gain_tolerance : float
        Percent within which the chosen model's DC gain must match the steady-state gain
        measured on the record's settled holds.
    nonlinear_models : bool
        Also fit the grey-box wheel and the NLARX (see
        :func:`rwlab.ident.study.identification_study`; the servo model is always fitted).
    force : bool
        Replace a previous study in ``out`` (only when this one succeeds).
    progress : callable, optional
        ``progress(done, total, stage)`` after each stage.
    echo : callable, optional
        ``echo(line)`` for what the study notes on the way (the data, a missing
        healthy reference).

    Returns
    -------
    study : dict
        Every number of ``study.json``.
    paths : dict of str to Path
        The files written, by name (in ``out``).

    Raises
    ------
    NoModelFitsError
        When even the best model's validation fit is negative: the folder is written
        all the same, and the error carries ``study`` and ``paths``.
    """
    with output_folder(out, STUDY_FILES, force=force, what="identification study") as stage:
        study, paths = identify_into(
            file,
            stage,
            progress=progress,
            echo=echo,
            Ts=Ts,
            input_col=input_col,
            output_col=output_col,
            preprocess=preprocess,
            split=split,
            tolerance=tolerance,
            gaps=gaps,
            gain_tolerance=gain_tolerance,
            nonlinear_models=nonlinear_models,
            force=force,
        )
    paths = {name: Path(out) / Path(p).name for name, p in paths.items()}
    if study.get("no_model_fits"):
        raise NoModelFitsError(
            f"{file}: no model fits: the best validation fit is "
            f"{study['best_fit_percent']:.2f} %, worse than the validation output's mean; the "
            f"study is in {out} (report.html says what was tried). Record an experiment that "
            "excites the system within its linear range, or check the input and output columns",
            study=study,
            paths=paths,
        )
    return study, paths


def identify_into(
    file: str | os.PathLike,
    folder: str | os.PathLike,
    *,
    progress: Callable[[int, int, str], None] | None = None,
    echo: Callable[[str], None] | None = None,
    **options: Any,
) -> tuple[dict, dict[str, Path]]:
    """The study of one record written straight into ``folder`` (no lock, no staging).

    Parameters
    ----------
    file : str or os.PathLike
        The record.
    folder : str or os.PathLike
        Where the files go (a staging folder the caller publishes).
    progress, echo : callable, optional
        As in :func:`identify`.
    **options
        ``Ts``, ``input_col``, ``output_col``, ``preprocess``, ``split``,
        ``tolerance``, ``gaps``, ``gain_tolerance``, ``nonlinear_models``, ``force`` as
        in :func:`identify`.

    Returns
    -------
    study : dict
        Every number of ``study.json``.
    paths : dict of str to Path
        The files written, by name.
    """
    from threadpoolctl import threadpool_limits

    # BLAS on one thread: the study's matrices are at most a few thousand by ten, where
    # BLAS threads only wait for each other; on a busy machine one SVD of the fits took
    # 250 ms threaded against 2 ms on one thread (measured), and the numbers agree to
    # round-off (1 ulp in one standard deviation of study.json)
    with threadpool_limits(1, user_api="blas"), contextlib.ExitStack() as stack:
        return _identify_into(file, folder, stack, progress=progress, echo=echo, **options)


def _identify_into(
    file, folder, stack, *, progress, echo, **options
) -> tuple[dict, dict[str, Path]]:
    """:func:`identify_into`'s work (``stack`` ends the child that draws figures, on an
    error)."""
    from rwlab.ident.study import load_current, load_study_data
    from rwlab.ident.study import wheel_model as make_wheel_model
    from rwlab.report.html import FigureQueue
    from rwlab.report.identification import write_study

    # the child that fits the servo model and draws, forked first: it starts what its
    # work needs (_warm_child) while this process reads the record
    queue = stack.enter_context(
        FigureQueue(_linear_makers, first=_nonlinear_part, warm=_warm_child)
    )
    Ts, gaps = options["Ts"], options.get("gaps", "refuse")
    file = str(file)
    record, reader = _read_once(file)
    data, saturation = load_study_data(
        file,
        Ts,
        input_col=options["input_col"],
        output_col=options["output_col"],
        gaps=gaps,
        reader=reader,
    )
    segments = None
    if gaps == "split" and record is not None:
        from rwlab.testbed.load import gap_free_segments

        segments = gap_free_segments(record, data.Ts)
    if echo is not None:  # the data are shown once the study accepts them (a refusal: one line)
        progress = _after_first(progress, lambda: echo(f"data: {data!r}"))
    datasheet = None
    spec = saturation.get("wheel_spec")
    if "current_limit_a" in saturation:
        from rwlab.ident.study import wheel_datasheet

        datasheet = {  # the record's wheel model, else the RW90's (records before specs)
            **(wheel_datasheet(spec) if spec is not None else {}),
            "current_limit": saturation["current_limit_a"],
            "max_speed_rpm": saturation["speed_limit_rpm"],
            "accel_limit_rpm_s": saturation["accel_limit_rpm_s"],
        }
    model_options = {
        "speed_limit_rpm": saturation["speed_limit_rpm"],
        "accel_limit_rpm_s": saturation["accel_limit_rpm_s"],
        "saturation_source": saturation["saturation_source"],
        "wheel_spec": spec,
    }
    result, reference, drawn = _study_while_drawing(
        queue,
        data,
        stack,
        progress,
        {"reference_data": _reference_data(file, record, data.Ts), "model_options": model_options},
        preprocess=options["preprocess"],
        split=options["split"],
        tolerance=options["tolerance"],
        gain_tolerance=options.get("gain_tolerance", 2.0) / 100.0,
        limits_rpm=(saturation["speed_limit_rpm"],) * 2,
        datasheet=datasheet,
        current=load_current(file, Ts, gaps=gaps, reader=reader),
        segments=segments,
        nonlinear_models=options.get("nonlinear_models", False),
    )
    model = make_wheel_model(result, **model_options)  # the owner class
    if isinstance(reference, dict):
        model = dataclasses.replace(model, healthy_reference=reference)
    elif echo is not None:
        advice = (
            "identify the testbed record (.mcap) this data came from"
            if reference == NOT_A_RECORD
            else "identify a longer or richer healthy record"
        )
        echo(
            f"warning: no healthy reference for fault diagnosis ({reference}); rwlab "
            f"diagnose refuses this model: {advice}"
        )
    paths = write_study(result, model, folder, force=options["force"], drawn=drawn)
    study = result.to_dict()
    study["data"]["output_unit"] = data.output_units[0]  # for the messages only
    study["healthy_reference"] = (  # for the messages only: model.json holds the reference
        {"stored": True, "samples": reference["samples"]}
        if isinstance(reference, dict)
        else {"stored": False, "why": reference}
    )
    return study, paths


def _study_while_drawing(queue, data, stack, progress, job, **options):
    """The study, its nonlinear stage run in the child of ``queue``
    (:class:`rwlab.report.html.FigureQueue`) while this process draws the report's
    figures of the linear study: the servo fit is most of the stage's time and drawing
    most of the report's, side by side on two cores. The child gets the linear study
    and ``job`` (the record's samples and what the wheel model needs), fits the servo model,
    draws its figures and measures the healthy reference (:func:`_nonlinear_part`);
    then each process draws the linear figures the other has not reached.

    Returns the study, the healthy reference (or why there is none) and every figure's
    PNG by id; ``options`` are :func:`rwlab.ident.study.identification_study`'s, and
    ``progress`` is told of the same stages. ``stack`` ends the child on an error.
    """
    from threadpoolctl import threadpool_limits

    from rwlab.ident.study import identification_study

    keys = ("limits_rpm", "datasheet", "current", "nonlinear_models")
    later = {key: options.pop(key) for key in keys}
    total: list[int] = []

    def linear_progress(done: int, stages: int, label: str) -> None:  # one stage to come
        total[:] = [stages + 1]
        if progress is not None:
            progress(done, stages + 1, label)

    linear = identification_study(data, nonlinear=False, progress=linear_progress, **options)
    # SciPy's own OpenBLAS loads with the study's imports, after identify_into's limit, so
    # it runs a thread per core: from here on one, as the servo fit and the drawing need
    # the cores (measured: 1–1.5 s less CPU, the same bytes written; the linear study
    # keeps them, as one thread there moves one standard deviation of study.json by 1 ulp)
    stack.enter_context(threadpool_limits(1, user_api="blas"))
    queue.start({**job, "linear": linear, "data": data, "split": options["split"], "later": later})
    drawn = queue.result()
    (servo, nl, grey, black), reference, nonlinear_pngs = queue.first
    if progress is not None:
        progress(total[0], total[0], "nonlinear")
    result = dataclasses.replace(linear, servo=servo, nonlinear=nl, greybox=grey, nlarx=black)
    return result, reference, drawn | nonlinear_pngs


def _linear_makers(job: dict) -> dict:
    """The makers of the linear study's figures (``job`` as :func:`_nonlinear_part`'s)."""
    from rwlab.report.study_figures import linear_makers

    return linear_makers(job["linear"], job["linear"].to_dict())


def _nonlinear_part(job: dict) -> tuple[tuple, dict | str, dict[str, bytes]]:
    """The child's work: the study's nonlinear stage, the servo model's figures and the
    healthy reference. ``job``: the linear study, its data and split, the nonlinear
    stage's options, the record sampled for the reference and the wheel model's
    options."""
    from rwlab.ident.study import nonlinear_stage
    from rwlab.ident.study import wheel_model as make_wheel_model
    from rwlab.report.html import render_pngs
    from rwlab.report.study_figures import nonlinear_makers

    result = nonlinear_stage(job["linear"], job["data"], split=job["split"], **job["later"])
    makers = {} if result.servo is None else nonlinear_makers(result)
    figures = [make() for make in makers.values()]
    pngs = dict(zip(makers, render_pngs(figures, processes=1), strict=True))
    stages = (result.servo, result.nonlinear, result.greybox, result.nlarx)
    model = make_wheel_model(result, **job["model_options"])
    return stages, _healthy_reference(job["reference_data"], model), pngs


def _warm_child() -> None:
    """What the figure child does while this process reads the record and runs the
    linear study: BLAS on one thread (as :func:`_study_while_drawing` sets it here), the
    healthy reference's imports, and numba's start, which a process's first compiled
    call pays (≈ 0.2 s, measured), with the servo fit's compiled simulation."""
    from threadpoolctl import threadpool_limits

    import rwlab.diagnose  # noqa: F401  (SciPy's BLAS is loaded already: the study's imports)
    from rwlab.ident.nonlinear import load_kernels

    threadpool_limits(1, user_api="blas")
    load_kernels()


def _read_once(file: str):
    """A testbed record decoded once, and a reader that samples it (for
    :func:`rwlab.ident.study.load_study_data`); (None, None) for any other file. The
    study, the motor current, the gap-free segments and the healthy reference all
    sample the one decoded record: decoding is most of a record's read."""
    if Path(file).suffix.lower() != ".mcap" or not Path(file).is_file():
        return None, None  # a missing file is refused by load_study_data, as any file
    from rwlab.testbed.load import read_mcap
    from rwlab.testbed.record import read_record

    record = read_record(file)
    return record, functools.partial(read_mcap, record)


def _after_first(progress, first: Callable[[], None]):
    """``progress`` that calls ``first()`` before its first report."""
    done: list[bool] = []

    def report(*args) -> None:
        if not done:
            done.append(True)
            first()
        if progress is not None:
            progress(*args)

    return report


NOT_A_RECORD = "not a testbed record (.mcap with motor current)"


def _reference_data(file: str, record, Ts: float):
    """The record sampled for the healthy reference (``record``: decoded already, else
    read from ``file``) at the study's ``Ts``, or why there is none."""
    import numpy as np

    from rwlab.diagnose.features import RECORD_OUTPUTS
    from rwlab.testbed.load import load_record

    if Path(file).suffix.lower() != ".mcap":
        return NOT_A_RECORD
    try:
        return load_record(
            file if record is None else record, Ts, outputs=RECORD_OUTPUTS, max_gap=np.inf
        )
    except RwlabError as exc:
        return _message(exc)


def _healthy_reference(data, model) -> dict | str:
    """The healthy reference measured on ``data`` (:func:`_reference_data`) with the
    wheel model ``model``, or why there is none."""
    from rwlab.diagnose import healthy_reference
    from rwlab.wheel import IdentifiedWheel

    if isinstance(data, str):
        return data
    try:
        wheel = IdentifiedWheel.from_file(model)
        # the data's name: the file's, and says so where the record was salvaged
        return healthy_reference(data, wheel, source=data.name).to_dict()
    except RwlabError as exc:
        return _message(exc)


def _message(exc: BaseException) -> str:
    """One line for an error (an OS error names its file)."""
    if isinstance(exc, OSError) and exc.strerror:
        return f"{exc.filename}: {exc.strerror}" if exc.filename is not None else exc.strerror
    return " ".join(str(exc).split()) or type(exc).__name__


def fleet_records(folder: str | os.PathLike) -> list[Path]:
    """The records of a fleet folder, sorted; their names must differ (one study each).

    Parameters
    ----------
    folder : str or os.PathLike
        A folder of records.

    Returns
    -------
    list of Path
    """
    folder = Path(folder)
    records = sorted(
        p
        for p in folder.iterdir()
        if p.is_file()
        and p.suffix.lower() in RECORD_SUFFIXES
        and not p.name.endswith(".partial.mcap")
    )
    if not records:
        raise ConfigError(f"{folder}: no records ({', '.join(RECORD_SUFFIXES)}) in the folder")
    stems = [p.stem for p in records]
    twins = sorted({s for s in stems if stems.count(s) > 1})
    if twins:
        raise ConfigError(f"{folder}: records {twins} share a name; their studies would collide")
    return records


def _identify_batch(jobs: list[tuple[str, str]], options: dict) -> list[dict]:
    """One fleet line per (record, study folder): its chosen model, or why it failed."""
    lines = []
    for record, out in jobs:
        line: dict[str, Any] = {"record": Path(record).name, "study": Path(out).name}
        line |= {"error": None, "nk": None, "structure": None, "fit_percent": None}
        try:
            study, _ = identify_into(record, out, **options)
        except (RwlabError, OSError) as exc:
            line["error"] = _message(exc)
        else:
            chosen = study["chosen"]
            line |= {
                "nk": study["delay"]["nk"],
                "structure": chosen["structure"],
                "fit_percent": chosen["fit_percent"],
            }
            if study.get("no_model_fits"):
                line["error"] = f"no model fits: best fit {study['best_fit_percent']:.2f} %"
        lines.append(line)
    return lines


def identify_fleet(
    folder: str | os.PathLike,
    out: str | os.PathLike,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    progress: Callable[[int], None] | None = None,
    **options: Any,
) -> tuple[list[dict], dict[str, Path]]:
    """Every record of ``folder`` studied on a Dask cluster, and the fleet's summary.

    Parameters
    ----------
    folder : str or os.PathLike
        A folder of records (a wheel fleet's acceptance tests).
    out : str or os.PathLike
        The output folder: ``OUT/<record name>/`` per record, ``fleet.json`` and
        ``fleet.html`` (locked while it runs; written whole or not at all).
    workers : int, optional
        Processes of a new local Dask cluster (default: the cores).
    scheduler : str, optional
        Address of a running Dask scheduler, e.g. ``tcp://host:8786``.
    force : bool
        Replace a previous output in ``out`` (only when this run succeeds).
    progress : callable, optional
        ``progress(done)``: records finished so far.
    **options
        ``Ts``, ``input_col``, ``output_col``, ``preprocess``, ``split``,
        ``tolerance``, ``gaps``, ``gain_tolerance``, ``nonlinear_models`` as in
        :func:`identify`.

    Returns
    -------
    lines : list of dict
        Per record: ``record``, ``study``, ``nk``, ``structure``, ``fit_percent``
        and ``error`` (None, or why its study failed; the others are still written).
    paths : dict of str to Path
        ``fleet.json`` and ``fleet.html`` in ``out``.
    """
    from rwlab.campaign.engine import dask_client, map_batches
    from rwlab.report.campaign import FLEET_FILES, write_fleet

    records = fleet_records(folder)
    options = {
        "Ts": None,
        "input_col": None,
        "output_col": None,
        "preprocess": "detrend",
        "split": 0.7,
        "tolerance": 3.0,
        "gaps": "refuse",
        "gain_tolerance": 2.0,
        "nonlinear_models": False,
        **options,
        "force": force,
    }
    names = [*FLEET_FILES, *(p.stem for p in records)]
    with output_folder(out, names, force=force, what="fleet identification") as stage:
        jobs = [[(str(p), str(stage / p.stem))] for p in records]
        with dask_client(workers, scheduler) as client:
            lines = map_batches(client, _identify_batch, jobs, options, progress=progress)
        paths = write_fleet(lines, stage, force=force)
    return lines, {name: Path(out) / Path(p).name for name, p in paths.items()}
