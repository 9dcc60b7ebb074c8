"""Names a package exports but imports only on first use (PEP 562), so that ``import
rwlab`` and ``rwlab --help`` stay light: python-can, SciPy and numba load when needed."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable
from typing import Any


def lazy_exports(package: str, sources: dict[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` that imports each exported name from its module on first use.

    Parameters
    ----------
    package : str
        The exporting module's ``__name__``; a name, once imported, is set on it.
    sources : dict of str to str
        Exported name → the module that defines it.

    Returns
    -------
    callable
        ``__getattr__(name)``; an unknown name raises ``AttributeError``.
    """

    def __getattr__(name: str) -> Any:
        if name not in sources:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(sources[name]), name)
        setattr(sys.modules[package], name, value)
        return value

    return __getattr__


def public_dir(names: list[str]) -> Callable[[], list[str]]:
    """A module ``__dir__`` (PEP 562) that lists the public names only: ``names`` (the
    module's ``__all__``), lazy ones included before their first use, and not the
    modules the package imports for itself (``sys``, ``importlib`` …).

    Parameters
    ----------
    names : list of str
        The public names.

    Returns
    -------
    callable
        ``__dir__()``, the names sorted.
    """

    def __dir__() -> list[str]:
        return sorted(names)

    return __dir__
