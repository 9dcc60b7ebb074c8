"""Optional dependencies: imported on first use, with the extra that installs them.

``pip install rwlab`` brings what the identification, the wheel, the testbed and
the attitude simulation need; Dask (campaigns, fleets), Bokeh (the live
monitor), pySerial (RS-232 wheels) and pandas (``to_pandas``) are extras
(``pip install 'rwlab[all]'`` installs every one).
"""

from __future__ import annotations

import importlib
from types import ModuleType

from rwlab.errors import MissingDependencyError

__all__ = ["EXTRAS", "require"]

EXTRAS = {
    "distributed": "campaign",
    "dask": "campaign",
    "bokeh": "monitor",
    "serial": "serial",
    "pandas": "notebook",
}


def require(module: str, what: str) -> ModuleType:
    """Import an optional dependency, or say which extra installs it.

    Parameters
    ----------
    module : str
        The module to import, e.g. ``"distributed"``.
    what : str
        What needs it, for the message (e.g. ``"a Monte Carlo campaign"``).

    Returns
    -------
    module
        The imported module.

    Raises
    ------
    MissingDependencyError
        It is not installed.
    """
    try:
        return importlib.import_module(module)
    except ImportError:
        extra = EXTRAS.get(module.partition(".")[0], "all")
        raise MissingDependencyError(
            f"{what} needs {module}, which is not installed: pip install 'rwlab[{extra}]'"
        ) from None
