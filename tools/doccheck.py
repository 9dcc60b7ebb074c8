"""Which exported callables have numpydoc ``Parameters`` and ``Returns`` sections.

``python tools/doccheck.py`` prints the coverage and the callables that lack a
section; ``tests/test_docstrings.py`` holds it at or above 95 %. Exported means
named in a public module's ``__all__`` (modules whose name has no leading
underscore). A function needs ``Parameters`` when it takes any, and ``Returns``
(or ``Yields``) unless it returns None; a class needs ``Parameters`` when its
constructor takes any. Parsed with numpydoc's own parser, as python-control does.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
import sys
import textwrap
from collections.abc import Iterator

from numpydoc.docscrape import ClassDoc, FunctionDoc

import rwlab


def public_modules() -> Iterator[str]:
    """Names of rwlab's public modules."""
    yield "rwlab"
    for info in pkgutil.walk_packages(rwlab.__path__, "rwlab."):
        if not any(p.startswith("_") for p in info.name.split(".")):
            yield info.name


def exported() -> dict[str, object]:
    """Qualified name → object, for every callable in a public ``__all__`` (once each)."""
    seen: dict[int, str] = {}
    out: dict[str, object] = {}
    for name in public_modules():
        mod = importlib.import_module(name)
        for attr in getattr(mod, "__all__", []):
            obj = getattr(mod, attr, None)
            if not (inspect.isfunction(obj) or inspect.isclass(obj)):
                continue  # click commands, constants
            if not obj.__module__.startswith("rwlab"):
                continue
            if id(obj) in seen:
                continue
            seen[id(obj)] = f"{obj.__module__}.{obj.__qualname__}"
            out[seen[id(obj)]] = obj
    return out


def _params(fn) -> list[str]:
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return []
    return [p for p in sig.parameters if p not in ("self", "cls")]


def _returns_value(fn) -> bool:
    """Whether an unannotated function has a ``return <value>`` or a ``yield``."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    except (OSError, TypeError, SyntaxError):
        return True
    body = tree.body[0]
    nodes = [n for stmt in getattr(body, "body", []) for n in ast.walk(stmt)]
    return any(
        (isinstance(n, ast.Return) and n.value is not None)
        or isinstance(n, ast.Yield | ast.YieldFrom)
        for n in nodes
    )


def missing(obj) -> list[str]:
    """The numpydoc sections ``obj`` lacks."""
    if inspect.isclass(obj):
        doc = ClassDoc(obj, config={"show_class_members": False})
        need_params = bool(_params(obj.__init__)) if "__init__" in vars(obj) else False
        if not need_params and hasattr(obj, "__dataclass_fields__"):
            need_params = bool(_params(obj))
        fields = doc["Parameters"] or doc["Attributes"]
        return ["Parameters"] if need_params and not fields else []
    doc = FunctionDoc(obj)
    lacks = []
    if _params(obj) and not doc["Parameters"]:
        lacks.append("Parameters")
    ret = inspect.signature(obj).return_annotation
    returns_none = ret in (None, "None", "NoReturn") or (
        ret is inspect.Signature.empty and not _returns_value(obj)
    )
    if not returns_none and not (doc["Returns"] or doc["Yields"]):
        lacks.append("Returns")
    return lacks


def coverage() -> tuple[float, dict[str, list[str]]]:
    """The share of exported callables with every section they need, and what the rest lack."""
    objs = exported()
    lacking = {name: m for name, obj in objs.items() if (m := missing(obj))}
    return 1 - len(lacking) / len(objs), lacking


def main() -> int:
    share, lacking = coverage()
    for name, sections in sorted(lacking.items()):
        print(f"{name}: no {' / '.join(sections)}")
    print(f"{share:.1%} of {len(exported())} exported callables documented")
    return 0 if share >= 0.95 else 1


if __name__ == "__main__":
    sys.exit(main())
