"""A wheel simulated by a model that ``rwlab identify`` wrote (``model.json``).

Two models, one per sample step each (``IdentifiedWheel.step``):

- ``"linear"``: paper A's chosen model, wrapped as the paper prescribes: the
  speed command is saturated before the model, and the model's speed may change
  by at most the acceleration limit (command clip → linear state-space step →
  output rate limit ±a·Ts → speed clip);
- ``"nonlinear"``: the servo model of ``rwlab.ident.nonlinear`` (its limits
  estimated with its dynamics), stepped by ``servo_advance``.

``model.json`` files from before the nonlinear model hold only the linear one.
"""

from __future__ import annotations

import os

import numpy as np

from rwlab.errors import ConfigError, FileFormatError, ModelError
from rwlab.ident.model_file import WheelModelFile
from rwlab.ident.models import PolyModel
from rwlab.ident.nonlinear import ServoModel, servo_advance
from rwlab.wheelspec import WheelSpec

__all__ = ["IdentifiedWheel"]

_RW90 = WheelSpec.load("rw90")  # the saturations of a model given without its own


class IdentifiedWheel:
    """Step-by-step simulation of an identified wheel model with its saturations.

    Parameters
    ----------
    model : PolyModel
        Speed command (rpm) → speed (rpm) around the offsets.
    input_offset, output_offset : float
        Operating point: ``y − output_offset = G·(u − input_offset)``, rpm.
    speed_limit_rpm, accel_limit_rpm_s : float
        The saturations (default: the RW90 spec's).
    servo : ServoModel, optional
        Fly this nonlinear model (rpm, rpm/s) instead of ``model``, which then
        only gives the equilibrium for ``reset``.
    wheel_spec : WheelSpec, optional
        The wheel model the model was identified on (``model.json``'s): what the
        diagnosis scales its tests by. None: a model file without one.
    """

    def __init__(
        self,
        model: PolyModel,
        *,
        input_offset: float = 0.0,
        output_offset: float = 0.0,
        speed_limit_rpm: float = _RW90.max_speed_rpm,
        accel_limit_rpm_s: float = _RW90.max_accel_rpm_s,
        servo: ServoModel | None = None,
        wheel_spec: WheelSpec | None = None,
    ) -> None:
        if model.nu != 1:
            raise FileFormatError("an identified wheel model must have one input")
        self.model = model
        self.Ts = model.Ts
        self.u0, self.y0 = float(input_offset), float(output_offset)
        self.speed_limit_rpm = float(speed_limit_rpm)
        self.accel_limit_rpm_s = float(accel_limit_rpm_s)
        ss = model.to_ss()
        self._A, self._B = np.asarray(ss.A), np.asarray(ss.B)[:, 0]
        self._C, self._D = np.asarray(ss.C)[0], float(np.asarray(ss.D)[0, 0])
        self.servo = servo
        self.wheel_spec = wheel_spec
        self.kind = "linear" if servo is None else "nonlinear"
        if servo is not None:
            if servo.Ts != self.Ts:
                raise FileFormatError(f"the servo model's Ts {servo.Ts} differs from {self.Ts}")
            self._p = servo.vector
        self.reset()

    @classmethod
    def from_json(cls, path: str | os.PathLike, model: str | None = None) -> IdentifiedWheel:
        """Load ``model.json`` as written by ``rwlab identify``.

        ``model``: 'linear', 'nonlinear', or None for the file's ``preferred``
        one (the better validation fit; 'linear' in files without a nonlinear model).
        """
        info = WheelModelFile.load(path)
        return cls.from_file(info, model, source=str(path))

    @classmethod
    def from_info(
        cls, info: dict, model: str | None = None, *, source: str = "model"
    ) -> IdentifiedWheel:
        """The wheel of a ``model.json`` already read (its dict); see :meth:`from_json`.

        Parameters
        ----------
        info : dict
            ``model.json``'s content.
        model : {'linear', 'nonlinear'}, optional
            Which model to fly (default: the file's ``preferred``).
        source : str
            The file's name for the messages.

        Returns
        -------
        IdentifiedWheel
        """
        return cls.from_file(WheelModelFile.from_dict(info, source=source), model, source=source)

    @classmethod
    def from_file(
        cls,
        info: WheelModelFile | str | os.PathLike,
        model: str | None = None,
        *,
        source: str = "model",
    ) -> IdentifiedWheel:
        """The wheel a :class:`~rwlab.ident.model_file.WheelModelFile` describes.

        Parameters
        ----------
        info : WheelModelFile or path-like
            The model file's content, or the ``model.json`` to read (as
            :meth:`from_json`).
        model : {'linear', 'nonlinear'}, optional
            Fly the linear or the servo model (default: the file's ``preferred``).
        source : str
            The file's name for the messages.

        Returns
        -------
        IdentifiedWheel

        Raises
        ------
        FileFormatError
            No such model in the file, or a model no wheel can have (unstable,
            non-finite, limits that are not positive).
        ConfigError
            ``info`` is neither a model file nor a path.
        """
        if isinstance(info, (str, os.PathLike)):
            return cls.from_json(info, model)
        if not isinstance(info, WheelModelFile):
            raise ConfigError(
                f"from_file takes a WheelModelFile or a model.json path, not a "
                f"{type(info).__name__} (a dict read from model.json: from_info)"
            )
        kind = model or info.preferred
        if kind not in ("linear", "nonlinear"):
            raise FileFormatError(f"model must be 'linear' or 'nonlinear', got {kind!r}")
        if kind == "nonlinear" and info.servo is None:
            raise FileFormatError(f"{source}: holds no nonlinear model; run rwlab identify again")
        wheel = cls(
            info.model,
            input_offset=info.input.offset,
            output_offset=info.output.offset,
            speed_limit_rpm=info.speed_limit_rpm,
            accel_limit_rpm_s=info.accel_limit_rpm_s,
            servo=info.servo if kind == "nonlinear" else None,
            wheel_spec=info.wheel_spec,
        )
        try:
            wheel._check(source)
        except ModelError as exc:
            raise FileFormatError(str(exc)) from None
        return wheel

    def _check(self, path) -> None:
        """Refuse a model no wheel can have: unstable, or coefficients out of any range."""
        coeffs = [np.ravel(m) for m in (self._A, self._B, self._C, self._D)]
        if not all(np.all(np.isfinite(m)) for m in coeffs):
            raise ModelError(f"{path}: the model holds non-finite coefficients")
        if max(float(np.max(np.abs(m), initial=0.0)) for m in coeffs) > 1e12:
            raise ModelError(f"{path}: the model's coefficients exceed 1e12: not a wheel's model")
        poles = np.linalg.eigvals(self._A) if self._A.size else np.zeros(0)
        if poles.size and np.max(np.abs(poles)) >= 1:
            raise ModelError(
                f"{path}: the model is unstable (largest pole |z| = {np.max(np.abs(poles)):.4g}); "
                "a wheel's speed loop is stable, so the file is wrong: identify the wheel again"
            )

    def reset(self, speed_rpm: float = 0.0) -> None:
        """Start at rest at ``speed_rpm`` (the model's equilibrium for that speed)."""
        u_eq = self.u0 + (speed_rpm - self.y0) / self.model.dc_gain()
        du = u_eq - self.u0
        n = self._A.shape[0]
        self._x = np.linalg.solve(np.eye(n) - self._A, self._B * du) if n else np.zeros(0)
        self.speed_rpm = float(speed_rpm)
        if self.servo is not None:  # at rest: the loop's integral is 0, the last command holds
            self._integral = 0.0
            self._u_prev = (speed_rpm - self.servo.offset) / self.servo.gain

    def state_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """The linear part (A, B, C, D) that :meth:`step` runs: (n, n), (n,), (n,), scalar."""
        return self._A.copy(), self._B.copy(), self._C.copy(), self._D

    def model_state(self) -> np.ndarray:
        """A copy of the model's state: the linear part's x (n,), or the servo's [I, u_prev]."""
        if self.servo is not None:
            return np.array([self._integral, self._u_prev])
        return self._x.copy()

    def step(self, command_rpm: float) -> float:
        """Apply a speed command for one sample time; returns the speed at the next sample, rpm."""
        if self.servo is not None:
            u = float(command_rpm)
            self.speed_rpm, self._integral = servo_advance(
                self.speed_rpm, self._integral, self._u_prev, u, self._p
            )
            self._u_prev = u
            return self.speed_rpm
        u = min(max(float(command_rpm), -self.speed_limit_rpm), self.speed_limit_rpm) - self.u0
        self._x = self._A @ self._x + self._B * u
        linear = self.y0 + float(self._C @ self._x) + self._D * u
        limit = self.accel_limit_rpm_s * self.Ts
        self.speed_rpm += min(max(linear - self.speed_rpm, -limit), limit)
        self.speed_rpm = min(max(self.speed_rpm, -self.speed_limit_rpm), self.speed_limit_rpm)
        return self.speed_rpm

    def simulate(self, command_rpm) -> np.ndarray:
        """Speeds (rpm) for a command sequence sampled at Ts, from rest at 0 rpm.

        ``out[k]`` is the speed one sample after ``command_rpm[k]`` was applied.
        """
        self.reset()
        return np.array([self.step(c) for c in np.asarray(command_rpm, dtype=float)])
