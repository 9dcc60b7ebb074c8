"""The import graph has no layering violation and no cycle (``python tools/importgraph.py``)."""

import sys
from pathlib import Path

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
