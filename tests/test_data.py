import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from rwlab.data import IOData, load, merge
from rwlab.errors import DataError, FileFormatError


def test_sample_time_is_required_and_positive():
    with pytest.raises(DataError, match="Ts is required"):
        IOData([1, 2], [1, 2], None)
    for bad in (0, -0.5, float("nan"), float("inf"), "fast"):
        with pytest.raises(DataError):
            IOData([1, 2], [1, 2], bad)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_samples_are_rejected_with_location(bad):
    y = np.ones(10)
    y[4] = bad
    with pytest.raises(DataError, match="sample 4"):
        IOData(np.ones(10), y, 1.0)


def test_unequal_lengths_are_rejected():
    with pytest.raises(DataError, match="same length"):
        IOData(np.ones(10), np.ones(9), 1.0)


def test_caller_arrays_are_copied_and_never_modified():
    u, y = np.arange(10.0), np.arange(10.0) ** 2
    u0, y0 = u.copy(), y.copy()
    d = IOData(u, y, 0.5)
    d.detrend("linear").normalize()
    d.split(0.7)
    u[0] = 99.0
    assert d.u[0, 0] == 0.0
    assert np.array_equal(y, y0) and np.array_equal(u[1:], u0[1:])
    with pytest.raises(ValueError):
        d.y[0, 0] = 1.0  # stored arrays are read-only


def test_split_is_seventy_thirty_and_keeps_time():
    d = IOData(np.arange(100.0), np.arange(100.0), 0.5, tstart=2.0)
    est, val = d.split(0.7)
    assert (est.N, val.N) == (70, 30)
    assert val.time[0] == pytest.approx(2.0 + 70 * 0.5)
    assert val.y[0, 0] == 70.0
    with pytest.raises(DataError):
        d.split(1.0)


def test_slicing_with_a_step_scales_the_sample_time():
    d = IOData(np.arange(10.0), np.arange(10.0), 0.1)
    s = d[2::2]
    assert s.Ts == pytest.approx(0.2) and s.tstart == pytest.approx(0.2) and s.N == 4


def test_detrend_constant_removes_means_and_keeps_offsets():
    rng = np.random.default_rng(1)
    u, y = 3 + rng.standard_normal(50), -7 + rng.standard_normal(50)
    d = IOData(u, y, 1.0).detrend()
    assert abs(d.u.mean()) < 1e-12 and abs(d.y.mean()) < 1e-12
    assert d.trend.output_offset[0] == pytest.approx(y.mean())
    assert np.allclose(d.trend.output_to_physical(d.y[:, 0], d.time), y)


def test_detrend_linear_removes_an_exact_ramp():
    t = np.arange(40) * 0.25
    d = IOData(np.sin(t), 2.0 + 0.5 * t, 0.25).detrend("linear")
    assert np.max(np.abs(d.y)) < 1e-10
    assert d.trend.output_slope[0] == pytest.approx(0.5)


def test_normalize_maps_to_unit_interval_and_back():
    rng = np.random.default_rng(2)
    u, y = 6000 * rng.uniform(-1, 1, 80), 100 * rng.standard_normal(80)
    d = IOData(u, y, 0.5).detrend().normalize()
    assert d.u.min() == pytest.approx(0) and d.u.max() == pytest.approx(1)
    assert d.y.min() == pytest.approx(0) and d.y.max() == pytest.approx(1)
    assert np.allclose(d.trend.output_to_physical(d.y[:, 0], d.time), y)
    assert np.allclose(d.trend.input_to_physical(d.u[:, 0], d.time), u)


def test_normalize_rejects_a_constant_channel():
    with pytest.raises(DataError, match="constant"):
        IOData(np.ones(10), np.arange(10.0), 1.0).normalize()


def test_resample_halves_rate_and_keeps_slow_content():
    t = np.arange(400) * 0.1
    d = IOData(np.sin(0.2 * t), np.cos(0.2 * t), 0.1).resample(1, 2)
    assert d.Ts == pytest.approx(0.2) and d.N == 200
    assert np.allclose(d.y[20:-20, 0], np.cos(0.2 * d.time[20:-20]), atol=1e-2)


def test_merge_requires_matching_sample_times():
    a = IOData(np.ones(5), np.ones(5), 1.0)
    assert len(merge(a, a)) == 2
    with pytest.raises(DataError, match="share Ts"):
        merge(a, IOData(np.ones(5), np.ones(5), 2.0))


finite = st.floats(
    allow_nan=False, allow_infinity=False, width=64, min_value=-1e300, max_value=1e300
)


@settings(max_examples=40, deadline=None)
@given(
    values=arrays(np.float64, st.tuples(st.integers(2, 30), st.just(3)), elements=finite),
    suffix=st.sampled_from([".csv", ".parquet", ".mat"]),
    Ts=st.floats(1e-4, 1e3),
)
def test_file_round_trip_is_exact(tmp_path_factory, values, suffix, Ts):
    d = IOData(
        values[:, :2],
        values[:, 2],
        Ts,
        input_names=["cmd", "aux"],
        output_names=["speed"],
        output_units=["rpm"],
    )
    path = d.write(tmp_path_factory.mktemp("io") / f"rec{suffix}")
    back = load(path)
    assert np.array_equal(back.u, d.u) and np.array_equal(back.y, d.y)
    assert back.Ts == pytest.approx(Ts, rel=1e-9)
    assert back.input_names == ("cmd", "aux") and back.output_units == ("rpm",)


def test_write_never_overwrites_and_leaves_no_partial_file(tmp_path):
    d = IOData(np.ones(5), np.arange(5.0), 1.0)
    path = d.write(tmp_path / "a.csv")
    before = path.read_bytes()
    with pytest.raises(FileExistsError):
        d.write(path)
    assert path.read_bytes() == before
    with pytest.raises(DataError):
        d.write(tmp_path / "a.xlsx")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv"]


def test_reading_garbage_is_a_typed_error(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,u,y\n0,1,2\n0.5,abc,3\n")
    with pytest.raises(FileFormatError, match="line 3"):
        load(bad)
    binary = tmp_path / "x.parquet"
    binary.write_bytes(b"\x00\x01 not parquet")
    with pytest.raises(FileFormatError):
        load(binary)
    mat = tmp_path / "x.mat"
    mat.write_text("not a mat file")
    with pytest.raises(FileFormatError):
        load(mat)


def test_csv_without_time_needs_ts_and_nonuniform_time_is_refused(tmp_path):
    plain = tmp_path / "plain.csv"
    plain.write_text("u,y\n1,2\n3,4\n")
    with pytest.raises(DataError, match="Ts is required"):
        load(plain)
    assert load(plain, Ts=0.5).Ts == 0.5
    jitter = tmp_path / "jitter.csv"
    jitter.write_text("time_s,u,y\n0,1,2\n0.5,1,2\n1.2,1,2\n")
    with pytest.raises(DataError, match="uniformly"):
        load(jitter)
