"""Isolation: which fault most likely explains an alarm, from the residual signature.

The signature is read over the last minute of usable samples before the
alarm (columns: speed residual rpm, measured acceleration rpm/s, measured
speed rpm, current residual A, measured current A):

==========  ======================================================  ======================
detector    signature                                               likely fault
==========  ======================================================  ======================
dropout     no telemetry frame for a whole sample period             ``telemetry_dropout``
stuck       identical speed readings, longer than noise allows       ``speed_sensor_stuck``
current     the last ≥ 3 speed readings identical (a frozen sensor   ``speed_sensor_stuck``
            makes the measured acceleration 0 while current flows)
current     extra current ∝ acceleration (regression slope ≥ 10 %)  ``torque_constant``
current     extra current in the direction of rotation, not ∝ α     ``friction``
speed       current clamped below its healthy peak while the         ``current_limit``
            speed lags the model
speed       speed offset with a healthy current                     ``speed_sensor_bias``
==========  ======================================================  ======================

Why these: a weak motor (k_t × F) needs 1/F times the current for the same
acceleration, so the current residual grows with α; worn bearings add a torque
against the rotation, whatever α; a lowered current limit leaves the current
balance intact (the residual stays white) but slows every large speed change;
a biased sensor shifts the speed and nothing else.
"""

from __future__ import annotations

import numpy as np

__all__ = ["isolate"]

FROZEN = 3  # identical readings that point to a frozen sensor (healthy: p³ ≈ 1 %)
_DIRECT = {"dropout": "telemetry_dropout", "stuck": "speed_sensor_stuck"}


def isolate(detector: str, window: np.ndarray, calibration: dict) -> str:
    """The likely fault for an alarm of ``detector`` given the recent samples.

    Parameters
    ----------
    detector : {'dropout', 'stuck', 'current', 'speed'}
    window : ndarray, shape (n, 5)
        Recent samples: speed residual, acceleration, speed, current residual, current.
    calibration : dict
        The diagnoser's calibration (``current_model``, ``current_peak_a``).

    Returns
    -------
    str
        The fault's name (``Alarm.kind``).
    """
    if detector in _DIRECT:
        return _DIRECT[detector]
    window = np.asarray(window, dtype=float).reshape(-1, 5)
    accel, speed, r_current, current = window[:, 1], window[:, 2], window[:, 3], window[:, 4]
    ok = np.isfinite(r_current)
    if detector == "current":
        if len(speed) >= FROZEN and speed[-1] != 0 and np.all(speed[-FROZEN:] == speed[-1]):
            return "speed_sensor_stuck"
        if ok.sum() < 4:
            return "friction"
        # r_i ≈ a·sign ω + b·(c_α α): b is the relative excess current per acceleration
        c_accel = calibration["current_model"]["a_per_rpm_s"]
        X = np.column_stack([np.sign(speed[ok]), c_accel * accel[ok]])
        (_, b), *_ = np.linalg.lstsq(X, r_current[ok], rcond=None)
        return "torque_constant" if abs(b) >= 0.1 else "friction"
    peak = calibration.get("current_peak_a")
    if peak is not None and np.isfinite(current).any():
        top = np.nanmax(np.abs(current))
        clamped = np.sum(np.abs(current) >= 0.99 * top) >= 3
        if top < 0.9 * peak and clamped:
            return "current_limit"
    return "speed_sensor_bias"
