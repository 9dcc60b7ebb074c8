"""``model.json``: the wheel model that joins the two papers, and its one owner.

:class:`WheelModelFile` is written by the identification study
(:func:`rwlab.ident.study.wheel_model`) and read by the simulated wheel
(:meth:`rwlab.wheel.IdentifiedWheel.from_json`), the attitude simulation and
the testbed. Its JSON Schema is ``rwlab/schemas/model.schema.json``; the
reading rule for older versions is :func:`rwlab.schemas.read_versioned`.

Version history: 1 — linear model with offsets and saturations, optionally the
servo model (``nonlinear``) and which one to fly (``preferred``); added within
version 1 as optional keys (older files simply lack them): the physical grey box
(``greybox``), the nonlinear ARX (``nlarx``), which of the nonlinear models the
study chose and why (``nonlinear_chosen``, ``nonlinear_choice``), the driver's
current limit (``saturation.current_limit_a``) and the diagnosis's healthy
reference (``healthy_reference``). 2 — the wheel model's spec travels with the
identified model (``wheel``: its name, hash, headline limits and the whole
:class:`rwlab.wheelspec.WheelSpec`); a version-1 file reads with no spec (``wheel_spec``
None: the wheel it came from is unknown).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any

from rwlab.errors import FileFormatError, ModelError
from rwlab.ident.base import SavedAsJson
from rwlab.ident.gain_constraint import study_name
from rwlab.ident.models import PolyModel
from rwlab.ident.nonlinear import ServoModel
from rwlab.schemas import format_tag, read_json, read_versioned, validate
from rwlab.wheelspec import WheelSpec

__all__ = ["KIND", "VERSION", "Channel", "WheelModelFile"]

KIND = "WheelModel"
VERSION = 2
_RW90 = WheelSpec.load("rw90")  # the saturations of a model made without a spec
NONLINEAR_MODELS = ("greybox", "nlarx")  # beside the servo model (``nonlinear``)
NOTE = (
    "y − output.offset = B/(A F)·(u − input.offset); apply the speed-command "
    "saturation before the model and the acceleration limit to its output."
)


@dataclass(frozen=True)
class Channel:
    """One side of the model: a signal's name, unit and operating point.

    Parameters
    ----------
    name : str
        The signal's name in the record (e.g. ``"command"``).
    unit : str
        Its unit (``"rpm"`` for a wheel).
    offset : float
        The operating point subtracted before the linear model, in ``unit``.
    """

    name: str
    unit: str
    offset: float

    def to_dict(self) -> dict:
        """Plain JSON.

        Returns
        -------
        dict
            ``{"name", "unit", "offset"}``.
        """
        return {"name": self.name, "unit": self.unit, "offset": float(self.offset)}


@dataclass(frozen=True, eq=False)
class WheelModelFile(SavedAsJson):
    """The content of ``model.json``: a wheel's identified model in physical units.

    Parameters
    ----------
    model : PolyModel
        Speed command → speed around the offsets: ``y − output.offset = G(q)·(u − input.offset)``.
    input, output : Channel
        The command and speed signals with their operating points (rpm).
    speed_limit_rpm : float
        Speed-command saturation applied before the model, rpm (default: the RW90 spec's).
    accel_limit_rpm_s : float
        Acceleration limit applied to the model's output, rpm/s (default: the RW90 spec's).
    saturation_source : str
        Where the saturations come from (the record's driver settings, defaults).
    validation_fit_percent : float
        The linear model's fit on validation data, %.
    servo : ServoModel, optional
        The nonlinear servo model, when the study estimated one.
    servo_fit_percent : float, optional
        Its validation fit, %.
    preferred : {"linear", "nonlinear"}
        The model to fly by default (the better validation fit).
    current_limit_a : float, optional
        The driver's current limit, A (the grey box's, when estimated).
    nonlinear_models : dict of str to dict
        The other nonlinear models' JSON forms (``"greybox"``, ``"nlarx"``), each
        with its ``validation_fit_percent``.
    nonlinear_chosen, nonlinear_choice : str, optional
        Which nonlinear model the study chose on validation data, and why.
    healthy_reference : dict, optional
        What the fault detectors need of the healthy identification record
        (:class:`rwlab.diagnose.HealthyReference`'s JSON form).
    data_segments : tuple of (float, float), optional
        The gap-free parts ``(t_start, t_end)`` (s) of a record split at its telemetry
        gaps and identified as separate experiments (``identify --gaps split``).
    wheel_spec : WheelSpec, optional
        The wheel model the record came from (its datasheet, as configured); None for a
        record or a version-1 file without one.
    """

    model: PolyModel
    input: Channel
    output: Channel
    speed_limit_rpm: float = _RW90.max_speed_rpm
    accel_limit_rpm_s: float = _RW90.max_accel_rpm_s
    saturation_source: str = "RW90 spec (rw90.toml)"
    validation_fit_percent: float = math.nan
    servo: ServoModel | None = None
    servo_fit_percent: float | None = None
    preferred: str = "linear"
    current_limit_a: float | None = None
    nonlinear_models: dict[str, dict] = field(default_factory=dict)
    nonlinear_chosen: str | None = None
    nonlinear_choice: str | None = None
    healthy_reference: dict | None = None
    data_segments: tuple[tuple[float, float], ...] | None = None
    wheel_spec: WheelSpec | None = None

    def __post_init__(self) -> None:
        if self.model.nu != 1:
            raise ModelError("a wheel model must have one input (the speed command)")
        if self.preferred not in ("linear", "nonlinear"):
            raise ModelError(f"preferred must be 'linear' or 'nonlinear', got {self.preferred!r}")
        if self.preferred == "nonlinear" and self.servo is None:
            raise ModelError("preferred 'nonlinear' needs a servo model")
        for name in ("speed_limit_rpm", "accel_limit_rpm_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ModelError(f"{name} must be a positive number, got {value}")
        if self.servo is not None and self.servo.Ts != self.model.Ts:
            raise ModelError(f"the servo model's Ts {self.servo.Ts} differs from {self.model.Ts}")
        _check_nonlinear_models(self.nonlinear_models or {}, self.model.Ts)

    @property
    def Ts(self) -> float:
        """The sample time, s."""
        return self.model.Ts

    @property
    def structure(self) -> str:
        """The linear model's structure, e.g. ``"ARX221"``; ``"ARX221+K"`` when its static
        gain was imposed (:func:`rwlab.ident.gain_constraint.study_name`)."""
        return study_name(self.model)

    def __repr__(self) -> str:
        servo = f", servo fit {self.servo_fit_percent:.1f} %" if self.servo is not None else ""
        return (
            f"<WheelModelFile {self.structure} Ts={self.Ts:g} s, "
            f"fit {self.validation_fit_percent:.1f} %{servo}, flies {self.preferred}>"
        )

    # -- JSON ----------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The JSON form (schema ``model.schema.json``).

        Returns
        -------
        dict
            Plain JSON with ``format`` = ``"rwlab.WheelModel/1"``.
        """
        d: dict[str, Any] = {
            "format": format_tag(KIND, VERSION),
            "structure": self.structure,
            "Ts": self.Ts,
            "input": self.input.to_dict(),
            "output": self.output.to_dict(),
            "model": self.model.to_dict(),
            "saturation": {
                "speed_rpm": float(self.speed_limit_rpm),
                "accel_rpm_s": float(self.accel_limit_rpm_s),
                "source": self.saturation_source,
            },
            "validation_fit_percent": _json_float(self.validation_fit_percent),
            "note": NOTE,
        }
        if self.servo is not None:
            fit = _json_float(self.servo_fit_percent)
            d["nonlinear"] = {**self.servo.to_dict(), "validation_fit_percent": fit}
            d["preferred"] = self.preferred
        for name, model in self.nonlinear_models.items():
            d[name] = model
        if self.nonlinear_chosen is not None:
            d["nonlinear_chosen"] = self.nonlinear_chosen
            d["nonlinear_choice"] = self.nonlinear_choice
        if self.current_limit_a is not None:  # optional: older files and records lack it
            d["saturation"]["current_limit_a"] = _json_float(self.current_limit_a)
        if self.healthy_reference is not None:
            d["healthy_reference"] = self.healthy_reference
        if self.data_segments is not None:
            d["data_segments"] = [[float(a), float(b)] for a, b in self.data_segments]
        if self.wheel_spec is not None:
            d["wheel"] = {**self.wheel_spec.limits(), "spec": self.wheel_spec.to_dict()}
        return d

    @classmethod
    def from_dict(cls, d: Any, *, source: str = "model.json") -> WheelModelFile:
        """Read the JSON form, upgrading older versions.

        Parameters
        ----------
        d : dict
            As :meth:`to_dict` returns, or any older version.
        source : str
            The file's name for the messages.

        Returns
        -------
        WheelModelFile

        Raises
        ------
        FileFormatError
            Another kind of file, a newer version, a missing or invalid field.
        """
        if not isinstance(d, dict) or "format" not in d:  # model.json always carried it
            expected = format_tag(KIND, VERSION)
            raise FileFormatError(
                f"{source}: not an rwlab wheel model (no format {expected!r}); pass the "
                "model.json that `rwlab identify` wrote"
            )
        d = read_versioned(d, KIND, VERSION, {1: _upgrade_1_to_2}, source=source)
        validate(d, "model", source=source)  # types and required fields, by the schema
        _check_top_level(d, source)
        try:
            sat, nl = d["saturation"], d.get("nonlinear")
            servo = None
            if nl is not None:
                servo = ServoModel.from_dict(
                    {k: v for k, v in nl.items() if k != "validation_fit_percent"}
                )
            return cls(
                PolyModel.from_dict(d["model"]),
                Channel(**_channel(d["input"])),
                Channel(**_channel(d["output"])),
                speed_limit_rpm=float(sat["speed_rpm"]),
                accel_limit_rpm_s=float(sat["accel_rpm_s"]),
                saturation_source=str(sat.get("source", "")),
                validation_fit_percent=_float(d.get("validation_fit_percent")),
                servo=servo,
                servo_fit_percent=None if nl is None else _float(nl.get("validation_fit_percent")),
                preferred=d.get("preferred", "linear"),
                current_limit_a=_optional_float(sat.get("current_limit_a")),
                nonlinear_models={k: d[k] for k in NONLINEAR_MODELS if d.get(k) is not None},
                nonlinear_chosen=d.get("nonlinear_chosen"),
                nonlinear_choice=d.get("nonlinear_choice"),
                healthy_reference=d.get("healthy_reference"),
                data_segments=_segments(d.get("data_segments")),
                wheel_spec=_wheel_spec(d.get("wheel"), source),
            )
        except (ModelError, FileFormatError) as exc:
            raise FileFormatError(f"{source}: {exc}") from None
        except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
            raise FileFormatError(f"{source}: missing or malformed field ({exc})") from None

    @classmethod
    def load(cls, path: str | os.PathLike) -> WheelModelFile:
        """Read ``model.json``.

        Parameters
        ----------
        path : str or os.PathLike
            The file.

        Returns
        -------
        WheelModelFile

        Raises
        ------
        FileFormatError
            Not readable, not JSON, not a wheel model, or a newer version.
        """
        try:
            d = read_json(path, what="model file")
        except OSError as exc:
            raise FileFormatError(f"{path}: not a readable model file ({exc})") from None
        return cls.from_dict(d, source=str(path))


def _upgrade_1_to_2(d: dict) -> dict:
    """Version 1 → 2: no field changes; a version-1 model has no wheel spec."""
    return dict(d)


def _wheel_spec(d: Any, source: str) -> WheelSpec | None:
    """The wheel spec a model carries, its hash checked (an edited number is refused)."""
    if d is None:
        return None
    from rwlab.errors import ConfigError

    try:
        spec = WheelSpec.from_dict(d["spec"], "wheel.spec")
    except ConfigError as exc:
        raise FileFormatError(str(exc)) from None
    if d.get("hash") != spec.hash:
        raise FileFormatError(
            f"{source}: wheel.hash {d.get('hash')!r} is not the hash of wheel.spec "
            f"({spec.hash}): the wheel's numbers were edited after identification"
        )
    return spec


def _channel(d: dict) -> dict:
    return {
        "name": str(d.get("name", "")),
        "unit": str(d.get("unit") or ""),
        "offset": float(d["offset"]),
    }


def _check_nonlinear_models(models: dict, Ts: float) -> None:
    """Every nonlinear model in the file readable, finite and at the linear model's Ts: a
    bad one is refused when the file is loaded, whichever command reads it."""
    from rwlab.ident.greybox import WheelGreyBox
    from rwlab.ident.nlarx import NLARXModel

    readers = {"greybox": WheelGreyBox.from_dict, "nlarx": NLARXModel.from_dict}
    for name, d in models.items():
        if not isinstance(d, dict):
            raise ModelError(f"{name} must be a JSON object, got {type(d).__name__}")
        try:
            model = readers[name](d)
        except (ModelError, KeyError, TypeError, ValueError) as exc:
            raise ModelError(f"bad {name} model ({exc})") from None
        ts = getattr(model, "Ts", Ts)
        if not (math.isfinite(ts) and abs(ts - Ts) <= 1e-9 * Ts):
            raise ModelError(f"the {name} model's Ts {ts} differs from the linear model's {Ts}")


def _check_top_level(d: dict, source: str) -> None:
    """The copies at the top (``Ts``, the fit) must be finite numbers, and ``Ts`` the model's."""
    for key in ("Ts", "validation_fit_percent"):
        value = d.get(key)
        if value is None and (key not in d or key == "validation_fit_percent"):
            continue  # a copy the file may leave out (a hand-written model); null fit: unknown
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise FileFormatError(f"{source}: {key} must be a number, got {value!r}")
        if not math.isfinite(value) or (key == "Ts" and value <= 0):
            raise FileFormatError(f"{source}: {key} must be a finite positive number, got {value}")
    model_Ts = d.get("model", {}).get("Ts") if isinstance(d.get("model"), dict) else None
    Ts = d.get("Ts")
    if isinstance(model_Ts, (int, float)) and Ts is not None and abs(model_Ts - Ts) > 1e-9 * Ts:
        raise FileFormatError(f"{source}: Ts {Ts} differs from the model's {model_Ts}")


def _optional_float(v: Any) -> float | None:
    return None if v is None else float(v)


def _float(v: Any) -> float:
    return math.nan if v is None else float(v)


def _json_float(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def _segments(value) -> tuple[tuple[float, float], ...] | None:
    """``data_segments``: None, or ordered finite ``[t_start, t_end]`` pairs."""
    if value is None:
        return None
    pairs = tuple((float(a), float(b)) for a, b in value)
    if not all(math.isfinite(a) and math.isfinite(b) and a <= b for a, b in pairs):
        raise ModelError(f"data_segments must be finite [t_start, t_end] pairs, got {value!r}")
    return pairs
