"""A wheel's live diagnosis in the loop: the :mod:`rwlab.diagnose` pipeline on its telemetry.

In the loop a wheel flies in acceleration mode: its driver feeds its model's current
forward (:attr:`rwlab.diagnose.features.Features.open_loop`), the regime the pipeline's
fault models describe at the speed loop's acceleration limit. Each control period adds
the command sent and the telemetry read back; every pipeline sample (``scales.Ts``, a
whole number of control periods) is the mean command in force over it, the mean current
over it and the speed at its end, as ``rwlab export --node`` would give them block by
block. Every decision time (:data:`rwlab.diagnose.bank.EVERY_S`) the record so far goes
through :class:`rwlab.diagnose.pipeline.Live`, which decides at the new decision times
only. The calibration is measured on healthy flights of the same wheel model with the
same excitation (:func:`hil_calibration_file`); lost frames are the dropout test's
(:mod:`rwlab.hil.telemetry`), not read here.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from rwlab.data import IOData
from rwlab.diagnose.bank import EVERY_S
from rwlab.diagnose.features import Features, compute_features
from rwlab.diagnose.pipeline import Event, Live
from rwlab.diagnose.scales import WheelScales
from rwlab.diagnose.wheel_calibration import DiagnosisCalibration
from rwlab.errors import ConfigError, DataError
from rwlab.wheel.physics import WheelParams
from rwlab.wheelspec import WheelSpec

__all__ = [
    "QUICK_S",
    "SAMPLE_S",
    "PipelineWatch",
    "flight_features",
    "hil_calibration_file",
    "sampled",
]

SAMPLE_S = 0.5  # the pipeline's sample time in flight, s (a block of control periods)
# design choice: a decision window of 5 s beside the bank's, so that a large fault (a
# dead motor, friction x 4) crosses at the first decision after it, as the loop's
# pointing needs (shortest 60 s: a dead motor at +15 s cost 0.123 deg; 10 s: friction x 4
# on the RW90 at +10 s cost 0.118 deg of the 0.1-deg requirement)
QUICK_S = 5.0
_OUTPUTS = ["speed_rpm", "current_a", "telemetry_age_s", "lost_frames"]


def hil_calibration_file(wheel: str | WheelSpec) -> Path | None:
    """The package's calibration for a wheel preset in the loop, or None where none is
    shipped (measured on healthy ``rwlab hil`` flights of the preset's redundant scenario;
    its ``origin`` says which).

    Parameters
    ----------
    wheel : str or WheelSpec
        A wheel preset's name (``rwlab wheel models``), or a wheel spec: only the preset's
        own (the same hash) has it; a unit's spec edited from a preset's keeps its name but
        not its numbers.

    Returns
    -------
    pathlib.Path or None
    """
    name = wheel if isinstance(wheel, str) else wheel.name
    path = Path(__file__).with_name(f"hil_calibration_{name}.json")
    if not path.is_file():
        return None
    if isinstance(wheel, WheelSpec) and not wheel.is_preset():
        return None
    return path


class PipelineWatch:
    """One wheel's pipeline in flight (module docstring).

    Parameters
    ----------
    calibration : DiagnosisCalibration
        Measured at ``SAMPLE_S`` on healthy flights of this wheel model.
    params : WheelParams
        The wheel model (its driver's feed-forward is the healthy reference).
    dt : float
        The control period, s.
    per_hour : float
        False alarms per hour asked of each detector.
    t0_s : float
        Flight time of the first reading, s.

    Raises
    ------
    ConfigError
        A calibration of another sample time, or a control period that does not divide it.
    """

    def __init__(
        self,
        calibration: DiagnosisCalibration,
        params: WheelParams,
        dt: float,
        per_hour: float,
        t0_s: float = 0.0,
    ) -> None:
        periods = SAMPLE_S / dt
        if abs(periods - round(periods)) > 1e-9 or not np.isclose(calibration.Ts, SAMPLE_S):
            raise ConfigError(
                f"the live diagnosis samples every {SAMPLE_S:g} s: it needs a control period "
                f"that divides it (got {dt:g} s) and a calibration at it (got {calibration.Ts:g} s)"
            )
        self.scales = WheelScales.from_params(params, SAMPLE_S)
        self.periods = round(periods)
        self.live = Live(calibration, per_hour)
        self.t0_s = t0_s
        self._every = round(EVERY_S / dt)  # control periods between updates
        # per control period: the command (rpm/s) and the reading after it (speed, current,
        # age; row 0: the reading before the first command), in arrays grown by doubling
        # (a list turned into an array at every decision cost 17 ms after 2 h)
        self._commands = np.empty(1024)
        self._readings = np.empty((1025, 3))
        self._n = 0  # control periods so far
        self._features: Features | None = None  # the last update's

    def update(
        self, command_rpm_s: float, speed_rpm: float, current_a: float, age_s: float
    ) -> list[Event]:
        """One control period: the command sent, then the reading it gave.

        Parameters
        ----------
        command_rpm_s : float
            The acceleration commanded over the period, rpm/s.
        speed_rpm, current_a, age_s : float
            The telemetry read at the period's end: speed (rpm), current (A), age (s).

        Returns
        -------
        list of Event
            The events a decision at this period opened (empty between decisions).
        """
        n = self._n
        if n == 0:  # the reading before the first command
            self._readings[0] = (speed_rpm, current_a, age_s)
        if n == self._commands.size:
            self._commands = np.concatenate([self._commands, np.empty(n)])
            self._readings = np.concatenate([self._readings, np.empty((n, 3))])
        self._commands[n] = command_rpm_s
        self._readings[n + 1] = (speed_rpm, current_a, age_s)
        self._n = n + 1
        if self._n % self._every:
            return []
        data = self.record()
        if data.N < 2:
            return []
        self._features = compute_features(data, None, self.scales, self._features)
        return self.live.update(self._features)

    def record(self) -> IOData:
        """The record so far on the pipeline's grid.

        Returns
        -------
        IOData
            As :func:`sampled` gives it, ``tstart`` = ``t0_s``.
        """
        n = self._n
        return sampled(self._commands[:n], self._readings[: n + 1], self.periods, self.t0_s)


def sampled(commands, readings, periods: int, t0_s: float = 0.0) -> IOData:
    """A wheel's control periods as the pipeline's samples, each ``periods`` long: the
    mean command in force over the sample, the mean current over it, the speed at its
    end, the oldest telemetry in it (the samples whose commands are complete).

    Parameters
    ----------
    commands : sequence of float, shape (K,)
        The acceleration commanded at each control period, rpm/s.
    readings : array-like, shape (K + 1, 3) or more rows
        Speed (rpm), current (A) and telemetry age (s) read at each period's start (the
        row after a command: what it gave).
    periods : int
        Control periods per sample.
    t0_s : float
        Time of the first reading, s.

    Returns
    -------
    IOData
        u: the command (rpm/s); outputs speed, current, age and lost frames (0: the
        dropout test's), at ``periods`` × the control period.
    """
    m = periods
    n = len(commands) // m
    cmd = np.asarray(commands[: n * m], dtype=float).reshape(n, m).mean(axis=1)
    read = np.asarray(readings[: n * m + 1], dtype=float)
    ends = m * np.arange(n)
    blocks = np.clip(ends[:, None] + np.arange(1 - m, 1)[None, :], 0, None)
    y = np.column_stack(
        [read[ends, 0], read[blocks, 1].mean(axis=1), read[blocks, 2].max(axis=1), np.zeros(n)]
    )
    return IOData(
        cmd[:, None], y, SAMPLE_S, output_names=_OUTPUTS, input_units=["rpm/s"], tstart=t0_s
    )


def flight_features(path: str | os.PathLike) -> dict[int, Features]:
    """Every wheel's features of a healthy ``rwlab hil`` record, as its pipeline read them
    in flight (:func:`sampled` of its telemetry from flight time 0, against the record's
    wheel model): what a calibration in the loop is measured on.

    Parameters
    ----------
    path : path-like
        The flight's ``record.mcap``.

    Returns
    -------
    dict of int to Features
        Per wheel node.

    Raises
    ------
    DataError
        Not an ``rwlab hil`` record, or one with an alarm (not a healthy flight).
    """
    from rwlab.diagnose.features import RECORD_OUTPUTS
    from rwlab.testbed import load_record
    from rwlab.testbed.record import read_record

    record = read_record(path)
    config = record.metadata.get("config", {})
    if record.metadata.get("kind") != "rwlab.hil/1" or "wheel_params" not in config:
        raise DataError(f"{path}: not an rwlab hil record (a flight's record.mcap)")
    alarms = [e["message"] for e in record.topic("/event") if e["kind"] == "alarm"]
    if alarms:
        raise DataError(f"{path}: not a healthy flight ({alarms[0]}); calibrate on healthy ones")
    scales = WheelScales.from_params(WheelParams(**config["wheel_params"]), SAMPLE_S)
    out = {}
    for node in config["nodes"]:
        data = load_record(path, None, node=node, outputs=RECORD_OUTPUTS, max_gap=np.inf)
        t = data.tstart + data.Ts * np.arange(data.N)
        first = int(np.searchsorted(t, -1e-9))
        periods = round(SAMPLE_S / data.Ts)
        wheel = sampled(data.u[first:-1, 0], data.y[first:, :3], periods)
        out[node] = compute_features(wheel, None, scales)
    return out
