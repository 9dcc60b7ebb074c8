"""A record's columns for the diagnosis, checked: a clear error, saying what to do, for
whatever the diagnosis cannot use (another sample time, no current, NaNs, a command
period the model does not run at)."""

from __future__ import annotations

import math

import numpy as np

from rwlab.data import IOData
from rwlab.errors import DataError

__all__ = ["RECORD_OUTPUTS", "check_command_period", "record_columns"]

# what load_record must give the diagnosis (its default is the speed alone)
RECORD_OUTPUTS = ("speed", "current", "age", "lost")


def record_columns(data: IOData, Ts: float) -> dict[str, np.ndarray]:
    """The record's columns by output name, with ``held`` (the command in force over each
    sample's last interval), ``telemetry_age_s`` and ``lost_frames`` (0 where absent).

    Parameters
    ----------
    data : IOData
        One input; outputs ``speed_rpm``, ``current_a`` and, where the record has them,
        ``telemetry_age_s`` and ``lost_frames``.
    Ts : float
        The model's sample time, s.

    Returns
    -------
    dict of str to numpy.ndarray

    Raises
    ------
    DataError
        Another sample time, no speed or current, more than one input, non-finite values.
    """
    if not math.isclose(data.Ts, Ts, rel_tol=1e-6):
        raise DataError(
            f"the data are sampled at {data.Ts:g} s, the model at {Ts:g} s: load the record "
            f"on the model's grid, load_record(path, {Ts:g}, outputs={RECORD_OUTPUTS!r})"
        )
    if data.nu != 1:
        raise DataError(
            "diagnosis needs one input: the speed command in rpm, or the acceleration "
            "command in rpm/s"
        )
    names = list(data.output_names)
    for needed in ("speed_rpm", "current_a"):
        if needed not in names:
            raise DataError(
                f"diagnosis needs a {needed} output, got {names}: load the record with "
                f"load_record(path, {Ts:g}, outputs={RECORD_OUTPUTS!r})"
            )
    out = {name: np.array(data.y[:, names.index(name)], dtype=float) for name in names}
    if not (np.isfinite(out["speed_rpm"]).all() and np.isfinite(out["current_a"]).all()):
        raise DataError("the record's speed or current holds NaN or Inf: no sample can be judged")
    out.setdefault("telemetry_age_s", np.zeros(data.N))
    out.setdefault("lost_frames", np.zeros(data.N))
    u = np.asarray(data.u[:, 0], dtype=float)
    out["held"] = np.concatenate([u[:1], u[:-1]])  # in force over the last interval
    return out


def check_command_period(data: IOData, Ts: float) -> None:
    """Refuse a speed-mode testbed record commanded at another period than the model's: a
    chirp commanded every 0.1 s, sampled at the model's 0.5 s, is not the command the
    wheel was given, and the model lags it (healthy chirps read as a clamp).

    Parameters
    ----------
    data : IOData
        A testbed record (its ``source["Ts"]``: the command period, s).
    Ts : float
        The model's sample time, s.

    Raises
    ------
    DataError
    """
    issued = data.source.get("Ts")
    if isinstance(issued, (int, float)) and not math.isclose(issued, Ts, rel_tol=1e-6):
        raise DataError(
            f"the record's commands came every {issued:g} s and the model runs at "
            f"{Ts:g} s: the model cannot follow the command the wheel was given; record "
            f"the test at --Ts {Ts:g}, or identify a model at {issued:g} s"
        )
