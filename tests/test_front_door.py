"""Every input checked at the door (issue 45, item 2).

JSON depth and types against the schemas, implausible time units warned with the
number, python-control models and pandas frames accepted where a MATLAB user passes
them, ``python -m rwlab``, and no Python name in a command-line message.
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import rwlab
from rwlab.data import IOData, load
from rwlab.errors import DataError, FileFormatError, ModelError, RwlabError, RwlabWarning
from rwlab.ident.model_file import WheelModelFile
from rwlab.schemas import MAX_DEPTH, json_depth, read_json
from tests.test_bad_inputs import MODEL

JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=5),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=4), inner, max_size=4)
    ),
    max_leaves=30,
)


def _depth(v) -> int:  # the textbook recursive definition
    if isinstance(v, dict):
        return 1 + max((_depth(x) for x in v.values()), default=0)
    if isinstance(v, list):
        return 1 + max((_depth(x) for x in v), default=0)
    return 0


@given(JSON)
def test_json_depth_is_the_recursive_definition(value):
    assert json_depth(value) == _depth(value)


@pytest.mark.parametrize("depth", [MAX_DEPTH, MAX_DEPTH + 1, 100_000])
def test_deep_json_is_refused_with_one_typed_error(tmp_path, depth):
    path = tmp_path / "deep.json"
    path.write_text("[" * depth + "]" * depth)
    if depth <= MAX_DEPTH:
        assert json_depth(read_json(path)) == depth
        return
    with pytest.raises(FileFormatError, match=f"nests deeper than {MAX_DEPTH} levels"):
        read_json(path, what="model file")
    with pytest.raises(FileFormatError, match="nests deeper"):  # no RecursionError
        WheelModelFile.load(path)


def _model(**changes) -> dict:
    m = json.loads(json.dumps(MODEL))
    for key, value in changes.items():
        *path, last = key.split(".")
        where = m
        for p in path:
            where = where[p]
        where[last] = value
    return m


@pytest.mark.parametrize(
    ("field", "value", "said"),
    [
        ("model.Ts", "0.5", "model.Ts: '0.5' is not of type 'number'"),
        ("Ts", "0.5", "Ts: '0.5' is not of type 'number'"),
        ("model.A", [1.0, "x"], "model.A[1]: 'x' is not of type 'number'"),
        ("input.offset", None, "input.offset: None is not of type 'number'"),
        ("model.nk", [-1], "model.nk[0]: -1 is less than the minimum of 0"),
    ],
)
def test_a_model_field_of_the_wrong_type_is_refused_naming_it(tmp_path, field, value, said):
    path = tmp_path / "m.json"
    path.write_text(json.dumps(_model(**{field: value})))
    with pytest.raises(FileFormatError) as info:
        WheelModelFile.load(path)
    assert str(info.value) == f"{path}: {said}"


def test_the_valid_model_still_loads(tmp_path):
    path = tmp_path / "m.json"
    path.write_text(json.dumps(_model()))
    assert WheelModelFile.load(path).Ts == 0.5


@settings(max_examples=150, deadline=None)
@given(JSON, st.sampled_from(["model", "input", "saturation", "Ts", "model.A", "model.Ts"]))
def test_any_json_in_any_field_is_read_or_refused_with_a_typed_error(value, field):
    d = _model(**{field: value})
    try:
        WheelModelFile.from_dict(d, source="m.json")
    except RwlabError:
        pass


# -- time units ----------------------------------------------------------------------------


def _csv(path, column: str, step: float, n: int = 200) -> None:
    rng = np.random.default_rng(1)
    rows = [f"{column},command,speed_rpm"]
    rows += [f"{k * step!r},{rng.standard_normal()},{rng.standard_normal()}" for k in range(n)]
    path.write_text("\n".join(rows) + "\n")


def test_a_time_column_in_milliseconds_is_warned_with_the_number(tmp_path):
    path = tmp_path / "ms.csv"
    _csv(path, "time_s", 100.0)
    with pytest.warns(RwlabWarning, match=r"Ts = 100 s, implausible .* Ts is 0\.1 s"):
        data = load(path)
    assert data.Ts == 100.0  # read as written: a warning, not a guess
    _csv(path, "time_ms", 100.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load(path).Ts == pytest.approx(0.1)
    _csv(path, "time_s", 1.0, n=100_000)  # 1 kHz in ms: Ts = 1 "s", 28 hours
    with pytest.warns(RwlabWarning, match="spanning 1.16 days"):
        load(path)


@pytest.mark.parametrize("step", [0.001, 0.1, 0.5, 9.0])
def test_plausible_time_columns_are_not_warned(tmp_path, step):
    path = tmp_path / "ok.csv"
    _csv(path, "time_s", step)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load(path).Ts == pytest.approx(step)


# -- pandas ------------------------------------------------------------------------------------


def test_from_pandas_reads_to_pandas_back_and_time_columns():
    pd = pytest.importorskip("pandas")
    rng = np.random.default_rng(2)
    data = IOData(rng.standard_normal(50), rng.standard_normal((50, 2)), 0.25, tstart=3.0)
    frame = data.to_pandas()
    before = frame.copy()
    back = IOData.from_pandas(frame, u="u1", y=["y1", "y2"])
    pd.testing.assert_frame_equal(frame, before)  # the frame is not modified
    assert back.Ts == 0.25 and back.tstart == 3.0
    assert np.array_equal(back.u, data.u) and np.array_equal(back.y, data.y)
    plain = frame.reset_index(drop=True)
    with pytest.raises(DataError, match="sample time Ts is required"):
        IOData.from_pandas(plain, u="u1", y="y1")
    assert IOData.from_pandas(plain, y="y1", Ts=0.5).nu == 0  # a time series
    timed = plain.assign(time_ms=np.arange(50) * 20.0)
    assert IOData.from_pandas(timed, u="u1", y="y1").Ts == pytest.approx(0.02)
    stamped = plain.set_index(pd.date_range("2026-01-01", periods=50, freq="100ms"))
    assert IOData.from_pandas(stamped, u="u1", y="y1").Ts == pytest.approx(0.1)
    with pytest.raises(DataError, match="disagrees"):
        IOData.from_pandas(stamped, u="u1", y="y1", Ts=0.2)
    with pytest.raises(DataError, match="no column 'nope'"):
        IOData.from_pandas(plain, u="nope", y="y1", Ts=1)
    with pytest.raises(DataError, match="must be numeric"):
        IOData.from_pandas(plain.assign(s="a"), u="s", y="y1", Ts=1)
    uneven = plain.assign(time_s=np.r_[0.0, np.cumsum(rng.uniform(0.5, 1.5, 49))])
    with pytest.raises(DataError, match="not uniformly sampled"):
        IOData.from_pandas(uneven, u="u1", y="y1")


# -- python-control models -------------------------------------------------------------------


@pytest.fixture(scope="module")
def first_order():
    Ts = 0.1
    gc = control.tf([2.0], [1.0, 1.0])
    gd = control.sample_system(gc, Ts, "zoh")
    u = np.random.default_rng(0).standard_normal(400)
    y = control.forced_response(gd, T=Ts * np.arange(400), U=u).outputs
    return gc, gd, IOData(u, y, Ts)


def test_compare_takes_python_control_models(first_order):
    gc, gd, data = first_order
    assert rwlab.compare(gd, data).fit_percent == pytest.approx(100, abs=1e-6)
    assert rwlab.compare(control.ss(gd), data).fit_percent == pytest.approx(100, abs=1e-6)
    with pytest.warns(
        RwlabWarning, match="discretised by zero-order hold at the data's Ts = 0.1"
    ) as caught:
        assert rwlab.compare(gc, data).fit_percent == pytest.approx(100, abs=1e-6)
    assert caught[0].filename == __file__  # the warning points at the caller's line
    with pytest.raises(ModelError, match=r"dt = 0\.2 s and the data at Ts = 0\.1 s"):
        rwlab.compare(control.sample_system(gc, 0.2, "zoh"), data)
    with pytest.raises(ModelError, match="not str"):
        rwlab.compare("G", data)


# -- the command line ------------------------------------------------------------------------


def test_python_dash_m_rwlab_is_the_command_line():
    r = subprocess.run(
        [sys.executable, "-m", "rwlab", "--help"], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0 and r.stdout.startswith("Usage: rwlab")


def test_a_wheel_fault_is_said_in_the_command_lines_words():
    from rwlab.cli._common import _message
    from rwlab.errors import WheelFault

    text = _message(WheelFault("wheel 0 reports fault WATCHDOG; call clear_fault() once the cause"))
    assert "clear_fault" not in text and "rwlab wheel cmd clear" in text
