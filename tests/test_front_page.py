"""The docs front page's Python example runs end to end (issue 41: a runnable example per
workflow): its code blocks are run as a script, as a user would paste them."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import rwlab

INDEX = Path(__file__).resolve().parents[1] / "docs" / "index.md"


def _script() -> str:
    blocks = re.findall(r"```python\n(.*?)```", INDEX.read_text(encoding="utf-8"), re.S)
    assert blocks, "the front page shows no Python example"
    return "\n".join(blocks)


def test_the_example_calls_every_workflow_under_a_main_guard():
    """Cheap and always run: the example parses, calls each workflow ``rwlab`` exports,
    and runs under ``if __name__ == "__main__":`` (the campaign's workers import it)."""
    tree = ast.parse(_script())
    called = {
        node.func.attr
        for node in ast.walk(tree)
        if isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and isinstance(node.func.value, ast.Name)
        and node.func.value.id == "rwlab"
    }
    assert {"identify", "diagnose", "simulate", "montecarlo", "hil"} <= called
    assert all(callable(getattr(rwlab, name)) for name in called)
    guards = [n for n in tree.body if isinstance(n, ast.If) and "__main__" in ast.unparse(n.test)]
    assert guards, "the example needs an if __name__ == '__main__': guard"


@pytest.mark.slow
def test_the_front_page_example_runs_as_a_script(tmp_path):
    """The whole example, as pasted into a file and run (a few minutes on two cores)."""
    script = tmp_path / "front_page.py"
    script.write_text(_script(), encoding="utf-8")
    src = str(Path(rwlab.__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([src, os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run(
        [sys.executable, str(script)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    out = done.stdout
    assert "alarms" in out and "deg on the bus" in out
    assert (tmp_path / "t6-id" / "model.json").exists()
    assert (tmp_path / "hil" / "metrics.json").exists()
