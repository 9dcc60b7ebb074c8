"""The import graph has no layering violation and no cycle (``python tools/importgraph.py``)."""

import ast
import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
import importgraph


def test_no_module_imports_a_higher_layer():
    assert importgraph.violations(importgraph.imports()) == []


def test_no_cycle_between_packages_or_modules():
    graph = importgraph.imports()
    assert importgraph.cycles(graph) == []
    assert importgraph.cycles(graph, packages=False) == []


def test_the_checker_sees_what_it_must():
    """Against a hand-made tree: a lazy upward import and a cycle are both found."""
    graph = {
        "rwlab.data": {"rwlab.testbed.load"},  # data reaching up (the old data.load)
        "rwlab.testbed.load": {"rwlab.data"},
        "rwlab.ident.study": {"rwlab.data"},
    }
    assert importgraph.violations(graph) == [("rwlab.data", "rwlab.testbed.load")]
    assert importgraph.cycles(graph) == [["data", "testbed"]]
    modules = {"rwlab.attitude.a": {"rwlab.attitude.b"}, "rwlab.attitude.b": {"rwlab.attitude.a"}}
    assert importgraph.cycles(modules) == []  # inside one package: only module-wise
    assert importgraph.cycles(modules, packages=False) == [["rwlab.attitude.a", "rwlab.attitude.b"]]


def test_the_real_graph_is_read_including_imports_inside_functions():
    graph = importgraph.imports()
    assert "rwlab.datafiles" in graph["rwlab.testbed.load"]
    assert "rwlab.ident.model_file" in graph["rwlab.wheel.identified"]
    assert "testbed" not in {m.split(".")[1] for m in graph["rwlab.ident.study"]}
    assert {importgraph.layer(m) for m in importgraph.modules()} <= set(
        range(len(importgraph.LAYERS))
    )


def test_a_format_is_read_by_the_reader_its_owner_registers(tmp_path):
    import numpy as np

    from rwlab import data
    from rwlab.errors import DataError

    calls = []

    def read_two_columns(path, Ts, **options):
        calls.append(options)
        table = np.loadtxt(path)
        return data.IOData(table[:, 0], table[:, 1], Ts or 1.0, source={"reader": "x2"})

    path = tmp_path / "r.x2col"
    np.savetxt(path, np.c_[np.arange(5.0), 2 * np.arange(5.0)])
    try:
        data.register_reader(".x2col", read_two_columns)
        z = data.load(path, 0.5, flag=1)
    finally:
        data._READERS.pop(".x2col", None)
    assert calls == [{"flag": 1}] and z.Ts == 0.5 and np.array_equal(z.y[:, 0], 2 * z.u[:, 0])
    assert z[1:3].source == {"reader": "x2"}  # the source survives slicing
    with pytest.raises(DataError, match="unknown data file type"):
        data.load(path)


def test_the_data_layer_names_no_reader_of_a_higher_layer():
    """rwlab.data imports nothing above it, not even by name: its readers and writers come
    from the entry points that rwlab's pyproject declares, one per suffix, each the owner's
    function."""
    import importlib.metadata
    import tomllib

    from rwlab import data

    graph = importgraph.imports()
    assert {importgraph.layer(m) for m in graph["rwlab.data"]} <= {
        0,
        importgraph.layer("rwlab.data"),
    }
    tree = ast.parse(Path(data.__file__).read_text(encoding="utf-8"))
    named = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)}
    assert not named & set(importgraph.modules()), "data names a module to import"
    root = Path(__file__).resolve().parent.parent
    declared = tomllib.loads((root / "pyproject.toml").read_text())["project"]["entry-points"]
    assert declared[data.READERS]["mcap"] == "rwlab.testbed.load:read_mcap"
    assert set(declared[data.WRITERS]) == {"csv", "parquet", "mat"}
    installed = {p.name: p.value for p in importlib.metadata.entry_points(group=data.READERS)}
    if installed != declared[data.READERS]:
        pytest.skip("rwlab's installed metadata is stale: pip install -e . (its entry points)")
    for group in (data.READERS, data.WRITERS):
        for point in importlib.metadata.entry_points(group=group):
            assert callable(point.load()), point


def test_reading_a_format_imports_only_its_owner(tmp_path):
    """In a fresh interpreter: rwlab.data alone does not import rwlab.testbed; reading a
    CSV does not either; reading an .mcap imports the module its entry point names."""
    import importlib.metadata
    import subprocess

    from rwlab import data
    from rwlab.testbed import ExperimentConfig, run_experiment

    if "mcap" not in {p.name for p in importlib.metadata.entry_points(group=data.READERS)}:
        pytest.skip("rwlab's installed metadata is stale: pip install -e . (its entry points)")
    run_experiment(ExperimentConfig(duration=20, Ts=0.5, seed=1), tmp_path / "r.mcap")
    (tmp_path / "d.csv").write_text("time_s,u,y\n0,1,2\n0.5,2,3\n1.0,3,4\n")
    code = (
        "import sys, rwlab.data as d\n"
        "d.load(sys.argv[1] + '/d.csv', input_columns='u', output_columns='y')\n"
        "assert not any(m.startswith('rwlab.testbed') for m in sys.modules), 'csv'\n"
        "z = d.load(sys.argv[1] + '/r.mcap')\n"
        "assert 'rwlab.testbed.load' in sys.modules and 'wheel' in z.source\n"
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parent.parent / "src")}
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path)], env=env, capture_output=True)
    assert done.returncode == 0, done.stderr.decode()


def test_imports_for_annotations_and_by_name_are_dependencies(tmp_path):
    """A type-only import, and an import_module of a constant name, are edges: two modules
    that need each other only for annotations are still a cycle."""
    pkg = tmp_path / "rwlab"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from rwlab import b\n"
        "else:\n    import rwlab.errors\n"
    )
    (pkg / "b.py").write_text("def f():\n    from rwlab import a\n")
    (pkg / "c.py").write_text("import importlib\nimportlib.import_module('rwlab.b')\n")
    (pkg / "errors.py").write_text("")
    graph = importgraph.imports(tmp_path)
    assert graph == {
        "rwlab.a": {"rwlab.b", "rwlab.errors"},
        "rwlab.b": {"rwlab.a"},
        "rwlab.c": {"rwlab.b"},
    }
    assert importgraph.cycles(graph, packages=False) == [["rwlab.a", "rwlab.b"]]


def test_no_module_takes_a_private_name_from_another():
    """src only (tests may reach into a module): a name another module needs is public."""
    assert importgraph.private_imports() == []


def test_the_private_name_check_sees_what_it_must(tmp_path):
    pkg = tmp_path / "rwlab"
    (pkg / "cli").mkdir(parents=True)
    for f in ("__init__.py", "a.py", "cli/__init__.py", "cli/_common.py"):
        (pkg / f).write_text("def _own():\n    pass\n\n\ndef public():\n    _own()\n")
    (pkg / "b.py").write_text("from rwlab.a import _own, public\n")
    (pkg / "c.py").write_text("from rwlab import a\n\na._own()\na.public()\n")
    (pkg / "cli" / "x.py").write_text("from rwlab.cli._common import _own\n")  # its package's
    (pkg / "d.py").write_text("from rwlab.cli._common import _own\n")  # another package's
    assert importgraph.private_imports(tmp_path) == [
        ("rwlab.b", "rwlab.a._own"),
        ("rwlab.c", "rwlab.a._own"),
        ("rwlab.d", "rwlab.cli._common._own"),
    ]
