"""Thresholds from measured false-alarm rates (rwlab.diagnose.calibration)."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rwlab.diagnose.calibration import (
    RESOLVED,
    SHARES,
    Curve,
    ThresholdCalibration,
    count_alarms,
    cusum_alarms,
    cusum_alarms_k,
    cusum_curves,
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
    both = cusum_alarms_k([np.array(z) for z in zs], (k, k + 0.7), sides, grid)
    assert list(both[1]) == [sum(_direct(z, k + 0.7, h, sides) for z in zs) for h in grid]
    assert list(both[0]) == list(counts)


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
    return ThresholdCalibration(0.5, hours, cusum_curves("speed", [([z], 0.5)], "both"))


def test_on_gaussian_block_means_the_measured_threshold_is_siegmunds():
    # independent truth: for i.i.d. N(0, 1) block means Siegmund's ARL₀ is accurate, so
    # the threshold measured from counts must be the analytic one, and fresh data at it
    # must raise the requested rate
    rng = np.random.default_rng(3)
    cal = _gaussian_calibration(rng)
    for per_hour in (0.1, 1.0):
        arl_blocks = 100.0 / per_hour
        analytic = cusum_threshold(arl_blocks, 0.5)  # two-sided ARL₀ (each side at 2·ARL₀)
        h, note = cal.threshold("speed", per_hour, analytic=99.0, k=0.5)
        assert note == ""
        assert h == pytest.approx(analytic, abs=0.25)
        fresh = rng.standard_normal(100_000)
        measured = _direct(fresh, 0.5, h, "both") / 1000.0
        assert 0.6 * per_hour <= measured <= 1.6 * per_hour


def _ar1(rng, n, phi):
    """A stationary AR(1) stream of unit variance."""
    e = rng.standard_normal(n) * math.sqrt(1 - phi**2)
    x = np.empty(n)
    x[0] = rng.standard_normal()
    for i in range(1, n):
        x[i] = phi * x[i - 1] + e[i]
    return x


@pytest.mark.parametrize("phi", [0.0, 0.5])
def test_a_model_whose_k_no_calibration_model_had_gets_the_rate_asked(phi):
    """A model's test compares the other units with its reference's level μ, against an
    absolute bound B (k = 0.5 + B − μ, as the motor test's datasheet headroom): models
    whose reference sits elsewhere in the spread have another k. Counted with three
    models (k = 2.9–3.5), a model whose reference sits low (k = 5, outside) gets
    thresholds whose rate, simulated independently on held-out units, is the one asked:
    on Gaussian block means and on AR(1) ones (φ = 0.5, whose rate no i.i.d. formula
    gives)."""
    rng = np.random.default_rng(11)
    per_h, hours, bound = 100.0, 200.0, 0.5
    n = int(per_h * hours)
    models = [(0.0, 0.5 + bound), (0.3, 0.5 + bound - 0.3), (0.6, 0.5 + bound - 0.6)]
    per_model = [([_ar1(rng, n, phi) - mu], k) for mu, k in models]
    cal = ThresholdCalibration(0.5, 3 * hours, cusum_curves("motor", per_model, "up"))
    mu, k = -1.5, 0.5 + bound + 1.5
    fresh = _ar1(rng, 2 * n, phi) - mu  # held-out units, through the new model's reference
    for per_hour in (1.0, 10.0):
        s = cal.setting("motor", per_hour, analytic=99.0, k=k)
        assert (s.k, s.share, s.note, s.info) == (k, 1.0, "", "")
        measured = _direct(fresh, k, s.threshold, "up") / (2 * hours)
        assert 0.75 * per_hour <= measured <= 1.33 * per_hour, (per_hour, measured)


def test_unresolved_rates_keep_the_higher_threshold_and_say_so():
    cal = _gaussian_calibration(np.random.default_rng(4), hours=200.0)
    last = cal.threshold("speed", RESOLVED / 200.0, analytic=0.0, k=0.5)[0]
    s = cal.setting("speed", 1e-3, analytic=0.0, k=0.5)
    assert s.threshold > last and s.note == ""  # the tail lies beyond the resolved rates
    assert "extrapolated" in s.info and "not verified" in s.info
    s = cal.setting("speed", 1e-3, analytic=s.threshold + 5, k=0.5)
    assert "the analytic one" in s.info and s.note == ""
    measured = cal.setting("speed", 1.0, analytic=0.0, k=0.5)
    assert measured.info == measured.note == ""  # a measured rate needs no word


def test_a_rate_a_detector_cannot_deliver_is_said():
    grid = (0.0, 1.0, 2.0)
    curves = {
        "friction@0": Curve("cusum", grid, (0, 0, 0), 0.5, 500, 0.0),
        "friction@1": Curve("cusum", grid, (0, 0, 0), 11.5, 500, 1.0),
        "lag@1": Curve("cusum", grid, (12, 4, 1), 6.0, 800),
        "dropout": Curve("count", (1.0, 2.0, 3.0), (33, 0, 0), 0.0, 2880),
    }
    cal = ThresholdCalibration(0.5, 8.0, curves)
    s = cal.setting("friction", 10.0, analytic=2.0, k=11.5)
    assert s.threshold == 2.0 and "cannot deliver 10/h" in s.note and s.k == 0.5
    s = cal.setting("friction", 0.01, analytic=2.0, k=11.5)  # unresolvable: said, no warning
    assert (s.threshold, s.k, s.note) == (2.0, 11.5, "") and "analytic" in s.info
    h, note = cal.threshold("lag", 10.0, analytic=5.0, k=6.0)
    assert h == 0.0 and "at most 1.5" in note
    assert cal.threshold("lag", 2.0, analytic=5.0, k=6.0) == (0.0, "")  # within a factor 2
    n, note = cal.threshold("dropout", 1.0, analytic=2.0)
    assert n == 2.0 and "whole events" in note
    assert cal.threshold("dropout", 3.0, analytic=2.0)[0] == 1.0


def test_calibration_file_round_trips_and_reads_the_first_format(tmp_path):
    curve = Curve("cusum", (0.0, 1.0), (3, 1), 6.0, 9, 0.5)
    cal = ThresholdCalibration(0.5, 2.0, {"lag@0.5": curve, "lag@1": Curve("cusum", (0.0,), (1,))})
    path = cal.save(tmp_path / "t.json")
    assert ThresholdCalibration.load(path) == cal
    assert not list(tmp_path.glob("*.partial"))
    path.write_text(json.dumps({**cal.to_dict(), "format": "other/1"}))
    with pytest.raises(FileFormatError, match="not a threshold calibration"):
        ThresholdCalibration.load(path)
    # the first format: the whole tolerance's curve under the plain name, a k range
    old = {
        "format": "rwlab.ThresholdCalibration/1",
        "Ts": 0.5,
        "hours": 2.0,
        "curves": {
            "lag": {"kind": "cusum", "k": 6.0, "decisions": 9, "share": 1.0,
                    "k_range": [5.0, 7.0], "thresholds": [0.0, 1.0], "alarms": [3, 1]},
            "stuck": {"kind": "count", "k": 0.0, "decisions": 9, "share": 1.0,
                      "thresholds": [1.0, 2.0], "alarms": [2, 0]},
        },
    }  # fmt: skip
    path.write_text(json.dumps(old))
    read = ThresholdCalibration.load(path)
    assert set(read.curves) == {"lag@1", "stuck"} and read.family("lag") == [(1.0, "lag@1")]
    path.write_text(json.dumps({**old, "curves": {"lag": {"kind": "cusum"}}}))
    with pytest.raises(FileFormatError, match="bad or missing field"):
        ThresholdCalibration.load(path)
    with pytest.raises(FileFormatError, match="cannot read"):
        ThresholdCalibration.load(tmp_path / "missing.json")


def test_the_package_calibration_covers_every_detector_over_shares_of_its_tolerance():
    cal = ThresholdCalibration.load()
    assert {name.split("@")[0] for name in cal.curves} == {
        "friction",
        "friction_change",
        "hold",
        "motor",
        "speed",
        "offset",
        "slew",
        "slew_change",
        "lag",
        "stuck",
        "dropout",
    }
    assert cal.hours >= 8.0 and "bench/calibrate_thresholds.py" in cal.origin
    for name in ("friction", "motor", "speed", "lag", "slew", "friction_change"):
        assert [s for s, _ in cal.family(name)] == sorted(SHARES)
        assert cal.curves[f"{name}@0"].k == pytest.approx(0.5)  # no tolerance: textbook k
    assert [s for s, _ in cal.family("offset")] == [1.0]  # no tolerance to share
    for name in cal.curves:
        rates = cal.rates(name)
        assert np.all(np.diff(rates) <= 0)
    # more tolerance, fewer alarms: at the lowest threshold the rate falls with the share
    for name in ("friction", "motor", "lag"):
        first = [cal.curves[key].alarms[0] for _, key in cal.family(name)]
        assert all(x >= y for x, y in itertools.pairwise(first)), name


def test_a_rate_beyond_the_models_tolerance_is_sought_with_less_of_it():
    grid = (0.0, 1.0, 2.0)
    curves = {
        "speed@1": Curve("cusum", grid, (0, 0, 0), 12.0, 600, 1.0),
        "speed@0.5": Curve("cusum", grid, (16, 8, 0), 6.25, 600, 0.5),
        "speed@0": Curve("cusum", grid, (400, 200, 100), 0.5, 600, 0.0),
    }
    cal = ThresholdCalibration(0.5, 8.0, curves)
    s = cal.setting("speed", 1e-3, analytic=9.0, k=12.0)
    assert (s.threshold, s.k, s.note) == (9.0, 12.0, "")  # the default keeps the model's k
    s = cal.setting("speed", 1.0, analytic=9.0, k=10.0)  # this model's half: 5.25 σ
    assert (s.k, s.share, s.note) == (5.25, 0.5, "") and s.threshold == pytest.approx(1.0)
    s = cal.setting("speed", 20.0, analytic=9.0, k=12.0)  # 25/h at h = 1, 12.5 at 2
    assert (s.k, s.share) == (0.5, 0.0) and 1.0 < s.threshold < 2.0 and s.note == ""
    assert cal.threshold("speed", 100.0, analytic=9.0, k=12.0) == (0.0, "")  # 50/h: x2
    s = cal.setting("speed", 200.0, analytic=9.0, k=12.0)
    assert (s.threshold, s.k) == (0.0, 0.5) and "cannot deliver 200/h" in s.note


def test_a_flat_measured_curve_does_not_extrapolate_to_an_endless_threshold():
    """A few healthy records above every measured threshold make the curve flat; its slope
    says nothing of the tail. Extrapolated as measured, friction_change's threshold for
    1e-3/h was 6.6e15 (the detector off); at least half of Gaussian's 2k bounds it."""
    grid = tuple(0.1 * i for i in range(16))
    k = 2.8
    cal = ThresholdCalibration(
        0.5, 14.0, {"fc@1": Curve("cusum", grid, (5,) * 15 + (0,), k, 135)}, "x"
    )
    h, _ = cal.threshold("fc", 1e-3, analytic=0.0, k=k)
    rate_last = 5 / 14.0  # alarms per hour at the last measured threshold, 1.4
    assert 1.4 < h <= 1.4 + math.log(rate_last / 1e-3) / k + 1e-9
