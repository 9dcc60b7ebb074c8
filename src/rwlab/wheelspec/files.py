"""Wheel spec files: reading a preset or a lab's TOML, checking it, and writing one out.

A spec file's structure is the JSON Schema ``rwlab/schemas/wheelspec.schema.json``
(checked with ``jsonschema``), after rwlab's own pass over its keys so that a typo is
named with the key it probably meant (``unknown key 'inertai_kg_m2' in [rotor]; did you
mean 'inertia_kg_m2'?``). :func:`to_toml` writes a spec back as a file that reads to the
same spec (``rwlab wheel models NAME`` prints one to copy and edit).
"""

from __future__ import annotations

import json
import os
import tomllib
from dataclasses import replace
from functools import cache
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import Any

from rwlab._toml import unknown_keys
from rwlab.errors import ConfigError
from rwlab.wheelspec.checks import check_physics
from rwlab.wheelspec.fields import FORMAT, KIND, KINDS, OPTIONAL, SECTION_OF, SECTIONS

# the spec's class is passed in (rwlab.wheelspec.spec imports this module, not the reverse)
WheelSpec = Any

__all__ = ["from_dict", "load", "load_text", "preset", "preset_names", "to_toml"]

_TOP = ("format", "name", "title", "documents", *SECTIONS, "tolerances")
_ENTRY = ("value", "source")
_TOLERANCE = ("relative", "absolute", "source")
_PACKAGE = "rwlab.wheelspec"


def load(cls: Any, name_or_path: str | os.PathLike) -> WheelSpec:
    """A shipped preset by name or a spec file, checked (:func:`check_physics` included).

    Parameters
    ----------
    name_or_path : str or path-like
        A preset name (:func:`preset_names`) or a spec file.

    Returns
    -------
    WheelSpec
    """
    if isinstance(name_or_path, str) and name_or_path in preset_names():
        return preset(cls, name_or_path)
    path = Path(name_or_path)
    if not path.is_file():
        raise ConfigError(
            f"unknown wheel model {str(name_or_path)!r}: not one of {list(preset_names())} "
            "and no such file (a wheel spec TOML; see `rwlab wheel models`)"
        )
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the wheel spec ({exc})") from None
    return replace(load_text(cls, text, str(path)), origin=str(path))


def load_text(
    cls: Any, text: str, where: str = "the wheel spec", *, validate: bool = True
) -> WheelSpec:
    """A spec file's text, parsed and checked (:func:`check_physics` included).

    Parameters
    ----------
    text : str
        The TOML.
    where : str
        The file's name, for messages.
    validate : bool
        Check the structure against the JSON Schema.

    Returns
    -------
    WheelSpec
    """
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{where}: not valid TOML ({exc})") from None
    spec = from_dict(cls, raw, where, validate=validate)
    try:
        check_physics(spec)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return spec


def from_dict(
    cls: Any, raw: Any, where: str = "the wheel spec", *, validate: bool = True
) -> WheelSpec:
    """A spec from its file's parsed form (ranges checked, not :func:`check_physics`).

    Parameters
    ----------
    raw : dict
        ``format``, ``name``, ``title``, ``documents``, the sections, ``tolerances``.
    where : str
        The file's name, for messages.
    validate : bool
        Check the keys and the structure (JSON Schema) first.

    Returns
    -------
    WheelSpec
    """
    if validate:
        check_keys(raw, where)
        _validate_schema(raw, where)
    values: dict[str, Any] = {}
    sources: dict[str, str] = {}
    for section, items in SECTIONS.items():
        table = raw[section]
        for name, kind in items:
            entry = table.get(name, OPTIONAL.get(name))
            if entry is None:  # the schema passed it (or validate=False): say which
                raise ConfigError(f"{where}: [{section}] has no {name}")
            value = entry["value"]
            if kind is float and isinstance(value, int) and not isinstance(value, bool):
                value = float(value)
            values[name] = value
            sources[name] = entry["source"]
    tolerances = {
        name: cls.tolerance_class(
            float(t.get("relative", 0)), float(t.get("absolute", 0)), t["source"]
        )
        for name, t in raw.get("tolerances", {}).items()
    }
    try:
        return cls(
            name=raw["name"],
            title=raw["title"],
            documents=tuple(raw["documents"]),
            tolerances=MappingProxyType(tolerances),
            sources=MappingProxyType(sources),
            **values,
        )
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def check_keys(raw: Any, where: str) -> None:
    """Every key of a spec file is one rwlab knows; a typo is named with its likely meaning.

    Parameters
    ----------
    raw : dict
        The parsed file.
    where : str
        The file's name, for messages.

    Raises
    ------
    ConfigError
        ``unknown key 'inertai' in [rotor]; did you mean 'inertia_kg_m2'?``, or a
        field in the wrong section, named with its section.
    """
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: a wheel spec is a TOML table")
    _unknown(where, raw, _TOP, "at the top level")
    for section, items in SECTIONS.items():
        table = raw.get(section)
        if not isinstance(table, dict):
            continue
        for key in table:
            home = SECTION_OF.get(key)
            if home is not None and home != section:
                raise ConfigError(f"{where}: {key} belongs in [{home}], not in [{section}]")
        _unknown(where, table, [name for name, _ in items], f"in [{section}]")
        for name, entry in table.items():
            if isinstance(entry, dict):
                _unknown(where, entry, _ENTRY, f"in {section}.{name}")
    tolerances = raw.get("tolerances")
    if isinstance(tolerances, dict):
        _unknown(where, tolerances, list(KINDS), "in [tolerances]")
        for name, entry in tolerances.items():
            if isinstance(entry, dict):
                _unknown(where, entry, _TOLERANCE, f"in tolerances.{name}")


def _unknown(where: str, table: dict, known, place: str) -> None:
    """Refuse the first key of ``table`` not in ``known``, with the nearest known one."""
    found = unknown_keys(table, known)
    if not found:
        return
    first = sorted(set(table) - set(known))[0]
    near = unknown_keys([first], known)
    hint = near.partition("(did you mean ")[2].rstrip(")]")
    hint = f"; did you mean {hint}" if hint else f"; known: {sorted(known)}"
    more = len(set(table) - set(known)) - 1
    also = f" (and {more} more unknown)" if more else ""
    raise ConfigError(f"{where}: unknown key {first!r} {place}{hint}{also}")


@cache
def _validator() -> Any:
    import jsonschema

    from rwlab.schemas import schema

    return jsonschema.Draft202012Validator(schema("wheelspec"))


def _validate_schema(raw: Any, where: str) -> None:
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: a wheel spec is a TOML table")
    tag = raw.get("format")
    if isinstance(tag, str) and tag.startswith(f"rwlab.{KIND}/") and tag != FORMAT:
        raise ConfigError(f"{where}: {tag} is not {FORMAT}, the version this rwlab reads")
    errors = sorted(_validator().iter_errors(raw), key=lambda e: list(e.absolute_path))
    if errors:
        first = errors[0]
        path = ".".join(str(p) for p in first.absolute_path) or "(top level)"
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        raise ConfigError(
            f"{where}: {path}: {first.message}{more}; every number is "
            '{ value = ..., source = "..." } in its section (`rwlab wheel models rw90` '
            "prints a whole file)"
        )


@cache
def preset(cls: Any, name: str) -> WheelSpec:
    """A shipped preset, read once (its structure is checked by the tests, to keep
    ``import rwlab.wheel`` fast; its physics here).

    Parameters
    ----------
    name : str
        One of :func:`preset_names`.

    Returns
    -------
    WheelSpec
    """
    text = (resources.files(_PACKAGE) / "presets" / f"{name}.toml").read_text(encoding="utf-8")
    spec = load_text(cls, text, f"wheel preset {name!r}", validate=False)
    return replace(spec, origin=name)


@cache
def preset_names() -> tuple[str, ...]:
    """The shipped wheel models, sorted.

    Returns
    -------
    tuple of str
    """
    folder = resources.files(_PACKAGE) / "presets"
    return tuple(sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml")))


def to_toml(spec: WheelSpec) -> str:
    """A spec as a whole TOML file that :func:`load` reads back to the same spec.

    Parameters
    ----------
    spec : WheelSpec
        The spec.

    Returns
    -------
    str
        The file's text: every number with its source, the tolerances.
    """
    d = spec.to_dict()
    lines = [
        f"# wheel spec {spec.name} (hash {spec.hash}): change the numbers, their sources and",
        '# the name; every number is { value = ..., source = "..." } in its section',
        f"format = {_text(d['format'])}",
        f"name = {_text(d['name'])}",
        f"title = {_text(d['title'])}",
        "documents = [",
        *(f"  {_text(doc)}," for doc in d["documents"]),
        "]",
    ]
    for section in SECTIONS:
        lines += ["", f"[{section}]"]
        lines += [
            f"{name} = {{ value = {_value(e['value'])}, source = {_text(e['source'])} }}"
            for name, e in d[section].items()
        ]
    lines += ["", "[tolerances]"]
    for name, t in d["tolerances"].items():
        parts = [f"{k} = {_value(t[k])}" for k in ("relative", "absolute") if t[k]]
        parts.append("source = " + _text(t["source"]))
        lines.append(f"{name} = {{ {', '.join(parts)} }}")
    return "\n".join(lines) + "\n"


def _text(s: str) -> str:
    """A TOML basic string (JSON's escapes are TOML's)."""
    return json.dumps(s, ensure_ascii=False)


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return _text(v)
    return repr(v)
