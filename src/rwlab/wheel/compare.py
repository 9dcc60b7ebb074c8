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

Each saturation comes, first found, from (:func:`resolve_saturation`):

1. the caller (``rwlab compare --current-limit/--speed-limit/--accel-limit``);
2. the record's metadata (a testbed record's driver settings);
3. the model file: the identification record's settings, and for the current
   limit the grey box's own (its estimate when the identification record showed
   the clamp binding, else the limit configured there).

A plain data file (CSV…) carries no metadata, so a wheel whose driver limits the
current differently from the identified one is simulated with the wrong clamp
unless the limit is given: the grey box's fit on validation data depends on it. Each
model's score says which saturations it applied and where each came from.

Initial state: at rest at the record's first measured speed (the records start
at rest); the same for every model.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from rwlab.data import IOData
from rwlab.errors import DataError, FileFormatError
from rwlab.ident.greybox import RPM, WheelGreyBox
from rwlab.ident.model_file import WheelModelFile
from rwlab.ident.nlarx import NLARXModel
from rwlab.ident.validation import fit_percent, mse
from rwlab.schemas import read_json
from rwlab.wheel.identified import IdentifiedWheel

__all__ = ["SATURATIONS", "compare_record", "compare_wheel_models", "resolve_saturation"]

SATURATIONS = ("speed_limit_rpm", "accel_limit_rpm_s", "current_limit_a")
APPLIED = {  # the saturations each model takes from the record
    "linear": ("speed_limit_rpm", "accel_limit_rpm_s"),
    "servo": (),
    "greybox": ("speed_limit_rpm", "current_limit_a"),
    "nlarx": (),
}


def _read(path: str | os.PathLike) -> dict:
    try:
        info = read_json(path, what="model file")  # no nesting deeper than a model's
    except OSError as exc:
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
        returns them), and optionally ``sources`` (key → where the value came
        from). Missing keys keep the model file's values.

    Returns
    -------
    dict
        Model name → ``{"fit_percent", "mse", "n_samples", "structure", "saturation"}``
        (``saturation``: the limits that model applied, each ``{"value", "source"}``
        from :func:`resolve_saturation`; the servo model and the NLARX take none), and
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
    resolved = resolve_saturation(info, sat)
    out = {}
    for name, (structure, yhat) in sims.items():
        ok = bool(np.all(np.isfinite(yhat)))
        out[name] = {
            "structure": structure,
            "fit_percent": fit_percent(y, yhat) if ok else None,
            "mse": mse(y, yhat) if ok else None,
            "n_samples": int(data.N),
            "saturation": {k: resolved[k] for k in APPLIED[name] if k in resolved},
            "yhat": yhat,
        }
    return out


def resolve_saturation(info: dict, given: dict) -> dict[str, dict]:
    """Which value of each saturation a comparison applies, and where it came from.

    Parameters
    ----------
    info : dict
        The model file's JSON.
    given : dict
        The saturations the caller or the record knows (keys of :data:`SATURATIONS`,
        rpm, rpm/s, A), with ``"sources"``: key → where that value came from; a key
        without one is named by ``"saturation_source"``, else ``"given"``.

    Returns
    -------
    dict
        Key of :data:`SATURATIONS` → ``{"value", "source"}``; a saturation known
        nowhere is left out.
    """
    sources = given.get("sources", {})
    default = str(given.get("saturation_source", "given"))
    out = {
        k: {"value": float(given[k]), "source": sources.get(k, default)}
        for k in SATURATIONS
        if given.get(k) is not None
    }
    sat = info.get("saturation", {})
    kept = "model file (the identification record's setting)"
    if "speed_limit_rpm" not in out and "speed_rpm" in sat:
        out["speed_limit_rpm"] = {"value": float(sat["speed_rpm"]), "source": kept}
    if "accel_limit_rpm_s" not in out and "accel_rpm_s" in sat:
        out["accel_limit_rpm_s"] = {"value": float(sat["accel_rpm_s"]), "source": kept}
    grey = info.get("greybox")
    if "current_limit_a" not in out and grey is not None:
        how = "estimate" if grey.get("current_limit_estimated") else "configured limit"
        out["current_limit_a"] = {
            "value": float(grey["current_limit"]),
            "source": f"model file (the grey box's {how} on the identification record)",
        }
    return out


def compare_record(
    model_json: str | os.PathLike,
    record: str,
    *,
    Ts: float | None = None,
    input_col: str | None = None,
    output_col: str | None = None,
    saturation: dict | None = None,
) -> tuple[IOData, dict[str, dict]]:
    """:func:`compare_wheel_models` on a record or data file, as ``rwlab compare`` runs it.

    Parameters
    ----------
    model_json : path
        A ``model.json`` written by ``rwlab identify``.
    record : str
        A testbed record (``.mcap``), a data file or a bundled data set.
    Ts : float, optional
        Sample time, s (the record's own by default).
    input_col, output_col : str, optional
        The command and speed columns; a data file with ``command`` and ``speed_rpm``
        columns (``rwlab export``'s) uses them by default.
    saturation : dict, optional
        Saturations that override the record's and the model file's (keys of
        :data:`SATURATIONS`: rpm, rpm/s, A; None values ignored).

    Returns
    -------
    (IOData, dict)
        The record as compared, and :func:`compare_wheel_models`'s scores, each with
        ``"saturation"``: the limits that model applied, each ``{"value", "source"}``.
    """
    data, known = _load(record, Ts, input_col, output_col)
    sat: dict = {"sources": {}}
    if known.get("saturation_source") == "the record's driver settings":
        for k in SATURATIONS:
            if known.get(k) is not None:
                sat[k] = known[k]
                sat["sources"][k] = "record (its driver settings)"
    elif known.get("current_limit_a") is not None:
        sat["current_limit_a"] = known["current_limit_a"]
        sat["sources"]["current_limit_a"] = "record (its wheel parameters)"
    for k, v in (saturation or {}).items():
        if k not in SATURATIONS:
            raise DataError(f"unknown saturation {k!r}; known: {SATURATIONS}")
        if v is not None:
            if not (math.isfinite(v) and v > 0):
                raise DataError(f"{k} must be a finite number > 0, got {v!r}")
            sat[k] = float(v)
            sat["sources"][k] = "option"
    return data, compare_wheel_models(model_json, data, sat)


def _load(record: str, Ts, input_col, output_col) -> tuple[IOData, dict]:
    """The record's command → speed and what it says of its saturations; an ``rwlab
    export`` file's command and speed_rpm columns unless others are chosen."""
    from rwlab.ident.study import load_study_data

    plain = Path(record).suffix.lower() != ".mcap" and Path(record).exists()
    if plain and input_col is None and output_col is None:
        try:
            return load_study_data(record, Ts, input_col="command", output_col="speed_rpm")
        except DataError:
            pass  # not an export's columns: the file's own choice, or its error
    return load_study_data(record, Ts, input_col=input_col, output_col=output_col)
