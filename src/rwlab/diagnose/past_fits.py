"""Least squares on every past of a record at once: the fit over the samples up to j,
for every j, from cumulative sums (the own reference of
:func:`rwlab.diagnose.features.current_nuisance`)."""

from __future__ import annotations

import numpy as np

__all__ = ["fit_every_past", "least_norm_solve"]


def fit_every_past(
    X: np.ndarray,
    y: np.ndarray,
    ok: np.ndarray,
    need: int,
    unit: np.ndarray,
    known: np.ndarray | None = None,
) -> np.ndarray:
    """The least-squares, least-norm coefficients of y on X's three columns over the
    samples 0..j where ``ok``, for every j.

    Parameters
    ----------
    X : numpy.ndarray
        Regressors, shape (P, 3); the first column is scaled by ``unit`` (below).
    y : numpy.ndarray
        Values, shape (P,).
    ok : numpy.ndarray of bool
        The samples fitted, shape (P,).
    need : int
        Fewer fitted samples than this: no fit (NaN).
    unit : numpy.ndarray
        The first column's scale in the fit ending at j, shape (P,): a least-norm
        solution depends on the columns' scales where the past leaves a direction
        unexcited (A = D A₁ D, b = D b₁ with D = diag(unit[j], 1, 1)).
    known : numpy.ndarray, optional
        The fits of a shorter record of the same samples, shape (M, 3): reused.

    Returns
    -------
    numpy.ndarray
        shape (P, 3): coefficients of X's columns as given; NaN rows where not fitted.
    """
    P = len(y)
    done = 0 if known is None else min(len(known), P)
    theta = np.full((P, 3), np.nan)
    if known is not None:
        theta[:done] = known[:done]
    Xo = X * ok[:, None]
    A = np.cumsum(Xo[:, :, None] * X[:, None, :], axis=0)
    b = np.cumsum(Xo * y[:, None], axis=0)
    new = done + np.flatnonzero(np.cumsum(ok)[done:] >= need)
    if new.size:
        scale = np.ones((new.size, 3))
        scale[:, 0] = unit[new]
        fitted = least_norm_solve(A[new] * scale[:, :, None] * scale[:, None, :], b[new] * scale)
        theta[new] = fitted * scale  # coefficients of X's unscaled columns
    return theta


def least_norm_solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least squares, least norm, of stacked symmetric positive semi-definite 3 × 3
    systems, as lstsq's (singular values under 1e-6 of the largest are zero).

    Written here because numpy's lstsq does not stack. The well-conditioned systems
    (det > 1e-6 trace³, so the smallest eigenvalue is over 1e-6 of the largest) by their
    adjugate; the others by eigenvalues (A's are its singular values). The adjugate is
    6× faster than ``eigh`` and, on the 2-h records a flight diagnoses every 5 s, was half of
    an update.

    Parameters
    ----------
    A : numpy.ndarray
        shape (K, 3, 3).
    b : numpy.ndarray
        shape (K, 3).

    Returns
    -------
    numpy.ndarray
        shape (K, 3).
    """
    a00, a11, a22 = A[:, 0, 0], A[:, 1, 1], A[:, 2, 2]
    a01, a02, a12 = A[:, 0, 1], A[:, 0, 2], A[:, 1, 2]
    adj = np.empty_like(A)
    adj[:, 0, 0] = a11 * a22 - a12 * a12
    adj[:, 0, 1] = adj[:, 1, 0] = a02 * a12 - a01 * a22
    adj[:, 0, 2] = adj[:, 2, 0] = a01 * a12 - a11 * a02
    adj[:, 1, 1] = a00 * a22 - a02 * a02
    adj[:, 1, 2] = adj[:, 2, 1] = a01 * a02 - a00 * a12
    adj[:, 2, 2] = a00 * a11 - a01 * a01
    det = np.einsum("kj,kj->k", A[:, 0], adj[:, :, 0])
    regular = det > 1e-6 * (a00 + a11 + a22) ** 3
    out = np.einsum("kij,kj->ki", adj, b) / np.where(regular, det, 1.0)[:, None]
    if not regular.all():
        lam, V = np.linalg.eigh(A[~regular])
        keep = lam > 1e-6 * lam[:, -1:]
        inv = np.where(keep, 1.0 / np.where(keep, lam, 1.0), 0.0)
        Vb = np.einsum("kji,kj->ki", V, b[~regular])
        out[~regular] = np.einsum("kij,kj,kj->ki", V, inv, Vb)
    return out
