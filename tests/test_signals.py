import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rwlab import signals
from rwlab.errors import ConfigError


def _runs(x):
    """Lengths of the runs of equal consecutive values."""
    edges = np.flatnonzero(np.diff(x)) + 1
    return np.diff(np.concatenate([[0], edges, [len(x)]]))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31), min_hold=st.floats(0.5, 20), amp=st.floats(1, 8000))
def test_prbs_respects_amplitude_and_minimum_hold(seed, min_hold, amp):
    Ts = 0.5
    x = signals.prbs(600, Ts, amp, min_hold, seed=seed)
    assert x.shape == (1200,)
    assert np.max(np.abs(x)) <= amp
    runs = _runs(x)
    assert runs[:-1].min() >= np.ceil(min_hold / Ts - 1e-9)  # the last run may be cut short


def test_prbs_is_reproducible_and_seed_dependent():
    a = signals.prbs(1200, 0.5, 6000, 5, seed=7)
    assert np.array_equal(a, signals.prbs(1200, 0.5, 6000, 5, seed=7))
    assert not np.array_equal(a, signals.prbs(1200, 0.5, 6000, 5, seed=8))
    b = signals.prbs(300, 0.5, 100, 5, levels="binary", seed=1)
    assert set(np.unique(b)) == {-100.0, 100.0}


def test_mlbs_has_the_maximum_length_balance():
    x = signals.mlbs(7, 2.0, hold=3)
    assert x.shape == (127 * 3,)
    assert np.sum(x > 0) == 64 * 3 and np.sum(x < 0) == 63 * 3


def test_rbs_holds_levels_for_one_over_band_samples():
    x = signals.rbs(1000, 1.0, band=0.25, seed=3)
    assert set(np.unique(x)) == {-1.0, 1.0}
    assert _runs(x)[:-1].min() >= 4


def test_linear_chirp_sweeps_its_frequency_band():
    Ts, T, f0, f1 = 0.01, 100.0, 0.1, 2.0
    x = signals.chirp(T, Ts, f0, f1, 1.0, method="linear")
    crossings = np.sum(np.diff(np.signbit(x)) != 0)
    expected_cycles = (f0 + f1) / 2 * T  # integral of the instantaneous frequency
    assert crossings / 2 == pytest.approx(expected_cycles, rel=0.02)
    assert np.max(np.abs(x)) <= 1.0


def test_chirp_above_nyquist_is_refused():
    with pytest.raises(ConfigError, match="Nyquist"):
        signals.chirp(100, 0.5, 0.0001, 2.0, 1.0)  # paper A's 2 Hz needs Ts < 0.25 s


def test_multisine_energy_stays_in_band_and_peak_is_amplitude():
    Ts, T = 0.1, 200.0
    x = signals.multisine(T, Ts, 0.2, 1.0, 3.0, seed=1)
    assert np.max(np.abs(x)) == pytest.approx(3.0)
    spectrum = np.abs(np.fft.rfft(x)) ** 2
    f = np.fft.rfftfreq(x.size, Ts)
    inband = (f >= 0.2 - 1e-9) & (f <= 1.0 + 1e-9)
    assert spectrum[inband].sum() / spectrum.sum() > 0.999


def test_rate_limit_bounds_the_slope_without_touching_input():
    x = np.array([0.0, 100.0, 100.0, -100.0, -100.0, -100.0])
    original = x.copy()
    y = signals.rate_limit(x, 50.0, 0.5)
    assert np.max(np.abs(np.diff(y))) <= 25.0 + 1e-12
    assert np.array_equal(x, original)


def test_steps_hold_each_level():
    x = signals.steps([0, 6000, -6000], hold=10, Ts=0.5)
    assert x.shape == (60,) and x[19] == 0 and x[20] == 6000 and x[-1] == -6000


@pytest.mark.parametrize(
    "call",
    [
        lambda: signals.prbs(-1, 0.5, 1, 5),
        lambda: signals.prbs(10, 0.5, 0, 5),
        lambda: signals.prbs(10, 0.5, 1, 5, max_hold=1),
        lambda: signals.prbs(10, 0.5, 1, 5, seed="x"),
        lambda: signals.mlbs(1, 1.0),
        lambda: signals.chirp(10, 0.1, 1, 2, 1, method="cubic"),
        lambda: signals.steps([], 1, 0.5),
        lambda: signals.multisine(10, 0.1, 3, 2, 1),
    ],
)
def test_bad_designs_raise_config_errors(call):
    with pytest.raises(ConfigError):
        call()
