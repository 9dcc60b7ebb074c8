"""rwlab: reaction-wheel testbed, system identification and attitude control."""

from rwlab.errors import (
    ConfigError,
    DataError,
    EstimationError,
    FileFormatError,
    ModelError,
    RwlabError,
)

__version__ = "0.1.0"

# What a MATLAB user reaches for first, importable as rwlab.compare, rwlab.IOData, ...:
# imported on first use, so that `import rwlab` stays light.
_LAZY = {"IOData": "rwlab.data", "load": "rwlab.data", "compare": "rwlab.ident.validation"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'rwlab' has no attribute {name!r}")


__all__ = [
    "ConfigError",
    "DataError",
    "EstimationError",
    "FileFormatError",
    "IOData",
    "ModelError",
    "RwlabError",
    "__version__",
    "compare",
    "load",
]
