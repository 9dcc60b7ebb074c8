"""Hardware in the loop: the satellite's attitude loop closed through wheel nodes on a bus.

- :class:`Satellite` — plant, sky, sensors, MEKF and controller on the host,
  one control period at a time, with the wheels outside.
- :class:`WheelBank` — the scenario's wheels as nodes on a bus, driven through
  :class:`~rwlab.wheel.WheelClient` in acceleration mode.
- :func:`run_hil` — the loop itself, its record, timing and live diagnosis.
"""

import importlib

_SOURCES = {
    "Satellite": "rwlab.hil.satellite",
    "WheelBank": "rwlab.hil.bench",
    "HilConfig": "rwlab.hil.run",
    "HilResult": "rwlab.hil.run",
    "run_hil": "rwlab.hil.run",
}


def __getattr__(name: str):
    """Import on first use (PEP 562): ``rwlab --help`` must not load numba and python-can."""
    if name not in _SOURCES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(_SOURCES[name]), name)
    globals()[name] = value
    return value


__all__ = ["HilConfig", "HilResult", "Satellite", "WheelBank", "run_hil"]
