"""Small helpers for polynomials in the backward shift operator q⁻¹.

A polynomial ``p = [p0, p1, ..., pn]`` means ``p0 + p1 q⁻¹ + ... + pn q⁻ⁿ``
(MATLAB layout). Filtering a signal by ``b(q⁻¹)/a(q⁻¹)`` is
``scipy.signal.lfilter(b, a, x)`` with zero initial conditions.
"""

from __future__ import annotations

import numpy as np

__all__ = ["is_stable", "shift", "stabilize", "to_z"]


def to_z(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rewrite ``num(q⁻¹)/den(q⁻¹)`` as a ratio of polynomials in z (descending powers).

    Both are padded to a common length ``L`` and read as coefficients of
    ``z^(L-1) ... z^0``: multiplying top and bottom by ``z^(L-1)``.
    """
    length = max(len(num), len(den))
    pad = lambda p: np.concatenate([p, np.zeros(length - len(p))])  # noqa: E731
    return pad(np.asarray(num, float)), pad(np.asarray(den, float))


def roots_z(p: np.ndarray) -> np.ndarray:
    """Roots in z of the monic q⁻¹-polynomial ``p`` (the model's poles or zeros)."""
    p = np.trim_zeros(np.asarray(p, float), "b")
    return np.roots(p) if len(p) > 1 else np.zeros(0)


def is_stable(p: np.ndarray, margin: float = 0.0) -> bool:
    """True when every root in z of ``p`` lies strictly inside the circle of radius 1 − margin."""
    r = roots_z(p)
    return bool(np.all(np.abs(r) < 1.0 - margin)) if r.size else True


def stabilize(p: np.ndarray) -> np.ndarray:
    """Reflect roots outside the unit circle to 1/conj(root); keep degree and p0 = 1.

    Used after each prediction-error step to keep C, D and F stable, as
    MATLAB's estimators do. Returns a new array; a stable ``p`` comes back equal.
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


def shift(x: np.ndarray, k: int) -> np.ndarray:
    """``q⁻ᵏ x``: delay by ``k`` samples with zeros before the start."""
    if k == 0:
        return x
    out = np.zeros_like(x)
    if k < len(x):
        out[k:] = x[: len(x) - k]
    return out
