"""Hardware in the loop: the satellite's attitude loop closed through wheel nodes on a bus.

- :class:`Satellite` — plant, sky, sensors, MEKF and controller on the host,
  one control period at a time, with the wheels outside.
- :class:`WheelBank` — the scenario's wheels as nodes on a bus, driven through
  :class:`~rwlab.wheel.WheelClient` in acceleration mode.
- :func:`run_hil` — the loop itself, its record, timing and live diagnosis.
"""

from rwlab._lazy import lazy_exports

_SOURCES = {
    "Satellite": "rwlab.hil.satellite",
    "WheelBank": "rwlab.hil.bench",
    "HilConfig": "rwlab.hil.run",
    "HilResult": "rwlab.hil.run",
    "run_hil": "rwlab.hil.run",
}


# imported on first use: ``rwlab --help`` must not load numba and python-can
__getattr__ = lazy_exports(__name__, _SOURCES)


__all__ = ["HilConfig", "HilResult", "Satellite", "WheelBank", "run_hil"]
