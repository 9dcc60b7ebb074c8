"""Read one table of a user's TOML file, every failure a ``ConfigError``."""

from __future__ import annotations

import os
import tomllib
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
