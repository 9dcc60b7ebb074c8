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


def _signature(fn) -> list[inspect.Parameter]:
    """The parameters a caller names (``self``/``cls`` left out), ``*args``/``**kw`` included."""
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return []
    # a leading underscore: not for callers (a test hook), so not for the docstring either
    return [p for p in sig.parameters.values() if p.name not in ("self", "cls")
            and not p.name.startswith("_")]  # fmt: skip


def _documented(section: list) -> list[str]:
    """The names a numpydoc Parameters section gives: ``a, b : float`` names two,
    ``**options`` names ``options``."""
    return [
        part.strip().lstrip("*")
        for entry in section
        for part in entry.name.split(",")
        if part.strip()
    ]


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


def _names(params: list[inspect.Parameter], documented: list[str]) -> list[str]:
    """Each parameter the docstring does not name, and each name it gives that is no
    parameter (stale); with ``**kwargs`` the docstring may name the keywords it takes."""
    lacks = [f"parameter {p.name!r}" for p in params if p.name not in documented]
    if not any(p.kind is p.VAR_KEYWORD for p in params):
        names = {p.name for p in params}
        lacks += [f"stale {n!r}" for n in documented if n not in names]
    return lacks


def _constructor(cls) -> list[inspect.Parameter]:
    if "__init__" in vars(cls) or hasattr(cls, "__dataclass_fields__"):
        return _signature(cls)
    return []


def missing(obj, doc_from: object = None) -> list[str]:
    """What ``obj``'s numpydoc docstring lacks: a section it needs (``"Parameters"``,
    ``"Returns"``), a parameter it does not name (``"parameter 'x'"``) or a name that is
    no parameter (``"stale 'y'"``). A class documents its constructor's parameters under
    Parameters, or (a dataclass) under Attributes."""
    if inspect.isclass(obj):
        doc = ClassDoc(obj, config={"show_class_members": False})
        params = _constructor(obj)
        if not params:
            return []
        fields = doc["Parameters"] + doc["Attributes"]
        if not fields:
            return ["Parameters"]
        return [n for n in _names(params, _documented(fields)) if not n.startswith("stale")]
    doc = FunctionDoc(obj, doc=inspect.getdoc(doc_from) if doc_from is not None else None)
    lacks = []
    params = _signature(obj)
    if params and not doc["Parameters"]:
        lacks.append("Parameters")
    elif params:
        lacks += _names(params, _documented(doc["Parameters"] + doc["Other Parameters"]))
    ret = inspect.signature(obj).return_annotation
    returns_none = ret in (None, "None", "NoReturn") or (
        ret is inspect.Signature.empty and not _returns_value(obj)
    )
    if not returns_none and not (doc["Returns"] or doc["Yields"]):
        lacks.append("Returns")
    return lacks


def methods(cls) -> dict[str, object]:
    """The public methods ``cls`` itself defines (properties and inherited ones left out)."""
    return {
        f"{cls.__module__}.{cls.__qualname__}.{name}": fn
        for name, value in vars(cls).items()
        if not name.startswith("_")
        and (fn := value.__func__ if isinstance(value, classmethod | staticmethod) else value)
        and inspect.isfunction(fn)
    }


def declared(cls, name: str) -> object:
    """Where the docstring of ``cls.name`` is: the method itself, or, when it has none, the
    base class method it overrides (what the API pages show, as ``inspect.getdoc`` does)."""
    fn = vars(cls)[name]
    fn = fn.__func__ if isinstance(fn, classmethod | staticmethod) else fn
    if (fn.__doc__ or "").strip():
        return fn
    for base in cls.__mro__[1:]:
        if name in vars(base):
            inherited = vars(base)[name]
            inherited = getattr(inherited, "__func__", inherited)
            if (getattr(inherited, "__doc__", None) or "").strip():
                return inherited
    return fn


def documented_callables() -> dict[str, object]:
    """The exported callables and the public methods of the exported classes."""
    objs = exported()
    for obj in list(objs.values()):
        if inspect.isclass(obj):
            objs.update(methods(obj))
    return objs


def _doc_owner(qualified: str, obj: object) -> object:
    """For a method, where its docstring is (:func:`declared`); else the object itself."""
    owner_name, _, attr = qualified.rpartition(".")
    module_name, _, class_name = owner_name.rpartition(".")
    module = sys.modules.get(module_name)
    cls = getattr(module, class_name, None) if module else None
    if inspect.isclass(cls) and attr in vars(cls) and not inspect.isclass(obj):
        return declared(cls, attr)
    return obj


def coverage() -> tuple[float, dict[str, list[str]]]:
    """The share of the documented callables (:func:`documented_callables`) whose docstring
    has every section and names every parameter, and what the rest lack."""
    objs = documented_callables()
    lacking = {name: m for name, obj in objs.items() if (m := missing(obj, _doc_owner(name, obj)))}
    return 1 - len(lacking) / len(objs), lacking


def main() -> int:
    share, lacking = coverage()
    for name, sections in sorted(lacking.items()):
        print(f"{name}: no {' / '.join(sections)}")
    print(f"{share:.1%} of {len(documented_callables())} callables documented")
    return 0 if not lacking else 1


if __name__ == "__main__":
    sys.exit(main())
