"""The fault detectors' measured constants, read from ``detector_constants.toml``.

A constant the detectors take from healthy records (a σ between units, a margin over a
healthy level) lives in that file with its value, unit, what it is and the measurement
behind it (records, units, models, command); the code that uses it states the rule from
the fault model and reads the number with :func:`measured`. Physics and definitions (a
datasheet tolerance, a sample count that defines a test) stay in the code.

The file (format ``rwlab.DetectorConstants/1``) is package data, read once.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from rwlab.errors import FileFormatError

__all__ = ["DEFAULT_FILE", "FORMAT", "MeasuredConstant", "measured", "parse", "read"]

FORMAT = "rwlab.DetectorConstants/1"
DEFAULT_FILE = Path(__file__).with_name("detector_constants.toml")
_TEXT_FIELDS = ("unit", "what", "measured")


@dataclass(frozen=True)
class MeasuredConstant:
    """One measured constant of the detectors.

    Parameters
    ----------
    name : str
        Its name in the code (``SLEW_SIGMA``).
    value : float
        The value, in ``unit``.
    unit : str
        Its unit; ``"1"`` for a ratio, whose basis ``what`` names.
    what : str
        What it is.
    measured : str
        How, and on which records, units and models, it was measured.
    """

    name: str
    value: float
    unit: str
    what: str
    measured: str


def parse(text: str, where: str = "detector constants") -> dict[str, MeasuredConstant]:
    """The constants of a file's text.

    Parameters
    ----------
    text : str
        The TOML text.
    where : str
        What to call it in messages (the file's path).

    Returns
    -------
    dict of str to MeasuredConstant
        By name.

    Raises
    ------
    FileFormatError
        Not TOML, another format, or a constant without a finite value or a text field.
    """
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise FileFormatError(f"{where}: not TOML ({exc})") from None
    if raw.get("format") != FORMAT:
        raise FileFormatError(f"{where}: format {raw.get('format')!r} is not {FORMAT}")
    table = raw.get("constants")
    if not isinstance(table, dict) or not table:
        raise FileFormatError(f"{where}: no [constants.NAME] tables")
    return {name: _constant(name, entry, where) for name, entry in table.items()}


def _constant(name: str, entry: object, where: str) -> MeasuredConstant:
    if not isinstance(entry, dict):
        raise FileFormatError(f"{where}: {name} is not a table")
    value = entry.get("value")
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise FileFormatError(f"{where}: {name}.value must be a finite number, not {value!r}")
    texts = [entry.get(key) for key in _TEXT_FIELDS]
    for key, text in zip(_TEXT_FIELDS, texts, strict=True):
        if not isinstance(text, str) or not text.strip():
            raise FileFormatError(f"{where}: {name}.{key} must be a non-empty string")
    unknown = set(entry) - {"value", *_TEXT_FIELDS}
    if unknown:
        raise FileFormatError(f"{where}: {name} has unknown keys {sorted(unknown)}")
    unit, what, how = (str(t) for t in texts)
    return MeasuredConstant(name, float(value), unit, what, how)


def read(path: str | Path = DEFAULT_FILE) -> dict[str, MeasuredConstant]:
    """The constants of a file (default: the package's).

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    dict of str to MeasuredConstant
        By name.

    Raises
    ------
    FileFormatError
        Unreadable, or malformed (:func:`parse`).
    """
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise FileFormatError(f"{path}: cannot read the detector constants ({exc})") from None
    return parse(text, str(path))


@cache
def _package() -> dict[str, MeasuredConstant]:
    return read(DEFAULT_FILE)


def measured(name: str) -> float:
    """The value of the package's measured constant ``name`` (in its file's unit).

    Parameters
    ----------
    name : str
        The constant's name (``SLEW_SIGMA``).

    Returns
    -------
    float

    Raises
    ------
    FileFormatError
        The package's file lacks it, or is malformed.
    """
    constants = _package()
    if name not in constants:
        raise FileFormatError(f"{DEFAULT_FILE.name} has no constant {name!r}")
    return constants[name].value
