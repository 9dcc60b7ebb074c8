"""rwlab's import graph, its layering violations and cycles — read from the source with ast.

Run ``python tools/importgraph.py`` (exit 1 on a violation, a cycle or a private name
taken from another module); the test
``tests/test_layering.py`` runs the same check. Hand-written on ``ast`` rather than
import-linter/grimp: those are not in rwlab's dependencies, and the rule here (an
ordered list of layers plus "no cycle between modules") is fifty lines.

Every ``import`` counts, also those inside functions (a lazy import is still a
dependency), those under ``if TYPE_CHECKING:`` (a type-only import is one too) and
``importlib.import_module("rwlab.…")``. A module's layer is that of its top-level
name under ``rwlab``.
"""

from __future__ import annotations

import ast
import functools
import sys
from collections import defaultdict
from pathlib import Path

SRC = Path(__file__).resolve().parent.parent / "src"

# Lowest first. A module may import its own layer and those below, never above.
# testbed sits above diagnose (the runner diagnoses live), both above wheel. The package
# itself (``rwlab``, its __init__) is the front door: it exports the workflows, so it
# sits on top, and no module below imports a name from it (``rwlab._version`` holds the
# version they stamp).
LAYERS: list[set[str]] = [
    {
        "_version",
        "_lazy",
        "errors",
        "interrupts",
        "_toml",
        "_io",
        "_forked",
        "_display",
        "_optional",
        "schemas",
    },
    {"data", "signals", "datafiles", "datasets", "wheelspec"},
    {"ident"},
    {"wheel"},
    {"diagnose"},
    {"testbed"},
    {"attitude"},
    {"hil"},
    {"campaign"},
    {"report"},
    {"workflows"},
    {"cli", "demo", "__main__", "__init__"},
]


def modules(src: Path = SRC) -> dict[str, Path]:
    """Every module of the ``rwlab`` package: dotted name → file."""
    out = {}
    for path in sorted((src / "rwlab").rglob("*.py")):
        parts = path.relative_to(src).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


@functools.cache
def _parsed(path: Path, mtime_ns: int, size: int) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"))


def _tree(path: Path) -> ast.Module:
    """The module's syntax tree, parsed once per version of the file (its modification time
    and size): the layering tests read every module several times. Read, never changed."""
    stat = path.stat()
    return _parsed(path, stat.st_mtime_ns, stat.st_size)


def _import_module_call(node: ast.AST) -> str | None:
    """The module named by ``importlib.import_module("rwlab.x")`` (a constant name), else None."""
    if not (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)):
        return None
    func = ast.unparse(node.func)
    name = node.args[0].value
    if func in ("importlib.import_module", "import_module") and isinstance(name, str):
        return name
    return None


def imports(src: Path = SRC) -> dict[str, set[str]]:
    """The graph: module → the rwlab modules it imports (anywhere in its body).

    An import under ``if TYPE_CHECKING:`` counts: a module that needs another's names
    for its annotations depends on it, and two that need each other are a cycle
    whether or not Python runs the import. So does ``importlib.import_module`` of a
    constant rwlab name: an import by name is still an import.
    """
    mods = modules(src)
    versions = tuple((path, path.stat().st_mtime_ns, path.stat().st_size) for path in mods.values())
    return {name: set(targets) for name, targets in _imports(src, versions).items()}


@functools.cache
def _imports(src: Path, versions: tuple) -> dict[str, set[str]]:
    """:func:`imports` once per version of the source files (read, never changed)."""
    mods = modules(src)
    graph: dict[str, set[str]] = defaultdict(set)
    for name, path in mods.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        tree = _tree(path)
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*up, base] if base else up)
                # "from rwlab import datasets" imports the module rwlab.datasets
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base
                           for a in node.names]  # fmt: skip
            elif by_name := _import_module_call(node):
                targets = [by_name]
            else:
                continue
            for t in targets:
                while t and t not in mods:
                    t = t.rpartition(".")[0]
                if t.startswith("rwlab") and t != name:
                    graph[name].add(t)
    return dict(graph)


def _private(name: str) -> bool:
    return name.startswith("_") and not name.endswith("__")


def private_imports(src: Path = SRC) -> list[tuple[str, str]]:
    """(importer, ``module._name``) for every private name a module takes from another.

    Counted: ``from rwlab.x import _y`` and ``x._y`` where ``x`` names an imported rwlab
    module. Allowed: a name of a package-private module (``rwlab.cli._common``) taken by a
    module of the same package: the module's own name already says "this package only".
    A name another module needs is public API of its module, or belongs elsewhere.
    """
    mods = modules(src)
    found: set[tuple[str, str]] = set()
    for name, path in mods.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        tree = _tree(path)
        bound: dict[str, str] = {}  # local name → the rwlab module it is
        taken: list[tuple[str, str]] = []  # (module, private name)
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    if a.name in mods:
                        bound[a.asname or a.name] = a.name
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*up, base] if base else up)
                for a in node.names:
                    if f"{base}.{a.name}" in mods:
                        bound[a.asname or a.name] = f"{base}.{a.name}"
                    elif base in mods and _private(a.name):
                        taken.append((base, a.name))
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and _private(node.attr):
                owner = bound.get(ast.unparse(node.value))
                if owner is not None:
                    taken.append((owner, node.attr))
        for owner, attr in taken:
            owner_package, _, owner_leaf = owner.rpartition(".")
            if owner == name or (_private(owner_leaf) and owner_package == package):
                continue
            found.add((name, f"{owner}.{attr}"))
    return sorted(found)


def layer(module: str) -> int:
    """The layer index of a module (0 lowest)."""
    top = module.split(".")[1] if "." in module else "__init__"
    for i, names in enumerate(LAYERS):
        if top in names:
            return i
    raise KeyError(f"{module}: its top-level name {top!r} is in no layer of LAYERS")


def violations(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """Imports from a lower layer up to a higher one."""
    return sorted((a, b) for a, bs in graph.items() for b in bs if layer(b) > layer(a))


def cycles(graph: dict[str, set[str]], *, packages: bool = True) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan).

    With ``packages``, modules are merged into their top-level name under rwlab
    (``rwlab.ident.pem`` → ``ident``), so a package's ``__init__`` re-exporting
    its own modules is not a cycle, but two packages needing each other is.
    """

    def node(m: str) -> str:
        return m.split(".")[1] if packages and "." in m else m

    g: dict[str, set[str]] = defaultdict(set)
    for a, bs in graph.items():
        for b in bs:
            if node(a) != node(b):
                g[node(a)].add(node(b))
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(g.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(set(g) | {w for ws in g.values() for w in ws}):
        if v not in index:
            visit(v)
    return found


def main() -> int:
    graph = imports()
    bad = violations(graph)
    loops = cycles(graph) + [c for c in cycles(graph, packages=False) if c not in cycles(graph)]
    for a, b in bad:
        print(f"layering: {a} (layer {layer(a)}) imports {b} (layer {layer(b)})")
    for c in loops:
        print(f"cycle: {' <-> '.join(c)}")
    private = private_imports()
    for importer, taken in private:
        print(f"private: {importer} takes {taken}")
    n_edges = sum(map(len, graph.values()))
    print(
        f"{len(graph)} modules, {n_edges} imports: {len(bad)} violations, {len(loops)} cycles, "
        f"{len(private)} private names taken from another module"
    )
    return 1 if bad or loops or private else 0


if __name__ == "__main__":
    sys.exit(main())
