"""Short reprs and notebook tables for rwlab's result objects.

A result holding time histories prints as its shapes, not its numbers
(``SimResult(t=array(3001,), q=array(3001, 4), ...)``): a notebook cell stays
readable and its output small. :class:`ShortRepr` gives a class ``__repr__``
and ``_repr_html_``; :func:`summarize` is the one-value rule they share.
"""

from __future__ import annotations

import dataclasses
import html
from typing import Any

import numpy as np

__all__ = ["ShortRepr", "summarize"]

_MAX_TEXT = 60


def summarize(value: Any) -> str:
    """A one-line description of a value: arrays by shape, long containers by size.

    Parameters
    ----------
    value : object
        Any value.

    Returns
    -------
    str
        At most about 60 characters.
    """
    if isinstance(value, np.ndarray):
        if value.size <= 4 and value.ndim <= 1:
            return np.array2string(value, precision=4, separator=", ")
        shape = ", ".join(str(n) for n in value.shape)
        return f"array({shape}{',' if value.ndim == 1 else ''} {value.dtype})"
    if isinstance(value, float | np.floating):
        return f"{float(value):.6g}"
    if isinstance(value, dict):
        return f"{{{len(value)} keys}}" if len(repr(value)) > _MAX_TEXT else repr(value)
    if isinstance(value, list | tuple):
        return f"[{len(value)} items]" if len(repr(value)) > _MAX_TEXT else repr(value)
    text = repr(value)
    return text if len(text) <= _MAX_TEXT else text[: _MAX_TEXT - 3] + "..."


def _fields(obj: Any) -> dict[str, Any]:
    if dataclasses.is_dataclass(obj):
        return {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj) if f.repr}
    return {k: v for k, v in vars(obj).items() if not k.startswith("_")}


class ShortRepr:
    """Mixin: ``__repr__`` and ``_repr_html_`` that summarise each field.

    For a dataclass, declare it with ``@dataclass(repr=False)`` so this
    ``__repr__`` is kept.
    """

    def __repr__(self) -> str:
        inner = ", ".join(f"{k}={summarize(v)}" for k, v in _fields(self).items())
        return f"{type(self).__name__}({inner})"

    def _repr_html_(self) -> str:
        """A two-column table of the fields, for Jupyter."""
        rows = "".join(
            f"<tr><th style='text-align:left'>{html.escape(k)}</th>"
            f"<td>{html.escape(summarize(v))}</td></tr>"
            for k, v in _fields(self).items()
        )
        return f"<div><strong>{type(self).__name__}</strong><table>{rows}</table></div>"


def pandas():
    """The pandas module, or an ImportError saying how to install it.

    Returns
    -------
    module
        ``pandas``.
    """
    from rwlab._optional import require

    return require("pandas", "to_pandas")
