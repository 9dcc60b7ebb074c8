"""The import graph has no layering violation and no cycle (``python tools/importgraph.py``)."""

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


def test_the_real_graph_is_read_including_imports_inside_functions():
    graph = importgraph.imports()
    assert "rwlab.datafiles" in graph["rwlab.testbed.load"]
    assert "rwlab.ident.model_file" in graph["rwlab.wheel.identified"]
    assert "rwlab.testbed" not in {m.split(".")[1] for m in graph["rwlab.ident.study"]}
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


def test_the_data_layer_imports_the_testbed_only_to_read_a_record(tmp_path):
    """In a fresh interpreter: rwlab.data alone does not import rwlab.testbed; reading a
    CSV does not either; reading an .mcap imports the module that registered it."""
    import subprocess

    from rwlab.testbed import ExperimentConfig, run_experiment

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


def test_imports_for_annotations_only_are_not_dependencies(tmp_path):
    pkg = tmp_path / "rwlab"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from rwlab import b\n"
        "else:\n    import rwlab.errors\n"
    )
    (pkg / "b.py").write_text("def f():\n    from rwlab import a\n")
    (pkg / "errors.py").write_text("")
    graph = importgraph.imports(tmp_path)
    assert graph == {"rwlab.a": {"rwlab.errors"}, "rwlab.b": {"rwlab.a"}}
