"""Residuals: the identified wheel model run beside the measured telemetry.

At each sample k (sample time Ts) the generator advances the identified model
(:class:`rwlab.wheel.IdentifiedWheel`, whichever structure ``model.json``
holds) by the command that was in force over the last interval and forms

- the speed residual  r_ω = ω_meas − ω_model  (rpm);
- the acceleration residual  r_α = Δω_meas/Ts − Δω_model/Ts  (rpm/s);
- the current residual  r_i = i_meas − î  (A), where î = c·[α_meas, ω_meas,
  sign ω_meas, 1] is the motor's current balance I·α/k_t + (b·ω + τ_c sign ω)/k_t
  + offset, its coefficients fitted by least squares on fault-free samples
  (:func:`fit_current_model`). The identified model maps command to speed only,
  so the current needs this second, physical model.
"""

from __future__ import annotations

import math

import numpy as np

from rwlab.errors import DataError

__all__ = ["current_regressors", "fit_current_model"]


def current_regressors(accel_rpm_s: float, speed_rpm: float) -> np.ndarray:
    """[α, ω, sign ω, 1] for the current balance (rpm/s, rpm), shape (4,).

    Parameters
    ----------
    accel_rpm_s : float
        Acceleration, rpm/s.
    speed_rpm : float
        Speed, rpm.

    Returns
    -------
    numpy.ndarray, shape (4,)
    """
    sign = 0.0 if speed_rpm == 0 else math.copysign(1.0, speed_rpm)
    return np.array([accel_rpm_s, speed_rpm, sign, 1.0])


def fit_current_model(accel_rpm_s, speed_rpm, current_a) -> np.ndarray:
    """Least-squares coefficients of i = c·[α, ω, sign ω, 1], shape (4,).

    In SI terms c = [I/k_t, b/k_t, τ_c/k_t, offset] with α and ω converted from
    rpm/s and rpm (×2π/60), so the fit can be checked against the wheel's inertia,
    torque constant and friction.

    Parameters
    ----------
    accel_rpm_s, speed_rpm, current_a : array_like, shape (N,)
        Acceleration (rpm/s), speed (rpm) and motor current (A) of healthy samples.

    Returns
    -------
    numpy.ndarray, shape (4,)
        The coefficients c, A per regressor unit.

    Raises
    ------
    DataError
        Fewer than 20 samples, or a non-finite value.
    """
    X = np.array([current_regressors(a, w) for a, w in zip(accel_rpm_s, speed_rpm, strict=True)])
    i = np.asarray(current_a, dtype=float)
    if len(i) < 20:
        raise DataError(f"the current model needs ≥ 20 fault-free samples, got {len(i)}")
    if not (np.isfinite(X).all() and np.isfinite(i).all()):
        raise DataError("the current model's calibration samples hold NaN or Inf")
    coef, *_ = np.linalg.lstsq(X, i, rcond=None)
    return coef


class ResidualGenerator:
    """The identified model stepped beside the telemetry, one sample at a time.

    Parameters
    ----------
    wheel : IdentifiedWheel
        The model (its ``reset`` and ``step`` only); sampled at its own Ts.
    """

    def __init__(self, wheel) -> None:
        self.wheel = wheel
        self.Ts = float(wheel.Ts)
        self.current_model: np.ndarray | None = None
        self._last: tuple[float, float] | None = None  # (measured, model) speed at k − 1, rpm

    def update(self, command_rpm: float, speed_rpm: float, current_a: float) -> dict:
        """Residuals at this sample, the command having been held since the last one.

        Returns
        -------
        dict
            ``model_rpm``, ``speed`` (rpm), ``acceleration`` (rpm/s, measured
            ``accel_rpm_s`` too) and ``current`` (A; NaN until a current model is
            set, or without a measured current). The first sample starts the
            model at the measured speed and has zero residuals.
        """
        if self._last is None:
            self.wheel.reset(speed_rpm)
            model = speed_rpm
            accel = accel_model = 0.0
        else:
            model = self.wheel.step(command_rpm)
            accel = (speed_rpm - self._last[0]) / self.Ts
            accel_model = (model - self._last[1]) / self.Ts
        self._last = (speed_rpm, model)
        current = math.nan
        if self.current_model is not None and math.isfinite(current_a):
            current = current_a - float(self.current_model @ current_regressors(accel, speed_rpm))
        return {
            "model_rpm": model,
            "speed": speed_rpm - model,
            "accel_rpm_s": accel,
            "acceleration": accel - accel_model,
            "current": current,
        }
