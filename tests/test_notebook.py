"""Objects a notebook shows: short reprs, HTML tables, pandas exports, typed errors."""

import inspect

import numpy as np
import pytest

from rwlab import datasets, errors
from rwlab._display import summarize
from rwlab.attitude.scenario import SCENARIOS
from rwlab.attitude.sim import PDController, simulate
from rwlab.ident import arx, etfe, n4sid


@pytest.fixture(scope="module")
def dryer():
    return datasets.get("dryer")


def test_a_simulation_prints_its_shapes_not_its_samples():
    run = simulate(SCENARIOS["geo-smallsat"], PDController(20.0, 400.0), duration=300)
    text = repr(run)
    assert len(text) < 1500 and "array(" in text and str(run.t.size) in text
    assert "<table>" in run._repr_html_()
    np.set_printoptions(threshold=10**9)  # whole arrays would be printed in full now
    try:
        assert len(repr(run)) < 1500
    finally:
        np.set_printoptions(threshold=1000)


def test_summarize_keeps_small_values_and_shortens_large_ones():
    assert summarize(np.array([1.0, 2.0])) == "[1., 2.]"
    assert summarize(np.zeros((5, 3))) == "array(5, 3 float64)"
    assert summarize(list(range(100))) == "[100 items]"
    assert summarize(0.1 + 0.2) == "0.3"


def test_models_and_data_have_html_and_short_reprs(dryer):
    m = arx(dryer, 2, 2, 3)
    ss = n4sid(dryer, 2)
    for obj in (m, ss):
        assert len(repr(obj)) < 100
        page = obj._repr_html_()
        assert "<table>" in page and "stable" in page
    page = dryer._repr_html_()
    assert f"N = {dryer.N}" in page and dryer.output_names[0] in page


def test_to_pandas_is_the_data_itself(dryer):
    pd = pytest.importorskip("pandas")
    frame = dryer.to_pandas()
    assert isinstance(frame, pd.DataFrame) and frame.shape == (dryer.N, dryer.nu + dryer.ny)
    assert np.array_equal(frame.to_numpy(), np.hstack([dryer.u, dryer.y]))
    assert np.allclose(frame.index.to_numpy(), dryer.time)
    g = etfe(dryer)
    table = g.to_pandas()
    assert np.allclose(table["magnitude_db[0,0]"], g.magnitude_db()[:, 0, 0])


def test_every_error_class_lives_in_rwlab_errors():
    import rwlab

    mods = [m for m in _walk(rwlab) if m.__name__ != "rwlab.errors"]
    for mod in mods:
        for name, obj in vars(mod).items():
            if inspect.isclass(obj) and issubclass(obj, Exception | Warning):
                if obj.__module__.startswith("rwlab"):
                    assert obj.__module__ == "rwlab.errors", f"{mod.__name__}.{name}"
    from rwlab.attitude.design import DesignError
    from rwlab.wheel.protocol import ProtocolError

    assert DesignError is errors.DesignError and ProtocolError is errors.ProtocolError
    assert issubclass(DesignError, errors.RwlabError)


def _walk(package):
    import importlib
    import pkgutil

    out = [package]
    for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
        if info.name.endswith("__main__"):
            continue
        out.append(importlib.import_module(info.name))
    return out
