"""Thresholds from measured false-alarm rates (rwlab.diagnose.calibration)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rwlab.diagnose.calibration import (
    RESOLVED,
    Curve,
    ThresholdCalibration,
    count_alarms,
    cusum_alarms,
    run_alarms,
)
from rwlab.diagnose.detect import Cusum, RunTest, cusum_threshold
from rwlab.errors import FileFormatError


def _direct(z, k, h, sides):
    """Restarted CUSUM alarms, one threshold, through detect.Cusum (two-sided) or by hand."""
    if sides == "both":
        c, n = Cusum(h, k, clip=math.inf), 0
        for x in z:
            if c.update(x):
                n += 1
                c.up = c.down = 0.0
        return n
    s, n = 0.0, 0
    for x in z:
        s = max(0.0, s + (x if sides == "up" else -x) - k)
        if s > h:
            n, s = n + 1, 0.0
    return n


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.lists(st.floats(-8, 8), max_size=30), min_size=1, max_size=3),
    st.floats(0.0, 3.0),
    st.sampled_from(["up", "down", "both"]),
)
def test_the_threshold_scan_counts_what_a_restarted_cusum_raises(zs, k, sides):
    grid = (0.0, 0.3, 1.0, 2.5, 6.0)
    counts = cusum_alarms([np.array(z) for z in zs], k, sides, grid)
    assert list(counts) == [sum(_direct(z, k, h, sides) for z in zs) for h in grid]


@given(st.lists(st.booleans(), max_size=60))
def test_run_counts_are_a_restarted_run_test(events):
    runs, r = [], 0
    for e in [*events, False]:
        if e:
            r += 1
        elif r:
            runs.append(r)
            r = 0
    for n, expected in enumerate(run_alarms(runs, 6), start=1):
        test, fired = RunTest(n), 0
        for e in events:
            if test.update(e):
                fired += 1
                test.restart()
        assert fired == expected


def test_count_alarms_counts_blocks_at_or_above_each_threshold():
    assert list(count_alarms([0, 1, 3, 0, 2], 4)) == [3, 2, 1, 0]


def _gaussian_calibration(rng, blocks_per_hour=100.0, hours=1000.0):
    z = rng.standard_normal(int(blocks_per_hour * hours))
    curve_alarms = cusum_alarms([z], 0.5, "both")
    from rwlab.diagnose.calibration import H_GRID

    curve = Curve("cusum", H_GRID, tuple(int(a) for a in curve_alarms), 0.5, z.size)
    return ThresholdCalibration(0.5, hours, {"speed": curve})


def test_on_gaussian_block_means_the_measured_threshold_is_siegmunds():
    # independent truth: for i.i.d. N(0, 1) block means Siegmund's ARL₀ is accurate, so
    # the threshold measured from counts must be the analytic one, and fresh data at it
    # must raise the requested rate
    rng = np.random.default_rng(3)
    cal = _gaussian_calibration(rng)
    for per_hour in (0.1, 1.0):
        arl_blocks = 100.0 / per_hour
        analytic = cusum_threshold(arl_blocks, 0.5)  # two-sided ARL₀ (each side at 2·ARL₀)
        h, note = cal.threshold("speed", per_hour, analytic=99.0)
        assert note == ""
        assert h == pytest.approx(analytic, abs=0.25)
        fresh = rng.standard_normal(100_000)
        measured = _direct(fresh, 0.5, h, "both") / 1000.0
        assert 0.6 * per_hour <= measured <= 1.6 * per_hour


def test_unresolved_rates_keep_the_higher_threshold():
    cal = _gaussian_calibration(np.random.default_rng(4), hours=200.0)
    last = cal.threshold("speed", RESOLVED / 200.0, analytic=0.0)[0]
    h, note = cal.threshold("speed", 1e-3, analytic=0.0)
    assert h > last and note == ""  # the extrapolated tail lies beyond the resolved rates
    assert cal.threshold("speed", 1e-3, analytic=h + 5)[0] == h + 5


def test_a_rate_a_detector_cannot_deliver_is_said():
    grid = (0.0, 1.0, 2.0)
    curves = {
        "friction": Curve("cusum", grid, (0, 0, 0), 11.5, 500),
        "lag": Curve("cusum", grid, (12, 4, 1), 6.0, 800),
        "dropout": Curve("count", (1.0, 2.0, 3.0), (33, 0, 0), 0.0, 2880),
    }
    cal = ThresholdCalibration(0.5, 8.0, curves)
    h, note = cal.threshold("friction", 10.0, analytic=2.0)
    assert h == 2.0 and "cannot deliver 10/h" in note
    assert cal.threshold("friction", 0.01, analytic=2.0) == (2.0, "")  # unresolvable: silent
    h, note = cal.threshold("lag", 10.0, analytic=5.0)
    assert h == 0.0 and "at most 1.5" in note
    assert cal.threshold("lag", 2.0, analytic=5.0) == (0.0, "")  # within a factor 2
    n, note = cal.threshold("dropout", 1.0, analytic=2.0)
    assert n == 2.0 and "whole events" in note
    assert cal.threshold("dropout", 3.0, analytic=2.0)[0] == 1.0


def test_calibration_file_round_trips_and_refuses_other_formats(tmp_path):
    cal = ThresholdCalibration(0.5, 2.0, {"lag": Curve("cusum", (0.0, 1.0), (3, 1), 6.0, 9)}, "x")
    path = cal.save(tmp_path / "t.json")
    assert ThresholdCalibration.load(path) == cal
    assert not list(tmp_path.glob("*.partial"))
    path.write_text(json.dumps({**cal.to_dict(), "format": "other/1"}))
    with pytest.raises(FileFormatError, match="not a threshold calibration"):
        ThresholdCalibration.load(path)
    with pytest.raises(FileFormatError, match="cannot read"):
        ThresholdCalibration.load(tmp_path / "missing.json")


def test_the_package_calibration_covers_every_detector_and_says_where_it_came_from():
    cal = ThresholdCalibration.load()
    assert {name.split("@")[0] for name in cal.curves} == {
        "friction",
        "friction_change",
        "hold",
        "motor",
        "speed",
        "offset",
        "slew",
        "lag",
        "stuck",
        "dropout",
    }
    assert cal.hours >= 8.0 and "bench/calibrate_thresholds.py" in cal.origin
    assert cal.curves["speed@0"].k == pytest.approx(0.5)  # no tolerance: the textbook k
    for name in cal.curves:
        rates = cal.rates(name)
        assert np.all(np.diff(rates) <= 0)


def test_a_rate_beyond_the_full_tolerance_is_sought_with_less_of_it():
    grid = (0.0, 1.0, 2.0)
    curves = {
        "speed": Curve("cusum", grid, (0, 0, 0), 12.0, 600),
        "speed@0.5": Curve("cusum", grid, (16, 8, 0), 6.25, 600, 0.5),
        "speed@0": Curve("cusum", grid, (400, 200, 100), 0.5, 600, 0.0),
    }
    cal = ThresholdCalibration(0.5, 8.0, curves)
    assert cal.setting("speed", 1e-3, analytic=9.0) == (9.0, 1.0, "")  # the default stays
    h, share, note = cal.setting("speed", 1.0, analytic=9.0)
    assert (share, note) == (0.5, "") and h == pytest.approx(1.0)  # 8 alarms in 8 h at h = 1
    h, share, note = cal.setting("speed", 20.0, analytic=9.0)  # 25/h at h = 1, 12.5 at 2
    assert share == 0.0 and 1.0 < h < 2.0 and note == ""
    assert cal.setting("speed", 100.0, analytic=9.0) == (0.0, 0.0, "")  # 50/h: within x2
    h, share, note = cal.setting("speed", 200.0, analytic=9.0)
    assert (h, share) == (0.0, 0.0) and note.startswith("speed: with 0% of the tolerance")
    assert "cannot deliver 200/h" in note


def test_a_flat_measured_curve_does_not_extrapolate_to_an_endless_threshold():
    """A few healthy records above every measured threshold make the curve flat; its slope
    says nothing of the tail. Extrapolated as measured, friction_change's threshold for
    1e-3/h was 6.6e15 (the detector off); at least half of Gaussian's 2k bounds it."""
    grid = tuple(0.1 * i for i in range(16))
    k = 2.8
    cal = ThresholdCalibration(
        0.5, 14.0, {"fc": Curve("cusum", grid, (5,) * 15 + (0,), k, 135)}, "x"
    )
    h, _ = cal.threshold("fc", 1e-3, analytic=0.0)
    rate_last = 5 / 14.0  # alarms per hour at the last measured threshold, 1.4
    assert 1.4 < h <= 1.4 + math.log(rate_last / 1e-3) / k + 1e-9


def test_a_curve_counted_over_several_models_holds_each_models_reference_value(tmp_path):
    """Models of different units standardise by their own σ, so one detector's k differs
    between them (friction: 10.3 for unit 300's reference, 11.6 for unit 0's); a curve
    counted over several models holds every k in their range (10 % beyond it), and the
    range survives the file."""
    curve = Curve("cusum", (0.0, 1.0), (3, 1), 11.0, 9, 1.0, (10.3, 11.6))
    assert curve.holds(10.3) and curve.holds(11.6) and curve.holds(9.4) and curve.holds(12.7)
    assert not curve.holds(9.3) and not curve.holds(12.8)
    single = Curve("cusum", (0.0, 1.0), (3, 1), 11.0, 9)
    assert single.holds(10.1) and not single.holds(9.9)  # one model: 10 % of its k
    cal = ThresholdCalibration(0.5, 2.0, {"friction": curve, "lag": single}, "x")
    assert ThresholdCalibration.load(cal.save(tmp_path / "t.json")) == cal
