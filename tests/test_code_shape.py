"""The shape the code keeps (issue 27): no function with more than 15 parameters, no module
over 600 lines without its docstring saying why, no command-line module over 500 lines."""

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "rwlab"
MAX_PARAMETERS = 15
MAX_LINES = 600
MAX_CLI_LINES = 500
WHY = "Why this module is long:"


def _modules():
    return sorted(SRC.rglob("*.py"))


def parameters(func: ast.FunctionDef | ast.AsyncFunctionDef) -> list[str]:
    """A function's named parameters (``self`` and ``cls`` not counted, nor ``*args`` or
    ``**kwargs``: a function that takes keywords through ``**`` names them elsewhere)."""
    a = func.args
    return [p.arg for p in (*a.posonlyargs, *a.args, *a.kwonlyargs) if p.arg not in ("self", "cls")]


def too_many_parameters(source: str) -> list[tuple[str, int]]:
    """(name, count) of every function in ``source`` with more than MAX_PARAMETERS."""
    return [
        (node.name, len(parameters(node)))
        for node in ast.walk(ast.parse(source))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
        and len(parameters(node)) > MAX_PARAMETERS
    ]


def long_without_reason(source: str) -> bool:
    """More than MAX_LINES lines and no ``Why this module is long:`` in the docstring."""
    if len(source.splitlines()) <= MAX_LINES:
        return False
    return WHY not in (ast.get_docstring(ast.parse(source)) or "")


def test_no_function_has_more_than_15_parameters():
    found = [
        f"{path.relative_to(SRC)}: {name} ({n})"
        for path in _modules()
        for name, n in too_many_parameters(path.read_text(encoding="utf-8"))
    ]
    assert not found, f"group them into a frozen config record: {found}"


def test_no_module_is_over_600_lines_without_saying_why():
    found = [
        f"{path.relative_to(SRC)} ({len(path.read_text(encoding='utf-8').splitlines())} lines)"
        for path in _modules()
        if long_without_reason(path.read_text(encoding="utf-8"))
    ]
    assert not found, f"split it along its concepts, or say {WHY!r} in its docstring: {found}"


def test_no_command_line_module_is_over_500_lines():
    long = [
        p.name
        for p in (SRC / "cli").glob("*.py")
        if len(p.read_text().splitlines()) > MAX_CLI_LINES
    ]
    assert not long


@pytest.mark.parametrize("n", [15, 16])
def test_the_checks_see_what_they_must(n):
    params = ", ".join(f"p{k}" for k in range(n))
    source = f"class C:\n    def f(self, {params}, *args, **kwargs):\n        pass\n"
    assert too_many_parameters(source) == ([] if n == 15 else [("f", 16)])
    body = "x = 1\n" * MAX_LINES
    assert long_without_reason(f'"""A module."""\n{body}')
    assert not long_without_reason(f'"""A module.\n\n{WHY} one loop, kept whole."""\n{body}')
    assert not long_without_reason('"""A module."""\n' + "x = 1\n" * (MAX_LINES - 1))
