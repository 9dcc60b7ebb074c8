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
import sys
import types

from rwlab._lazy import lazy_exports, public_dir
from rwlab._version import __version__
from rwlab.errors import (
    ConfigError,
    DataError,
    EstimationError,
    FileFormatError,
    ModelError,
    RwlabError,
)

_LAZY = {
    "WheelSpec": "rwlab.wheelspec",
    "identify": "rwlab.workflows",
    "simulate": "rwlab.workflows",
    "montecarlo": "rwlab.workflows",
    # what a MATLAB user reaches for first
    "IOData": "rwlab.data",
    "load": "rwlab.data",
    "compare": "rwlab.ident.validation",
}


_PACKAGES = ("diagnose", "hil")  # workflows named like the packages that hold them


class _Workflow:
    """``rwlab.diagnose`` and ``rwlab.hil``: the workflow when called, the package otherwise.

    Importing ``rwlab.diagnose`` binds the package to that name on ``rwlab``; this
    wrapper keeps both meanings: ``rwlab.diagnose(record, model)`` runs the workflow
    (:mod:`rwlab.workflows`), ``rwlab.diagnose.Diagnoser`` is the package's name, and
    setting a name (a test's monkeypatch) sets it on the package.
    """

    def __init__(self, name: str, package: types.ModuleType) -> None:
        object.__setattr__(self, "_name", name)
        object.__setattr__(self, "_package", package)
        workflow = getattr(importlib.import_module("rwlab.workflows"), name)
        object.__setattr__(self, "__doc__", workflow.__doc__)

    def __call__(self, *args, **kwargs):
        return getattr(importlib.import_module("rwlab.workflows"), self._name)(*args, **kwargs)

    def __getattr__(self, attr: str):
        return getattr(self._package, attr)

    def __setattr__(self, attr: str, value) -> None:
        setattr(self._package, attr, value)

    def __delattr__(self, attr: str) -> None:
        delattr(self._package, attr)

    def __dir__(self):
        return dir(self._package)

    def __repr__(self) -> str:
        return f"<rwlab.{self._name}: the workflow (call it) and the package {self._package!r}>"


class _Rwlab(types.ModuleType):
    def __setattr__(self, name: str, value) -> None:
        if name in _PACKAGES and isinstance(value, types.ModuleType):
            value = _Workflow(name, value)  # the import system binding the subpackage
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Rwlab


_lazy = lazy_exports(__name__, _LAZY)


def __getattr__(name: str):
    """Import on first use (PEP 562): ``import rwlab`` stays light."""
    if name in _PACKAGES:
        importlib.import_module(f"rwlab.{name}")  # binds the wrapper (_Rwlab.__setattr__)
        return globals()[name]
    return _lazy(name)


__all__ = [
    "ConfigError",
    "DataError",
    "EstimationError",
    "FileFormatError",
    "IOData",
    "ModelError",
    "RwlabError",
    "WheelSpec",
    "__version__",
    "compare",
    "diagnose",
    "hil",
    "identify",
    "load",
    "montecarlo",
    "simulate",
]

__dir__ = public_dir(__all__)
