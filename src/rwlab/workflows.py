"""The workflows a Python user calls, each one function (``rwlab.identify`` …).

They are the command line's workflows without the command line: the same checks,
the same files. ``import rwlab`` loads none of them until first use.

- :func:`identify` — paper A's identification study on a record (``rwlab identify``).
- :func:`diagnose` — fault detection on a record with an identified model.
- :func:`simulate` — one controller on a scenario, the wheels from a spec or a model.json.
- :func:`montecarlo` — a Monte Carlo pointing campaign (``rwlab attitude montecarlo``).
- :func:`hil` — the satellite on the host, its wheels on a bus (``rwlab hil``).
"""

from __future__ import annotations

import os
from typing import Any

__all__ = ["diagnose", "hil", "identify", "montecarlo", "simulate"]


def identify(file: str | os.PathLike, out: str | os.PathLike, **options: Any):
    """Paper A's identification study on a record, written into the folder ``out``.

    Parameters
    ----------
    file : str or os.PathLike
        A testbed record (``.mcap``) or a data file.
    out : str or os.PathLike
        The output folder: ``model.json`` (with the record's wheel spec), ``study.json``,
        ``report.html``.
    **options
        As :func:`rwlab.report.identify.identify` (``Ts``, ``preprocess``, ``force`` …).

    Returns
    -------
    study : dict
        ``study.json``'s content.
    paths : dict of str to Path
        The files written.
    """
    from rwlab.report.identify import identify as run

    return run(file, out, **options)


def diagnose(
    record: str | os.PathLike,
    model: str | os.PathLike,
    *,
    calibration: str | os.PathLike | None = None,
    false_alarms_per_hour: float = 1e-3,
):
    """Detect, name and size wheel faults in a record with an identified model: the GLR
    pipeline (:mod:`rwlab.diagnose.pipeline`), as ``rwlab diagnose``.

    Parameters
    ----------
    record : str or os.PathLike
        A speed-mode testbed record (``.mcap``).
    model : str or os.PathLike
        The ``model.json`` ``rwlab identify`` wrote (with its healthy reference).
    calibration : str or os.PathLike, optional
        A ``calibration.json`` of ``rwlab diagnose calibrate`` (the wheel's own healthy
        records); default: the twin calibration of the model's wheel preset
        (:func:`rwlab.diagnose.wheel_calibration.model_calibration_file`).
    false_alarms_per_hour : float
        Asked of each detector.

    Returns
    -------
    Result
        The verdict, each event (fault, size, 95 % interval, runner-up) and the faults
        the record cannot tell from healthy.

    Raises
    ------
    ConfigError
        No calibration given for a model of no preset's own spec.
    """
    import numpy as np

    from rwlab.diagnose.features import RECORD_OUTPUTS, WheelScales, compute_features
    from rwlab.diagnose.pipeline import run
    from rwlab.diagnose.wheel_calibration import DiagnosisCalibration, model_calibration_file
    from rwlab.testbed import load_record
    from rwlab.wheel import IdentifiedWheel

    wheel = IdentifiedWheel.from_json(model)
    scales = WheelScales.from_model_file(model)
    cal = DiagnosisCalibration.load(calibration or model_calibration_file(model))
    data = load_record(record, scales.Ts, outputs=RECORD_OUTPUTS, max_gap=np.inf)
    return run(compute_features(data, wheel, scales), cal, false_alarms_per_hour)


def simulate(
    scenario: str = "geo-comsat",
    controller: str = "lqg",
    *,
    duration: float,
    wheel: str | None = None,
    wheel_model: str | os.PathLike | None = None,
    seed: int | None = None,
    force_wheel: bool = False,
    **overrides: Any,
):
    """Fly one controller on a scenario with its wheel model.

    Parameters
    ----------
    scenario : str
        A built-in scenario (``geo-comsat``, ``geo-smallsat``, ``geo-cubesat`` …) or a file.
    controller : {"pd", "lqr", "lqg", "lqg_ltr"}
    duration : float
        Seconds.
    wheel : str, optional
        Fly this wheel model (a preset or a spec file) instead of the scenario's.
    wheel_model : str or os.PathLike, optional
        Fly this ``model.json`` as the actuator (with the wheel spec it carries).
    seed : int, optional
        Noise seed (the scenario's by default).
    force_wheel : bool
        Fly wheels that cannot deliver the scenario's needs (else ``ConfigError``);
        the metrics' ``wheel_forced`` says what they lack.
    **overrides
        Scenario fields by dotted name (``**{"run.dt": 0.2}``).

    Returns
    -------
    run : SimResult
        The trajectories.
    metrics : dict
        Pointing and wheel metrics, and ``wheel_forced`` (list of str).
    """
    from rwlab.attitude.control import fly
    from rwlab.attitude.scenario import load_scenario
    from rwlab.attitude.wheel_fit import check_wheel_fit

    changes = dict(overrides)
    if wheel is not None:
        changes["wheels.spec"] = str(wheel)
    if wheel_model is not None:
        from rwlab.ident.model_file import WheelModelFile

        changes |= {"wheels.model": "identified", "wheels.model_file": str(wheel_model)}
        if WheelModelFile.load(wheel_model).wheel_spec is not None:
            changes["wheels.spec"] = str(wheel_model)
    sc = load_scenario(scenario, **changes)
    forced = check_wheel_fit(sc, force=force_wheel)
    run, metrics = fly(sc, controller, duration=duration, seed=seed)
    return run, {**metrics, "wheel_forced": forced}


def montecarlo(out: str | os.PathLike, **options: Any):
    """A Monte Carlo pointing campaign, written into the folder ``out``.

    Parameters
    ----------
    out : str or os.PathLike
        The output folder.
    **options
        The fields of :class:`rwlab.report.montecarlo.CampaignOptions` (``scenario``,
        ``runs``, ``duration`` …) and the keywords of
        :func:`rwlab.report.montecarlo.montecarlo` (``workers``, ``force`` …).

    Returns
    -------
    summary : dict
    paths : dict of str to Path
    """
    from dataclasses import fields

    from rwlab.report.montecarlo import CampaignOptions
    from rwlab.report.montecarlo import montecarlo as run

    names = {f.name for f in fields(CampaignOptions)}
    spec = CampaignOptions(**{k: v for k, v in options.items() if k in names})
    return run(out, spec, **{k: v for k, v in options.items() if k not in names})


def hil(
    out: str | os.PathLike,
    *,
    scenario: str = "geo-smallsat",
    duration: float,
    wheel: str | None = None,
    force: bool = False,
    force_wheel: bool = False,
    **settings: Any,
):
    """Fly the satellite on the host with its wheels on a (virtual) bus.

    Parameters
    ----------
    out : str or os.PathLike
        The output folder: ``record.mcap``, ``metrics.json``, ``report.html``.
    scenario : str
        A built-in scenario or a file.
    duration : float
        Seconds of flight.
    wheel : str, optional
        The wheel model the twin nodes fly: a preset or a unit's own spec file.
    force : bool
        Overwrite ``out``'s files.
    force_wheel : bool
        Fly wheels that cannot deliver the scenario's needs (else ``ConfigError``); the
        report's first screen and ``metrics["config"]["wheel_forced"]`` say what they lack.
    **settings
        Other :class:`rwlab.hil.run.HilConfig` fields (``controller``, ``seed`` …).

    Returns
    -------
    HilResult
        The run, its metrics and the files written.
    """
    from rwlab.hil.run import HilConfig, run_hil
    from rwlab.report.hil import write_hil_report

    cfg = HilConfig(
        scenario=scenario, duration=duration, wheel=wheel, force_wheel=force_wheel, **settings
    )
    result = run_hil(cfg, out, force=force)
    write_hil_report(result, out)
    return result
