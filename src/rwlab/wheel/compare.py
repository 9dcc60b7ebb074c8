"""MATLAB's ``compare`` for a saved wheel model (``model.json``) on any other record.

Every model the file holds is simulated from the record's first measured speed
on the record's speed command, with the saturations of the wheel that made the
record (its speed, acceleration and current limits, the known settings a
datasheet or the driver's configuration gives), and scored by the NRMSE fit %:

- ``"linear"``: the chosen linear model as ``IdentifiedWheel`` flies it
  (command clip → linear model → output rate limit → speed clip);
- ``"servo"``: the servo model (the file's ``nonlinear`` key), its limits as
  estimated;
- ``"greybox"``: the physical grey-box wheel, with the record's current and
  speed limits in place of the identified unit's;
- ``"nlarx"``: the nonlinear ARX (a black box: it takes no limit).

Initial state: at rest at the record's first measured speed (the records start
at rest); the same for every model.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from rwlab.data import IOData
from rwlab.errors import DataError, FileFormatError
from rwlab.ident.greybox import RPM, WheelGreyBox
from rwlab.ident.model_file import WheelModelFile
from rwlab.ident.nlarx import NLARXModel
from rwlab.ident.validation import fit_percent, mse
from rwlab.wheel.identified import IdentifiedWheel

__all__ = ["compare_wheel_models"]


def _read(path: str | os.PathLike) -> dict:
    try:
        info = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FileFormatError(f"{path}: not a readable model file ({exc})") from None
    WheelModelFile.from_dict(info, source=str(path))  # the whole file checked by its owner
    return info


def _identified(path, kind: str, y0: float, u: np.ndarray, saturation: dict) -> np.ndarray:
    wheel = IdentifiedWheel.from_json(path, kind)
    if kind == "linear":
        wheel.speed_limit_rpm = float(saturation.get("speed_limit_rpm", wheel.speed_limit_rpm))
        wheel.accel_limit_rpm_s = float(
            saturation.get("accel_limit_rpm_s", wheel.accel_limit_rpm_s)
        )
    wheel.reset(y0)
    out = np.empty(u.size)
    out[0] = y0
    for k in range(u.size - 1):
        out[k + 1] = wheel.step(u[k])
    return out


def compare_wheel_models(
    model_json: str | os.PathLike, data: IOData, saturation: dict | None = None
) -> dict[str, dict]:
    """Simulated fit of every model in ``model_json`` on ``data`` (MATLAB ``compare``).

    Parameters
    ----------
    model_json : path
        A ``model.json`` written by ``rwlab identify``.
    data : IOData
        Speed command (rpm) → measured speed (rpm), SISO, at the model's Ts.
    saturation : dict, optional
        The record's wheel: ``speed_limit_rpm``, ``accel_limit_rpm_s``,
        ``current_limit_a`` (as :func:`rwlab.ident.study.load_study_data`
        returns them). Missing keys keep the model file's values.

    Returns
    -------
    dict
        Model name → ``{"fit_percent", "mse", "n_samples", "structure"}``, and
        ``"yhat"`` (numpy array, shape (N,)) for plotting.
    """
    info = _read(model_json)
    if not isinstance(data, IOData) or data.nu != 1 or data.ny != 1:
        raise DataError("compare needs a single-input single-output record (command → speed)")
    if abs(data.Ts - float(info["Ts"])) > 1e-9 * info["Ts"]:
        raise DataError(
            f"the record's Ts is {data.Ts} s, the model's {info['Ts']} s: resample the record"
        )
    sat = dict(saturation or {})
    u, y = data.u[:, 0], data.y[:, 0]
    if np.ptp(y) == 0:
        raise DataError("the record's speed is constant: fit % is undefined")
    sims: dict[str, tuple[str, np.ndarray]] = {
        "linear": (info.get("structure", "linear"), _identified(model_json, "linear", y[0], u, sat))
    }
    if "nonlinear" in info:
        sims["servo"] = ("servo", _identified(model_json, "nonlinear", y[0], u, sat))
    if "greybox" in info:
        grey = WheelGreyBox.from_dict(info["greybox"]).with_limits(  # checked by _read
            current_limit=sat.get("current_limit_a"),
            max_speed=None if "speed_limit_rpm" not in sat else sat["speed_limit_rpm"] * RPM,
        )
        sims["greybox"] = ("greybox", grey.simulate(u, y[0]))
    if "nlarx" in info:
        black = NLARXModel.from_dict(info["nlarx"])  # checked by _read
        sims["nlarx"] = ("nlarx", black.predict(data, np.inf))
    out = {}
    for name, (structure, yhat) in sims.items():
        ok = bool(np.all(np.isfinite(yhat)))
        out[name] = {
            "structure": structure,
            "fit_percent": fit_percent(y, yhat) if ok else None,
            "mse": mse(y, yhat) if ok else None,
            "n_samples": int(data.N),
            "yhat": yhat,
        }
    return out
