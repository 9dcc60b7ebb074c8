"""The satellite's channel of an ``rwlab hil`` record as a table (``rwlab export --satellite``).

``/satellite`` rows are written every ``log_every`` control periods (whole
sensor periods). A sensor that gave no reading in a row (the Sun out of the
field of view, the Earth sensor blinded, no tracker tick, no gyros on board)
has its columns 0 and its ``*_valid`` column 0: a table of finite numbers with
the gaps said, not NaNs.
"""

from __future__ import annotations

import os

import numpy as np

from rwlab.data import IOData
from rwlab.errors import DataError

__all__ = ["satellite_data"]

# column group → (record key, width or None for the wheel count, unit)
_OUTPUTS = [
    ("error", "error_deg", 1, "deg"),
    ("estimation_error", "estimation_error_deg", 1, "deg"),
    ("q", "q", 4, ""),
    ("q_est", "q_est", 4, ""),
    ("w_bo", "w_bo", 3, "rad/s"),
    ("wheel_momentum", "wheel_momentum_Nms", None, "N*m*s"),
]
# sensor readings that may be absent in a row: (name, record key, width, unit)
_SENSORS = [
    ("sun_sensor", "sun_sensor", 3, ""),
    ("earth_sensor", "earth_sensor", 3, ""),
    ("gyro", "gyro_rad_s", 3, "rad/s"),
    ("star_tracker_q", "star_tracker_q", 4, ""),
]


def _names(name: str, width: int) -> list[str]:
    return [name] if width == 1 else [f"{name}_{i + 1}" for i in range(width)]


def satellite_data(path: str | os.PathLike) -> IOData:
    """The ``/satellite`` channel of an ``rwlab hil`` record.

    Parameters
    ----------
    path : path-like
        The record (``record.mcap``).

    Returns
    -------
    IOData
        Inputs: the torque demand (3 body axes, N·m) and each wheel's commanded
        torque (N·m); outputs: pointing and estimation errors (°), the true and
        estimated attitude quaternions (scalar last), the body rate relative to
        the orbit frame (rad/s), the wheel momenta (N·m·s), and each sensor's
        reading with its ``*_valid`` flag (sun and Earth sensor unit vectors in
        the body frame, gyro rate in rad/s, star-tracker quaternion). ``Ts`` is
        the rows' spacing, ``tstart`` the first row's time (s from the run's start).

    Raises
    ------
    DataError
        The record has no ``/satellite`` rows (it is not an ``rwlab hil`` record)
        or its rows are not evenly spaced.
    """
    from rwlab.testbed.record import read_record

    record = read_record(path)
    rows = record.topic("/satellite")
    if len(rows) < 2:
        raise DataError(
            f"{path}: no satellite channel (/satellite) to export; it is written by "
            "`rwlab hil` (for a wheel's channels use --node)"
        )
    t = np.array([r["t"] for r in rows], dtype=float)
    step = np.diff(t)
    Ts = float(np.median(step))
    if not np.allclose(step, Ts, rtol=1e-6, atol=1e-9):
        raise DataError(f"{path}: the satellite rows are not evenly spaced; the record is damaged")
    n_wheels = len(rows[0]["wheel_momentum_Nms"])
    u = np.array([r["torque_demand_Nm"] + r["wheel_torque_cmd_Nm"] for r in rows], dtype=float)
    in_names = _names("torque_demand", 3) + _names("wheel_torque_cmd", n_wheels)
    columns, names, units = [], [], []
    for name, key, width, unit in _OUTPUTS:
        width = width or n_wheels
        columns.append(np.array([r[key] for r in rows], dtype=float).reshape(len(rows), width))
        names += _names(name, width)
        units += [unit] * width
    for name, key, width, unit in _SENSORS:
        values = np.zeros((len(rows), width))
        valid = np.zeros((len(rows), 1))
        for i, r in enumerate(rows):
            if r.get(key) is not None:
                values[i], valid[i] = r[key], 1.0
        columns += [values, valid]
        names += [*_names(name, width), f"{name}_valid"]
        units += [unit] * width + [""]
    return IOData(
        u,
        np.hstack(columns),
        Ts,
        input_names=in_names,
        output_names=names,
        input_units=["N*m"] * len(in_names),
        output_units=units,
        tstart=float(t[0]),
        name="satellite",
        source={"record": str(path), "channel": "/satellite"},
    )
