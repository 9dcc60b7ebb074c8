"""A wheel simulated by the model that ``rwlab identify`` chose (``model.json``).

Paper A's linear model is only valid inside the wheel's limits, so it is
wrapped as the paper prescribes: the speed command is saturated before the
model, and the model's speed may change by at most the acceleration limit.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from rwlab.errors import FileFormatError
from rwlab.ident.models import PolyModel

__all__ = ["IdentifiedWheel"]


class IdentifiedWheel:
    """Step-by-step simulation of an identified wheel model with its saturations.

    Parameters
    ----------
    model : PolyModel
        Speed command (rpm) → speed (rpm) around the offsets.
    input_offset, output_offset : float
        Operating point: ``y − output_offset = G·(u − input_offset)``, rpm.
    speed_limit_rpm, accel_limit_rpm_s : float
        The saturations (paper A: ±7800 rpm, ±314 rpm/s).
    """

    def __init__(
        self,
        model: PolyModel,
        *,
        input_offset: float = 0.0,
        output_offset: float = 0.0,
        speed_limit_rpm: float = 7800.0,
        accel_limit_rpm_s: float = 314.0,
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
        self.reset()

    @classmethod
    def from_json(cls, path: str | os.PathLike) -> IdentifiedWheel:
        """Load ``model.json`` as written by ``rwlab identify``."""
        try:
            info = json.loads(Path(path).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise FileFormatError(f"{path}: not a readable model file ({exc})") from None
        if info.get("format") != "rwlab.WheelModel/1":
            raise FileFormatError(f"{path}: not an rwlab wheel model (format rwlab.WheelModel/1)")
        sat = info["saturation"]
        return cls(
            PolyModel.from_dict(info["model"]),
            input_offset=info["input"]["offset"],
            output_offset=info["output"]["offset"],
            speed_limit_rpm=sat["speed_rpm"],
            accel_limit_rpm_s=sat["accel_rpm_s"],
        )

    def reset(self, speed_rpm: float = 0.0) -> None:
        """Start at rest at ``speed_rpm`` (the model's equilibrium for that speed)."""
        u_eq = self.u0 + (speed_rpm - self.y0) / self.model.dc_gain()
        du = u_eq - self.u0
        n = self._A.shape[0]
        self._x = np.linalg.solve(np.eye(n) - self._A, self._B * du) if n else np.zeros(0)
        self.speed_rpm = float(speed_rpm)

    def state_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """The linear part (A, B, C, D) that :meth:`step` runs: (n, n), (n,), (n,), scalar."""
        return self._A.copy(), self._B.copy(), self._C.copy(), self._D

    def model_state(self) -> np.ndarray:
        """A copy of the linear part's state (n,)."""
        return self._x.copy()

    def step(self, command_rpm: float) -> float:
        """Apply a speed command for one sample time; returns the speed at the next sample, rpm."""
        u = min(max(float(command_rpm), -self.speed_limit_rpm), self.speed_limit_rpm) - self.u0
        self._x = self._A @ self._x + self._B * u
        linear = self.y0 + float(self._C @ self._x) + self._D * u
        limit = self.accel_limit_rpm_s * self.Ts
        self.speed_rpm += min(max(linear - self.speed_rpm, -limit), limit)
        self.speed_rpm = min(max(self.speed_rpm, -self.speed_limit_rpm), self.speed_limit_rpm)
        return self.speed_rpm

    def simulate(self, command_rpm) -> np.ndarray:
        """Speeds (rpm) for a command sequence sampled at Ts, from rest at 0 rpm."""
        self.reset()
        return np.array([self.step(c) for c in np.asarray(command_rpm, dtype=float)])
