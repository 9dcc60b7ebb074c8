"""Small helpers for polynomials in the backward shift operator q⁻¹.

A polynomial ``p = [p0, p1, ..., pn]`` means ``p0 + p1 q⁻¹ + ... + pn q⁻ⁿ``
(MATLAB layout). Filtering a signal by ``b(q⁻¹)/a(q⁻¹)`` is
``scipy.signal.lfilter(b, a, x)`` with zero initial conditions.
"""

from __future__ import annotations

import numpy as np
from scipy import signal as sps

__all__ = ["filt", "fit_initial", "free_responses", "is_stable", "shift", "stabilize", "to_z"]


def to_z(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rewrite ``num(q⁻¹)/den(q⁻¹)`` as a ratio of polynomials in z (descending powers).

    Both are padded to a common length ``L`` and read as coefficients of
    ``z^(L-1) ... z^0``: multiplying top and bottom by ``z^(L-1)``.

    Parameters
    ----------
    num, den : numpy.ndarray
        Numerator and denominator in q⁻¹.

    Returns
    -------
    num_z, den_z : numpy.ndarray
        The same ratio in descending powers of z, equal lengths.
    """
    length = max(len(num), len(den))
    pad = lambda p: np.concatenate([p, np.zeros(length - len(p))])  # noqa: E731
    return pad(np.asarray(num, float)), pad(np.asarray(den, float))


def roots_z(p: np.ndarray) -> np.ndarray:
    """Roots in z of the monic q⁻¹-polynomial ``p`` (the model's poles or zeros)."""
    p = np.trim_zeros(np.asarray(p, float), "b")
    return np.roots(p) if len(p) > 1 else np.zeros(0)


def is_stable(p: np.ndarray, margin: float = 0.0) -> bool:
    """True when every root in z of ``p`` lies strictly inside the circle of radius 1 − margin.

    Parameters
    ----------
    p : numpy.ndarray
        Polynomial in q⁻¹ (``p[0] = 1``).
    margin : float
        Required distance inside the unit circle.

    Returns
    -------
    bool
    """
    r = roots_z(p)
    return bool(np.all(np.abs(r) < 1.0 - margin)) if r.size else True


def stabilize(p: np.ndarray) -> np.ndarray:
    """Reflect roots outside the unit circle to 1/conj(root); keep degree and p0 = 1.

    Used after each prediction-error step to keep C, D and F stable, as
    MATLAB's estimators do. Returns a new array; a stable ``p`` comes back equal.

    Parameters
    ----------
    p : numpy.ndarray
        Monic polynomial in q⁻¹.

    Returns
    -------
    numpy.ndarray
        The stabilised polynomial, same length.
    """
    p = np.asarray(p, float)
    r = roots_z(p)
    outside = np.abs(r) > 1.0
    if not outside.any():
        return p.copy()
    r = np.where(outside, 1.0 / np.conj(r), r)
    q = np.real(np.poly(r))
    out = np.zeros_like(p)
    out[: len(q)] = q
    return out


INITIAL = ("zero", "steady", "estimate")


def check_initial(initial: str, allowed: tuple[str, ...] = INITIAL) -> str:
    """Validate an initial-condition convention name against ``allowed``."""
    if initial not in allowed:
        from rwlab.errors import DataError

        raise DataError(f"initial must be one of {', '.join(allowed)}; got {initial!r}")
    return initial


def free_responses(den: np.ndarray, n: int, N: int) -> np.ndarray:
    """Basis of every response of an ``n``-state filter with denominator ``den`` to its initial
    state alone, shape (N, n).

    Column i is ``(1/den) δ(t − i)``: these n sequences are independent and span the
    solutions of ``den(q) s(t) = 0`` for t ≥ n, i.e. all free responses of any
    realisation of order n (n ≥ len(den) − 1) with this denominator.

    Parameters
    ----------
    den : numpy.ndarray
        Denominator in q⁻¹.
    n : int
        Number of states (≥ len(den) − 1).
    N : int
        Number of samples.

    Returns
    -------
    numpy.ndarray, shape (N, n)
        One free response per column.
    """
    impulses = np.zeros((N, n))
    idx = np.arange(min(n, N))
    impulses[idx, idx] = 1.0
    return sps.lfilter([1.0], den, impulses, axis=0)


def fit_initial(y: np.ndarray, yhat: np.ndarray, den: np.ndarray, n: int) -> np.ndarray:
    """``yhat`` plus the free response of ``den`` (n states) that best fits ``y`` (least squares).

    This is MATLAB's ``InitialCondition = 'e'``: the initial state is chosen to
    minimise ‖y − ŷ‖, given the zero-initial-state response ``yhat``.

    Parameters
    ----------
    y : numpy.ndarray, shape (N,)
        Measured output.
    yhat : numpy.ndarray, shape (N,)
        Response from a zero initial state.
    den : numpy.ndarray
        Denominator of the free response, in q⁻¹.
    n : int
        Number of initial states.

    Returns
    -------
    numpy.ndarray, shape (N,)
        ``yhat`` plus the fitted free response.
    """
    basis = free_responses(den, n, len(y))
    x0, *_ = np.linalg.lstsq(basis, y - yhat, rcond=None)
    return yhat + basis @ x0


def shift(x: np.ndarray, k: int, steady: bool = False) -> np.ndarray:
    """``q⁻ᵏ x``: delay by ``k`` samples; zeros (or ``x[0]`` if ``steady``) before the start.

    Parameters
    ----------
    x : numpy.ndarray, shape (N,)
        The signal.
    k : int
        Delay, samples (≥ 0).
    steady : bool
        Fill with ``x[0]`` instead of zeros.

    Returns
    -------
    numpy.ndarray, shape (N,)
        The delayed signal.
    """
    if k == 0:
        return x
    out = np.full_like(x, x[0] if steady and len(x) else 0.0)
    if k < len(x):
        out[k:] = x[: len(x) - k]
    return out


def filt(b, a, x: np.ndarray, steady: bool = False) -> np.ndarray:
    """``(b/a) x`` by ``scipy.signal.lfilter``.

    ``steady=False``: zero initial conditions (the signals were 0 before t = 0).
    ``steady=True``: the input held ``x[0]`` forever before t = 0, so the filter
    starts in that equilibrium (``lfilter_zi``) — a record that starts at rest.

    Parameters
    ----------
    b, a : array_like
        Numerator and denominator in q⁻¹ (``a[0] ≠ 0``).
    x : numpy.ndarray, shape (N,)
        The signal.
    steady : bool
        Start in the equilibrium of ``x[0]`` instead of at rest.

    Returns
    -------
    numpy.ndarray, shape (N,)
        The filtered signal.
    """
    b = np.atleast_1d(np.asarray(b, float))
    a = np.atleast_1d(np.asarray(a, float))
    if len(a) == 1 and len(b) == 1:
        return x * (b[0] / a[0])
    if not steady or not len(x):
        return sps.lfilter(b, a, x)
    n = max(len(a), len(b))
    b = np.concatenate([b, np.zeros(n - len(b))])
    a = np.concatenate([a, np.zeros(n - len(a))])
    return sps.lfilter(b, a, x, zi=_held_state(b, a) * x[0])[0]


def _held_state(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``scipy.signal.lfilter_zi(b, a)`` (equal lengths): lfilter's state after the input
    was held at 1 forever. Hand-written in closed form, as the PEM fits call it thousands
    of times and scipy's solves a linear system each time (28 µs against 6 µs, measured):
    with ``a[0] = 1``, the output settles at y = Σb/Σa and state i at Σ_{k>i}(b_k − a_k·y).
    A pole at 1 (Σa = 0) has no such state: scipy's says so."""
    b, a = b / a[0], a / a[0]
    total = a.sum()
    if total == 0.0:
        return sps.lfilter_zi(b, a)
    return np.cumsum((b - a * (b.sum() / total))[:0:-1])[::-1]
