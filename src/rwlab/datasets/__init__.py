"""Real identification data shipped with rwlab, as MATLAB ships ``dryer2``.

Origins are listed in ``ORIGIN.md`` beside this file.
"""

from __future__ import annotations

from importlib import resources
from typing import Any

import numpy as np
from scipy.io import loadmat

from rwlab.data import IOData, load
from rwlab.errors import DataError

__all__ = [
    "NAMES",
    "cascaded_tanks",
    "cascaded_tanks_est",
    "cascaded_tanks_val",
    "drive",
    "dryer",
    "gas_furnace",
    "get",
]


def _path(name: str):
    return resources.files(__package__).joinpath(name)


def _bundled(
    file: str, Ts: float, name: str, names: tuple[str, str], units: tuple[str, str]
) -> IOData:
    """A bundled single-experiment file: (input, output) names and units ("": none)."""
    with resources.as_file(_path(file)) as p:
        d = load(p, Ts=Ts)
    return IOData(
        d.u, d.y, d.Ts, input_names=[names[0]], output_names=[names[1]],
        input_units=[units[0]], output_units=[units[1]], name=name,
    )  # fmt: skip


def dryer() -> IOData:
    """Feedback PT326 hair dryer (DaISy 96-006, MATLAB ``dryer2``): 1000 samples, Ts = 0.08 s.

    Input: heater voltage (V); output: thermocouple voltage (V). Not detrended.

    Returns
    -------
    IOData
        1000 samples, Ts = 0.08 s.
    """
    return _bundled("daisy_dryer.dat", 0.08, "dryer", ("power", "temperature"), ("V", "V"))


def gas_furnace() -> IOData:
    """Box & Jenkins Series J gas furnace: 296 samples, Ts = 9 s.

    Input: gas feed rate (scaled ft³/min); output: CO2 in outlet gas (%).

    Returns
    -------
    IOData
        296 samples, Ts = 9 s.
    """
    return _bundled("bj_gas_furnace.csv", 9.0, "gas_furnace", ("gas_rate", "co2"), ("", "%"))


def cascaded_tanks() -> tuple[IOData, IOData]:
    """Cascaded tanks benchmark (Schoukens et al. 2016): estimation and validation, Ts = 4 s.

    Returns
    -------
    est, val : IOData
        The estimation and validation records (pump voltage → level, V), 1024 samples each.
    """
    with resources.as_file(_path("cascaded_tanks_dataBenchmark.csv")) as p:
        est = load(p, Ts=4.0, input_columns="uEst", output_columns="yEst")
        val = load(p, Ts=4.0, input_columns="uVal", output_columns="yVal")
    kw: dict[str, Any] = dict(
        input_names=["pump"], output_names=["level"], input_units=["V"], output_units=["V"]
    )
    return (
        IOData(est.u, est.y, 4.0, name="cascaded_tanks_est", **kw),
        IOData(val.u, val.y, 4.0, name="cascaded_tanks_val", **kw),
    )


def drive(experiment: int = 1) -> IOData:
    """Coupled electric drives, PRBS experiment 1, 2 or 3 (Wigren & Schoukens 2017), Ts = 0.02 s.

    The speed sensor is insensitive to sign: the system is nonlinear in sign.

    Parameters
    ----------
    experiment : {1, 2, 3}
        Which PRBS experiment (input amplitude ±1, ±1.5 or ±0.5).

    Returns
    -------
    IOData
        Input voltage → measured (unsigned) pulley speed, 500 samples.
    """
    if experiment not in (1, 2, 3):
        raise DataError(f"drive experiment must be 1, 2 or 3, got {experiment}")
    with resources.as_file(_path("drive.mat")) as p:
        mat = loadmat(p)
    return IOData(
        np.asarray(mat[f"u{experiment}"], float),
        np.asarray(mat[f"z{experiment}"], float),
        0.02,
        input_names=["voltage"],
        output_names=["speed"],
        name=f"drive{experiment}",
    )


def cascaded_tanks_est() -> IOData:
    """Cascaded tanks benchmark, estimation record: 1024 samples, Ts = 4 s.

    Returns
    -------
    IOData
        Pump voltage (V) → upper tank level (V).
    """
    return cascaded_tanks()[0]


def cascaded_tanks_val() -> IOData:
    """Cascaded tanks benchmark, validation record: 1024 samples, Ts = 4 s.

    Returns
    -------
    IOData
        Pump voltage (V) → upper tank level (V).
    """
    return cascaded_tanks()[1]


NAMES = {
    "dryer": dryer,
    "gas_furnace": gas_furnace,
    "cascaded_tanks_est": cascaded_tanks_est,
    "cascaded_tanks_val": cascaded_tanks_val,
    "drive": drive,
}


def get(name: str) -> IOData:
    """A bundled record by name (see ``NAMES``; ``drive`` is experiment 1).

    Parameters
    ----------
    name : str
        One of ``NAMES`` (``"dryer"``, ``"gas_furnace"``, ``"drive"``, ...).

    Returns
    -------
    IOData
        The record.
    """
    if name not in NAMES:
        raise DataError(f"no bundled dataset {name!r}; choose from {sorted(NAMES)}")
    return NAMES[name]()
