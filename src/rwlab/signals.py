"""Test-signal design (MATLAB ``idinput`` and paper A's signals).

Every function returns a new float array of samples at the sample time ``Ts``
(seconds) and is reproducible from its ``seed`` (an int or a
``numpy.random.Generator``). Amplitudes are in the caller's unit (rpm for a
speed command, rpm/s for an acceleration command).

- :func:`prbs` — random levels *and* random pulse widths with a minimum hold
  (paper A: holds ≥ 5 s, levels within ±6000 rpm).
- :func:`mlbs` — maximum-length binary sequence (``idinput(..., 'prbs')``).
- :func:`rbs` — random binary signal with a band limit (``idinput(..., 'rbs')``).
- :func:`chirp` — linear or logarithmic swept sine (paper A: 0.0001–2 Hz).
- :func:`steps` — a staircase of levels.
- :func:`multisine` — Schroeder-phased sum of sines on the period's frequency grid.
- :func:`rate_limit` — limit the slope of any of the above. The testbed can
  apply it to a speed-mode PRBS (``ExperimentConfig.rate_limit``, ``rwlab
  experiment --rate-limit``: the wheel's acceleration limit, its spec's
  ``max_accel_rpm_s``), so the command ramps rather than steps. Off by default: paper A's PRBS
  steps, and the wheel follows each step at its acceleration limit.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal as sps

from rwlab.data import check_Ts
from rwlab.errors import ConfigError

__all__ = ["chirp", "mlbs", "multisine", "prbs", "rate_limit", "rbs", "steps"]


def _rng(seed) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise ConfigError(f"seed must be an int or numpy.random.Generator, got {seed!r}")
    return np.random.default_rng(int(seed))


def _count(duration: float, Ts: float) -> int:
    Ts = check_Ts(Ts)
    if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration > 0):
        raise ConfigError(f"duration must be a positive number of seconds, got {duration!r}")
    n = round(duration / Ts)
    if n < 1:
        raise ConfigError(f"duration {duration} s is shorter than one sample ({Ts} s)")
    return n


def _positive(name: str, value) -> float:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ConfigError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


def prbs(
    duration: float,
    Ts: float,
    amplitude: float,
    min_hold: float,
    max_hold: float | None = None,
    *,
    levels: str = "random",
    offset: float = 0.0,
    seed=0,
) -> np.ndarray:
    """Pseudo-random signal with random levels and random hold times (paper A, Fig. 14).

    Parameters
    ----------
    duration : float
        Length in seconds; N = round(duration / Ts) samples.
    Ts : float
        Sample time in seconds.
    amplitude : float
        Levels lie in [offset − amplitude, offset + amplitude].
    min_hold, max_hold : float
        Each level is held for a random whole number of samples between these
        (seconds; default ``max_hold = 4·min_hold``). The last hold may be cut
        short by the end of the record.
    levels : {'random', 'binary'}
        Uniform random levels, or ±amplitude only.
    offset : float
        Centre level.
    seed : int or numpy.random.Generator

    Returns
    -------
    numpy.ndarray, shape (N,)
    """
    n = _count(duration, Ts)
    amplitude = _positive("amplitude", amplitude)
    min_hold = _positive("min_hold", min_hold)
    max_hold = 4 * min_hold if max_hold is None else _positive("max_hold", max_hold)
    if max_hold < min_hold:
        raise ConfigError(f"max_hold ({max_hold} s) must be ≥ min_hold ({min_hold} s)")
    if levels not in ("random", "binary"):
        raise ConfigError(f"levels must be 'random' or 'binary', got {levels!r}")
    lo, hi = max(1, math.ceil(min_hold / Ts - 1e-9)), max(1, math.floor(max_hold / Ts + 1e-9))
    hi = max(hi, lo)
    rng = _rng(seed)
    out = np.empty(n)
    pos, sign = 0, 1.0
    while pos < n:
        hold = int(rng.integers(lo, hi + 1))
        if levels == "binary":
            sign = -sign if pos else float(rng.choice([-1.0, 1.0]))
            level = sign * amplitude
        else:
            level = rng.uniform(-amplitude, amplitude)
        out[pos : pos + hold] = offset + level
        pos += hold
    return out


def mlbs(n_bits: int, amplitude: float, *, hold: int = 1, periods: int = 1) -> np.ndarray:
    """Maximum-length binary sequence of ±amplitude (period 2^n_bits − 1 bits).

    Parameters
    ----------
    n_bits : int
        Shift-register length, 2..32.
    amplitude : float
        The two levels, ±amplitude.
    hold : int
        Samples per bit (the clock period of the sequence).
    periods : int
        Number of whole periods.

    Returns
    -------
    numpy.ndarray, shape ((2**n_bits − 1)·hold·periods,)
    """
    if not (isinstance(n_bits, int) and 2 <= n_bits <= 32):
        raise ConfigError(f"n_bits must be an integer in 2..32, got {n_bits!r}")
    if not (isinstance(hold, int) and hold >= 1 and isinstance(periods, int) and periods >= 1):
        raise ConfigError("hold and periods must be positive integers")
    amplitude = _positive("amplitude", amplitude)
    seq = sps.max_len_seq(n_bits)[0].astype(float) * 2 - 1
    return np.tile(np.repeat(seq, hold), periods) * amplitude


def rbs(n: int, amplitude: float, *, band: float = 1.0, seed=0) -> np.ndarray:
    """Random binary signal ±amplitude whose switching rate is limited to ``band``.

    ``band`` is the upper band edge as a fraction of the Nyquist frequency
    (MATLAB ``idinput(n, 'rbs', [0 band])``): each level is held ≈ 1/band samples.

    Parameters
    ----------
    n : int
        Number of samples.
    amplitude : float
        The two levels are ±amplitude.
    band : float
        Upper band edge as a fraction of the Nyquist frequency, in (0, 1].
    seed : int or numpy.random.Generator
        The random source.

    Returns
    -------
    numpy.ndarray, shape (n,)
        The samples.
    """
    if not (isinstance(n, int) and n >= 1):
        raise ConfigError(f"n must be a positive integer, got {n!r}")
    if not 0 < band <= 1:
        raise ConfigError(f"band must be in (0, 1], got {band}")
    amplitude = _positive("amplitude", amplitude)
    hold = max(1, round(1 / band))
    bits = _rng(seed).choice([-1.0, 1.0], size=math.ceil(n / hold))
    return np.repeat(bits, hold)[:n] * amplitude


def chirp(
    duration: float,
    Ts: float,
    f0: float,
    f1: float,
    amplitude: float,
    *,
    method: str = "logarithmic",
    offset: float = 0.0,
) -> np.ndarray:
    """Swept sine from ``f0`` to ``f1`` Hz over ``duration`` seconds (paper A, Fig. 15).

    ``method`` is 'linear' or 'logarithmic' (the paper's 0.0001–2 Hz sweep
    spans four decades, so logarithmic is the default). ``f1`` must be below
    the Nyquist frequency 1/(2 Ts).

    Parameters
    ----------
    duration : float
        Length of the signal, s.
    Ts : float
        Sample time, s.
    f0, f1 : float
        Start and end frequencies, Hz (0 < f0 < f1 < 1/(2 Ts)).
    amplitude : float
        Peak value, in the signal's unit.
    method : {'logarithmic', 'linear'}
        How the frequency sweeps.
    offset : float
        Added to every sample.

    Returns
    -------
    numpy.ndarray, shape (round(duration / Ts),)
        The samples.
    """
    n = _count(duration, Ts)
    f0, f1 = _positive("f0", f0), _positive("f1", f1)
    amplitude = _positive("amplitude", amplitude)
    if method not in ("linear", "logarithmic"):
        raise ConfigError(f"method must be 'linear' or 'logarithmic', got {method!r}")
    nyquist = 0.5 / Ts
    if max(f0, f1) >= nyquist:
        raise ConfigError(
            f"chirp frequency {max(f0, f1)} Hz is at or above the Nyquist frequency {nyquist} Hz "
            f"of Ts = {Ts} s; generate the command at a shorter Ts"
        )
    t = np.arange(n) * Ts
    t_end = max(t[-1], Ts)
    return offset + amplitude * sps.chirp(t, f0, t_end, f1, method=method, phi=-90)


def steps(levels, hold: float, Ts: float) -> np.ndarray:
    """A staircase: each of ``levels`` held for ``hold`` seconds in turn.

    Parameters
    ----------
    levels : sequence of float
        The successive levels.
    hold : float
        How long each is held, s.
    Ts : float
        Sample time, s.

    Returns
    -------
    numpy.ndarray, shape (len(levels) · round(hold / Ts),)
        The staircase.
    """
    values = np.asarray(levels, dtype=float)
    if values.ndim != 1 or values.size == 0 or not np.all(np.isfinite(values)):
        raise ConfigError("levels must be a non-empty list of finite numbers")
    return np.repeat(values, _count(hold, Ts))


def multisine(
    duration: float,
    Ts: float,
    f_min: float,
    f_max: float,
    amplitude: float,
    *,
    n_freqs: int | None = None,
    seed=0,
) -> np.ndarray:
    """Sum of sines with Schroeder phases (low crest factor), peak-normalised to ``amplitude``.

    Frequencies are whole multiples of 1/duration between ``f_min`` and
    ``f_max`` Hz (so the record holds whole periods); ``n_freqs`` picks that
    many of them, log-spaced (default all, at most 200).

    Parameters
    ----------
    duration : float
        Length of the signal (one period), s.
    Ts : float
        Sample time, s.
    f_min, f_max : float
        Frequency band, Hz.
    amplitude : float
        Peak value after normalisation.
    n_freqs : int, optional
        Number of frequencies (default all in the band, at most 200).
    seed : int or numpy.random.Generator
        Chooses the frequencies when fewer than all are taken.

    Returns
    -------
    numpy.ndarray, shape (round(duration / Ts),)
        The samples.
    """
    n = _count(duration, Ts)
    f_min, f_max = _positive("f_min", f_min), _positive("f_max", f_max)
    amplitude = _positive("amplitude", amplitude)
    if f_max >= 0.5 / Ts or f_min > f_max:
        raise ConfigError(f"need f_min ≤ f_max < Nyquist ({0.5 / Ts} Hz); got {f_min}..{f_max}")
    df = 1.0 / (n * Ts)
    grid = np.arange(max(1, math.ceil(f_min / df)), math.floor(f_max / df) + 1)
    if grid.size == 0:
        raise ConfigError(f"no frequency of the record's grid (step {df:.3g} Hz) lies in the band")
    count = min(n_freqs or 200, grid.size)
    idx = np.unique(np.round(np.geomspace(grid[0], grid[-1], count)).astype(int))
    k = np.arange(1, idx.size + 1)
    phases = -np.pi * k * (k - 1) / idx.size + _rng(seed).uniform(0, 2 * np.pi)
    t = np.arange(n) * Ts
    x = np.sin(2 * np.pi * np.outer(t, idx * df) + phases).sum(axis=1)
    return amplitude * x / np.max(np.abs(x))


def rate_limit(x, max_rate: float, Ts: float, initial: float | None = None) -> np.ndarray:
    """Follow ``x`` with a slope of at most ``max_rate`` per second (a new array).

    ``initial`` is the value before the first sample (default: ``x[0]``, no
    initial jump limited); pass 0 for a wheel starting at rest.

    Parameters
    ----------
    x : array_like, shape (N,)
        The signal to follow.
    max_rate : float
        Largest change per second, in x's unit per second (> 0).
    Ts : float
        Sample time, s.
    initial : float, optional
        The value before the first sample.

    Returns
    -------
    numpy.ndarray, shape (N,)
        The rate-limited signal (``x`` is not modified).
    """
    Ts = check_Ts(Ts)
    max_rate = _positive("max_rate", max_rate)
    src = np.asarray(x, dtype=float)
    out = np.empty_like(src)
    step = max_rate * Ts
    prev = (src[0] if src.size else 0.0) if initial is None else float(initial)
    for i, target in enumerate(src):
        prev += min(max(target - prev, -step), step)
        out[i] = prev
    return out
