"""The JSON Schemas of the files rwlab writes, and the rule for reading older versions.

Every JSON file rwlab writes names its kind and schema version in a
``"format"`` field, ``"rwlab.<Kind>/<version>"`` (files written before the
field existed are version 1). The reading rule:

- the same version reads as is;
- an older version is upgraded, one version at a time, by the functions its
  owner registers (``upgrades[v]`` turns a version-``v`` dict into ``v + 1``);
- a newer version is refused with a :class:`~rwlab.errors.FileFormatError`
  saying to update rwlab: a reader never guesses at fields it does not know.

The schemas ship in this package as ``<name>.schema.json`` (:func:`schema`,
:data:`NAMES`); the documentation renders them.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from functools import cache
from importlib import resources
from typing import Any

from rwlab.errors import FileFormatError

__all__ = ["NAMES", "format_tag", "read_versioned", "schema"]

NAMES = (
    "model",
    "study",
    "metrics",
    "compare",
    "sigma",
    "budget",
    "fleet",
    "diagnosis",
    "trend",
    "demo",
    "polymodel",
    "ssmodel",
    "frequency_response",
    "fir",
    "diagnosis_calibration",
    "fdi_diagnosis",
)


def format_tag(kind: str, version: int) -> str:
    """The ``format`` value of a file: ``"rwlab.<kind>/<version>"``.

    Parameters
    ----------
    kind : str
        The file's kind, e.g. ``"WheelModel"``.
    version : int
        Its schema version, from 1.

    Returns
    -------
    str
        The tag, e.g. ``"rwlab.WheelModel/1"``.
    """
    return f"rwlab.{kind}/{int(version)}"


def read_versioned(
    d: Any,
    kind: str,
    current: int,
    upgrades: Mapping[int, Callable[[dict], dict]] | None = None,
    *,
    source: str = "the file",
) -> dict:
    """Check a file's ``format`` and upgrade an older version to ``current``.

    Parameters
    ----------
    d : dict
        The parsed JSON.
    kind : str
        The expected kind, e.g. ``"WheelModel"``.
    current : int
        The version this rwlab writes.
    upgrades : mapping of int to callable, optional
        ``upgrades[v](d)`` returns the version ``v + 1`` form of a version-``v`` dict.
    source : str
        The file's name for the messages.

    Returns
    -------
    dict
        A new dict in the current version (``d`` is not modified).

    Raises
    ------
    FileFormatError
        Not a dict, another kind, an unknown or newer version.
    """
    if not isinstance(d, dict):
        raise FileFormatError(f"{source}: not an rwlab {kind} file (a JSON object expected)")
    tag = d.get("format", format_tag(kind, 1))
    prefix = f"rwlab.{kind}/"
    if not isinstance(tag, str) or not tag.startswith(prefix) or not tag[len(prefix) :].isdigit():
        raise FileFormatError(f"{source}: not an rwlab {kind} file (format {tag!r})")
    version = int(tag[len(prefix) :])
    if version > current:
        raise FileFormatError(
            f"{source}: {tag} is newer than this rwlab reads ({format_tag(kind, current)}); "
            "update rwlab"
        )
    out = dict(d)
    for v in range(version, current):
        if upgrades is None or v not in upgrades:
            raise FileFormatError(f"{source}: no upgrade from {format_tag(kind, v)}")
        out = upgrades[v](out)
    out["format"] = format_tag(kind, current)
    return out


@cache
def _load(name: str) -> str:
    if name not in NAMES:
        raise KeyError(f"no schema {name!r}; known: {', '.join(NAMES)}")
    return (resources.files(__name__) / f"{name}.schema.json").read_text(encoding="utf-8")


def schema(name: str) -> dict:
    """The JSON Schema of one file kind.

    Parameters
    ----------
    name : str
        One of :data:`NAMES` (``"model"`` is ``model.json``, ``"budget"`` is
        ``budget.json`` ...).

    Returns
    -------
    dict
        The schema (draft 2020-12), a fresh copy.
    """
    return json.loads(_load(name))
