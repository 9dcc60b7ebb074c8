"""The README's and the getting-started page's claims stay true: links, extras,
commands and their options, the package map."""

import re
import tomllib
from pathlib import Path

import click
import pytest

from rwlab.cli import main

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()
GETTING_STARTED = (ROOT / "docs" / "getting_started.md").read_text()


def _blocks(text):
    return re.findall(r"```(?:bash|)\n(.*?)```", text, re.S)


def test_every_relative_link_in_the_readme_exists():
    links = re.findall(r"\]\(([^)#]+)\)", README)
    assert links
    for link in links:
        if not link.startswith("http"):
            assert (ROOT / link).exists(), link


def test_the_quick_start_extras_and_scripts_exist():
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"
    ]
    named = re.findall(r'pip install (?:-e )?"\.\[([a-z,]+)\]"', README + GETTING_STARTED)
    assert {"all", "test", "docs"} <= {e for n in named for e in n.split(",")}
    for group in named:
        for extra in group.split(","):
            assert extra in extras, extra
    assert (ROOT / "docs" / "build.py").exists()
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()
    assert ci[-1] == 'pip install -e ".[test]" && python -m pytest'
    assert 'pip install -e ".[test]" && python -m pytest' in README


def _command(words):
    """The click command a list of words names, and the words left (its arguments)."""
    cmd, rest = main, list(words)
    while rest and isinstance(cmd, click.Group) and rest[0] in cmd.commands:
        cmd = cmd.commands[rest.pop(0)]
    if rest and isinstance(cmd, click.Group) and "run" in cmd.commands:
        cmd = cmd.commands["run"]  # `rwlab diagnose RECORD ...` is `rwlab diagnose run ...`
    return cmd, rest


def _listed_commands():
    lines = []
    for block in _blocks(README) + _blocks(GETTING_STARTED):
        lines += [ln.strip() for ln in block.splitlines() if ln.strip().startswith("rwlab ")]
    return lines


@pytest.mark.parametrize("line", _listed_commands())
def test_every_listed_command_and_option_exists(line):
    words = line.split()[1:]
    first = words[0].split("|")[0]
    cmd, _ = _command([first, *[w.split("|")[0] for w in words[1:]]])
    assert cmd is not main, line
    options = {o for p in cmd.params for o in getattr(p, "opts", [])}
    for flag in re.findall(r"(?<![\w-])--[a-z][a-z-]*", line):
        assert flag in options, f"{line}: {flag} is not an option of {cmd.name}"


def test_the_package_map_names_every_module():
    text = (ROOT / "docs" / "package_map.md").read_text()
    src = ROOT / "src" / "rwlab"
    missing = []
    for path in sorted(src.rglob("*.py")):
        rel = path.relative_to(src)
        if path.name in ("__init__.py", "__main__.py") or rel.parts[0] in ("cli", "report"):
            continue  # a package's own files; cli/ and report/ are mapped as folders
        if path.name not in text and f"{path.stem}.py" not in text:
            missing.append(str(rel))
    assert not missing, f"docs/package_map.md omits {missing}"
