"""The pipeline live on a speed-mode record as it is recorded (``rwlab experiment
--model``): each sample's command and reading are kept as they come, and every
``EVERY_S`` the record so far goes through :class:`~rwlab.diagnose.pipeline.Live`
(the features of the new samples only: :func:`~rwlab.diagnose.features.compute_features`'s
``before``), so a live alarm is the one ``rwlab diagnose`` raises on the record."""

from __future__ import annotations

import os

import numpy as np

from rwlab.data import IOData
from rwlab.diagnose.bank import EVERY_S
from rwlab.diagnose.features import Features, WheelScales, compute_features
from rwlab.diagnose.pipeline import Event, Live
from rwlab.diagnose.wheel_calibration import DiagnosisCalibration, model_calibration_file

__all__ = ["RecordWatch"]

_COLUMNS = ("speed_rpm", "current_a", "telemetry_age_s", "lost_frames")


class RecordWatch:
    """One wheel's pipeline over its record as it grows (module docstring).

    Parameters
    ----------
    model_file : path-like
        The identified wheel's ``model.json``.
    calibration_file : path-like, optional
        Default: the twin calibration of the model's wheel preset
        (:func:`~rwlab.diagnose.wheel_calibration.model_calibration_file`).
    per_hour : float
        False alarms per hour asked of each detector.

    Raises
    ------
    ConfigError
        No calibration for a model of no preset's own spec; one of another sample time.
    """

    def __init__(
        self,
        model_file: str | os.PathLike,
        calibration_file: str | os.PathLike | None = None,
        per_hour: float = 1e-3,
    ) -> None:
        from rwlab.wheel import IdentifiedWheel

        self.wheel = IdentifiedWheel.from_json(model_file)
        self.scales = WheelScales.from_model_file(model_file)
        path = calibration_file or model_calibration_file(model_file)
        self.live = Live(DiagnosisCalibration.load(path), per_hour)
        self.live.check_sample_time(self.scales.Ts)
        self._every = max(1, round(EVERY_S / self.scales.Ts))
        self._rows = np.empty((1024, 1 + len(_COLUMNS)))  # command, then the readings
        self._n = 0
        self._t0_s = 0.0
        self._features: Features | None = None
        self._named: dict[int, str] = {}  # each event's name as last reported

    def update(
        self,
        t_s: float,
        command_rpm: float,
        speed_rpm: float,
        current_a: float,
        age_s: float,
        lost_frames: float,
    ) -> list[Event]:
        """One sample: the reading, then the command sent after it.

        Parameters
        ----------
        t_s : float
            The sample's time, s (the first sets the record's start).
        command_rpm : float
            The speed command sent at this sample, rpm.
        speed_rpm, current_a, age_s : float
            The latest telemetry: speed (rpm), current (A), its age (s).
        lost_frames : float
            Telemetry frames lost so far.

        Returns
        -------
        list of Event
            The events a decision at this sample opened or re-labelled (a better-supported
            fault: ``Event.relabelled``), empty between decisions.
        """
        if self._n == 0:
            self._t0_s = t_s
        if self._n == len(self._rows):  # grown by doubling: no copy of the whole at each
            self._rows = np.concatenate([self._rows, np.empty_like(self._rows)])
        self._rows[self._n] = (command_rpm, speed_rpm, current_a, age_s, lost_frames)
        self._n += 1
        if self._n % self._every or self._n < 2:
            return []
        rows = self._rows[: self._n]
        data = IOData(
            rows[:, :1],
            rows[:, 1:],
            self.scales.Ts,
            tstart=self._t0_s,
            input_names=["command"],
            output_names=list(_COLUMNS),
            input_units=["rpm"],
            output_units=["rpm", "A", "s", ""],
        )
        self._features = compute_features(data, self.wheel, self.scales, self._features)
        self.live.update(self._features)
        changed = [e for e in self.live.events if self._named.get(id(e)) != e.fault]
        self._named.update({id(e): e.fault for e in changed})
        return changed
