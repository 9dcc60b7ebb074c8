"""What every identified model shares: input checks, JSON files, notebook display.

:class:`~rwlab.ident.models.PolyModel` and :class:`~rwlab.ident.ssmodel.SSModel`
derive from :class:`IdentifiedModel`; each keeps its own structure, responses and
``to_dict``/``from_dict``.
"""

from __future__ import annotations

import html
import json
import os
from pathlib import Path
from typing import Any, ClassVar, Self

import numpy as np

from rwlab._io import atomic_write_bytes
from rwlab.data import IOData
from rwlab.errors import DataError
from rwlab.schemas import read_json

__all__ = ["IdentifiedModel", "load_model_json", "save_model_json"]


class SavedAsJson:
    """What writes itself as one JSON file, its ``to_dict()``: a model, ``model.json``."""

    def to_dict(self) -> dict:  # pragma: no cover - abstract
        """The JSON content."""
        raise NotImplementedError

    def save(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        """Write :meth:`to_dict` as JSON, atomically.

        Parameters
        ----------
        path : str or os.PathLike
            The file.
        overwrite : bool
            Replace an existing file; otherwise ``FileExistsError``.

        Returns
        -------
        Path
            The file written.
        """
        return save_model_json(path, self.to_dict(), overwrite=overwrite)


class IdentifiedModel(SavedAsJson):
    """Base class of the identified models (not used on its own).

    Subclasses set ``Ts`` (s), ``report`` (dict) and implement ``nu``,
    ``parameters``, ``poles``, ``to_dict`` and ``from_dict``.
    """

    FORMAT: ClassVar[str] = ""
    Ts: float
    report: dict

    # -- interface the subclasses provide ------------------------------------------
    @property
    def nu(self) -> int:  # pragma: no cover - abstract
        """Number of inputs."""
        raise NotImplementedError

    @property
    def parameters(self) -> np.ndarray:  # pragma: no cover - abstract
        """The free parameters, shape (n_params,)."""
        raise NotImplementedError

    def poles(self) -> np.ndarray:  # pragma: no cover - abstract
        """The poles in z."""
        raise NotImplementedError

    def to_dict(self) -> dict:  # pragma: no cover - abstract
        """Plain-JSON form."""
        raise NotImplementedError

    @classmethod
    def from_dict(cls, d: dict) -> Self:  # pragma: no cover - abstract
        """Inverse of :meth:`to_dict`."""
        raise NotImplementedError

    # -- shared ---------------------------------------------------------------------
    @property
    def n_params(self) -> int:
        """Number of free parameters."""
        return int(self.parameters.size)

    def is_stable(self) -> bool:
        """True when every pole is strictly inside the unit circle.

        Returns
        -------
        bool
        """
        return bool(np.all(np.abs(self.poles()) < 1.0))

    def _inputs(self, u) -> np.ndarray:
        """``u`` (array or IOData) as a finite (N, nu) float array, copied."""
        if isinstance(u, IOData):
            u = u.u
        arr = np.asarray(u, dtype=float)
        if arr.ndim == 1:
            arr = arr[:, None]
        if arr.ndim != 2 or arr.shape[1] != self.nu:
            raise DataError(f"u must have shape (N,) or (N, {self.nu}); got {np.shape(u)}")
        if not np.all(np.isfinite(arr)):
            raise DataError("u contains NaN or Inf")
        return arr

    @classmethod
    def load(cls, path: str | os.PathLike) -> Self:
        """Read a model written by :meth:`save`.

        Parameters
        ----------
        path : str or os.PathLike
            The file.

        Returns
        -------
        IdentifiedModel
            Of the class it is called on.
        """
        return cls.from_dict(load_model_json(path))

    def _summary(self) -> dict[str, Any]:
        """The few facts a notebook shows about the model."""
        rep = self.report or {}
        fit = rep.get("fit_percent")
        if isinstance(fit, list):
            fit = ", ".join(f"{f:.2f}" for f in fit)
        elif fit is not None:
            fit = f"{fit:.2f}"
        return {
            "structure": getattr(self, "structure", type(self).__name__),
            "Ts [s]": f"{self.Ts:g}",
            "inputs": self.nu,
            "parameters": self.n_params,
            "stable": self.is_stable(),
            "method": rep.get("method", ""),
            "fit to estimation data [%]": "" if fit is None else fit,
        }

    def _repr_html_(self) -> str:
        """A short table and the equations, for Jupyter."""
        rows = "".join(
            f"<tr><th style='text-align:left'>{html.escape(k)}</th>"
            f"<td>{html.escape(str(v))}</td></tr>"
            for k, v in self._summary().items()
            if v != ""
        )
        return (
            f"<div><strong>{type(self).__name__}</strong><table>{rows}</table>"
            f"<pre>{html.escape(str(self))}</pre></div>"
        )


def save_model_json(path: str | os.PathLike, d: dict, *, overwrite: bool) -> Path:
    """Write a model's dict as JSON atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    d : dict
        The model's ``to_dict()`` (numpy scalars and arrays are converted).
    overwrite : bool
        Replace an existing file; otherwise ``FileExistsError``.

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
    text = json.dumps(d, indent=2, default=_json_default)
    return atomic_write_bytes(path, lambda tmp: tmp.write_text(text))


def load_model_json(path: str | os.PathLike) -> dict:
    """The dict of a model file written by :func:`save_model_json`.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    dict
        The parsed JSON.

    Raises
    ------
    FileFormatError
        The file is not JSON, or nests deeper than any model file.
    """
    return read_json(path, what="model file")


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"cannot store {type(obj).__name__} in JSON")
