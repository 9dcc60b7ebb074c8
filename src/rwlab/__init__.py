"""rwlab: reaction-wheel testbed, system identification and attitude control.

The workflows, from a Python session (each loads its modules on first use)::

    import rwlab
    spec = rwlab.WheelSpec.load("nrwa-t6")          # a wheel model's datasheet
    rwlab.identify("prbs.mcap", "out")               # model.json, study.json, report.html
    rwlab.diagnose("later.mcap", "out/model.json")   # alarms, fault sizes
    run, metrics = rwlab.simulate("geo-comsat", "lqg", duration=3600)
    rwlab.montecarlo("mc", scenario="geo-comsat", runs=20, duration=1800)
    rwlab.hil("hil", scenario="geo-cubesat", duration=600)
"""

import importlib

from rwlab.errors import (
    ConfigError,
    DataError,
    EstimationError,
    FileFormatError,
    ModelError,
    RwlabError,
)

__version__ = "0.1.0"

_LAZY = {
    "WheelSpec": "rwlab.wheelspec",
    "identify": "rwlab.workflows",
    "diagnose": "rwlab.workflows",
    "simulate": "rwlab.workflows",
    "montecarlo": "rwlab.workflows",
    "hil": "rwlab.workflows",
}


def __getattr__(name: str):
    """Import on first use (PEP 562): ``import rwlab`` stays light."""
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(_LAZY[name]), name)
    globals()[name] = value
    return value


__all__ = [
    "ConfigError",
    "DataError",
    "EstimationError",
    "FileFormatError",
    "ModelError",
    "RwlabError",
    "WheelSpec",
    "__version__",
    "diagnose",
    "hil",
    "identify",
    "montecarlo",
    "simulate",
]
