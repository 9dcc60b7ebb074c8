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
:data:`NAMES`); the documentation renders them. A file rwlab reads back is
checked at the door: :func:`read_json` refuses JSON nested deeper than any
rwlab file (:data:`MAX_DEPTH`) before it can exhaust Python's stack, and
:func:`validate` checks types and required fields against the schema with
``jsonschema``, so ``"Ts": "0.5"`` is an error naming the field, not a string
that reaches arithmetic.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Mapping
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

from rwlab.errors import FileFormatError

__all__ = [
    "MAX_DEPTH",
    "NAMES",
    "format_tag",
    "json_depth",
    "read_json",
    "read_versioned",
    "schema",
    "validate",
]

#: The deepest nesting a JSON file rwlab reads may have (model.json is 5 deep).
MAX_DEPTH = 32

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
    "wheelspec",
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


def json_depth(value: Any) -> int:
    """How deeply a parsed JSON value nests (a number 0, ``[1]`` 1, ``{"a": [1]}`` 2).

    Parameters
    ----------
    value : Any
        Parsed JSON (dicts, lists, scalars).

    Returns
    -------
    int
        The nesting depth, found without recursion (any depth is measured).
    """
    deepest, stack = 0, [(value, 0)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict):
            stack.extend((v, depth + 1) for v in item.values())
        elif isinstance(item, list):
            stack.extend((v, depth + 1) for v in item)
        else:
            continue
        deepest = max(deepest, depth + 1)
    return deepest


def read_json(path: str | os.PathLike, *, what: str = "JSON file") -> Any:
    """Parse a JSON file rwlab reads, refusing what no rwlab file is.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    what : str
        What the file should be, for messages (``"model file"``).

    Returns
    -------
    Any
        The parsed JSON.

    Raises
    ------
    FileFormatError
        Not UTF-8 text, not JSON, or nested deeper than :data:`MAX_DEPTH`.
    OSError
        The file cannot be read (missing, a folder, no permission).
    """
    try:
        text = Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise FileFormatError(f"{path}: not a readable {what} (not UTF-8 text)") from None
    deep = f"{path}: not a {what}: its JSON nests deeper than {MAX_DEPTH} levels"
    try:
        value = json.loads(text)
    except RecursionError:  # the parser's own stack: deeper than any file rwlab reads
        raise FileFormatError(deep) from None
    except json.JSONDecodeError as exc:
        raise FileFormatError(f"{path}: not a readable {what} (not JSON: {exc})") from None
    if json_depth(value) > MAX_DEPTH:
        raise FileFormatError(deep)
    return value


@cache
def _validator(name: str):
    from jsonschema import Draft202012Validator

    return Draft202012Validator(schema(name))


def _where(path) -> str:
    """A JSON location as a reader writes it: ``model.A[1]``."""
    text = ""
    for part in path:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return text or "the top level"


def validate(d: Any, name: str, *, source: str = "the file") -> None:
    """Check parsed JSON against one of rwlab's schemas (types, required fields, bounds).

    Parameters
    ----------
    d : Any
        The parsed file, in the current version (after :func:`read_versioned`).
    name : str
        The schema, one of :data:`NAMES`.
    source : str
        The file's name for the message.

    Raises
    ------
    FileFormatError
        The first (most relevant, as ``jsonschema.exceptions.best_match`` ranks
        them) violation, naming the field: ``m.json: model.Ts: '0.5' is not of
        type 'number'``.
    """
    from jsonschema.exceptions import best_match

    error = best_match(_validator(name).iter_errors(d))
    if error is not None:
        message = " ".join(error.message.split())
        if len(message) > 200:
            message = message[:200] + " …"
        raise FileFormatError(f"{source}: {_where(error.absolute_path)}: {message}")
