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

__all__ = [
    "ConfigError",
    "DataError",
    "EstimationError",
    "FileFormatError",
    "ModelError",
    "RwlabError",
    "__version__",
]
