"""Read one table of a user's TOML file, every failure a ``ConfigError``."""

from __future__ import annotations

import difflib
import os
import tomllib
from collections.abc import Iterable
from pathlib import Path

from rwlab.errors import ConfigError


def read_table(path: str | os.PathLike, section: str, what: str) -> dict:
    """The ``[section]`` table of a TOML file, or its top-level keys when it has none.

    Parameters
    ----------
    path : path-like
        The file.
    section : str
        The table's name.
    what : str
        What the file describes, for messages ("experiment", "wheel").
    """
    try:
        raw = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"no such {what} file: {path}") from None
    except IsADirectoryError:
        raise ConfigError(f"{path} is a folder, not a {what} file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not a valid TOML {what} file ({exc})") from None
    table = raw.get(section, raw)
    if not isinstance(table, dict):
        raise ConfigError(f"{path}: {section} must be a table ([{section}])")
    return dict(table)


def unknown_keys(keys: Iterable[str], known: Iterable[str]) -> str:
    """The keys not in ``known``, each with the nearest known one when a typo is likely.

    Parameters
    ----------
    keys : iterable of str
        The keys a file gave.
    known : iterable of str
        The keys it may give.

    Returns
    -------
    str
        ``""`` when every key is known, else e.g.
        ``"['max_torq' (did you mean 'max_torque'?)]"``, for a message.
    """
    known = list(known)
    parts = []
    for key in sorted(set(keys) - set(known)):
        near = difflib.get_close_matches(key, known, n=1, cutoff=0.75)
        parts.append(f"{key!r} (did you mean {near[0]!r}?)" if near else repr(key))
    return f"[{', '.join(parts)}]" if parts else ""
