"""A known static gain imposed on a single-input polynomial model (beyond MATLAB).

A speed loop with integral action has the static gain 1 from setpoint to speed,
and a record's settled holds measure it (``rwlab.ident.study.steady_state_gain``).
A linear fit to data from a wheel that sometimes saturates (rate or current limit)
biases that gain; the remedy of an identification engineer is to impose it:

    B(1) = K · A(1) · F(1)

(the polynomials' coefficient sums). With ``na = 0`` or ``nf = 0`` (ARX, ARMAX, OE,
BJ) this is one linear equality on the free parameters θ = [a…, b…, c…, d…, f…]:

    cᵀθ = K,   c = (−K on every a and f, 1 on every b, 0 on c and d).

It is imposed by the reparametrisation θ = θ₀ + N η, with N an orthonormal basis
of c's null space (d − 1 columns) and θ₀ a point on the constraint: ARX then is
equality-constrained least squares, solved exactly, and the prediction-error
search runs on η. The covariance of the constrained estimate is
``N cov(η) Nᵀ`` (rank d − 1: the constrained combination has no variance), with
λ = Σε²/(N − d + 1). MATLAB's polynomial estimators have no such option (its
``idgrey``/``Structure`` can only fix single parameters); this is hand-written.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import linalg

from rwlab.errors import DataError

__all__ = ["SUFFIX", "StaticGain", "constrained_least_squares", "study_name"]

SUFFIX = "+K"  # a model name's suffix when its static gain was imposed (``ARX221+K``)


def study_name(model) -> str:
    """``model.structure``, with :data:`SUFFIX` when its static gain was imposed (the
    estimators record it as ``report['dc_gain']``).

    Parameters
    ----------
    model : PolyModel
        An estimated model.

    Returns
    -------
    str
        E.g. ``"ARX221"`` or ``"ARX221+K"``.
    """
    return model.structure + (SUFFIX if model.report.get("dc_gain") is not None else "")


@dataclass(frozen=True)
class StaticGain:
    """The constraint ``B(1) = K·A(1)·F(1)`` on θ = [a…, b…, c…, d…, f…] of one input.

    Parameters
    ----------
    gain : float
        K, the static gain in the data's units (output unit per input unit).
    na, nb, nc, nd, nf : int
        The structure's orders (``na`` or ``nf`` must be 0, ``nb`` ≥ 1).
    """

    gain: float
    na: int
    nb: int
    nc: int = 0
    nd: int = 0
    nf: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.gain, bool) or not math.isfinite(float(self.gain)):
            raise DataError(f"dc_gain must be a finite number, got {self.gain!r}")
        if self.nb < 1:
            raise DataError("dc_gain needs at least one B coefficient (nb ≥ 1)")
        if self.na and self.nf:
            raise DataError(
                "dc_gain is a linear constraint only when A or F is 1 (ARX, ARMAX, OE, BJ); "
                f"this structure has na = {self.na} and nf = {self.nf}"
            )

    @classmethod
    def of(cls, dc_gain: float | None, orders) -> StaticGain | None:
        """The constraint on a prediction-error structure's parameters, or None.

        Parameters
        ----------
        dc_gain : float or None
            K, or None for no constraint.
        orders
            The structure (``na``, ``nb``, ``nc``, ``nd``, ``nf``; ``nb``/``nf`` per input).

        Returns
        -------
        StaticGain or None
        """
        if dc_gain is None:
            return None
        if len(orders.nb) != 1:
            raise DataError(f"dc_gain applies to one input; the data have {len(orders.nb)}")
        return cls(dc_gain, orders.na, orders.nb[0], orders.nc, orders.nd, orders.nf[0])

    @property
    def vector(self) -> np.ndarray:
        """c, shape (d,): the constraint is ``c @ theta == gain``."""
        K = float(self.gain)
        return np.concatenate(
            [
                np.full(self.na, -K),
                np.ones(self.nb),
                np.zeros(self.nc + self.nd),
                np.full(self.nf, -K),
            ]
        )

    @property
    def basis(self) -> np.ndarray:
        """N, shape (d, d − 1): orthonormal basis of the directions the constraint leaves free."""
        return linalg.null_space(self.vector[None, :])

    def project(self, theta: np.ndarray) -> np.ndarray:
        """``theta`` moved onto the constraint by an equal shift of every b (a new array)."""
        theta = np.array(theta, dtype=float)
        miss = float(self.gain) - float(self.vector @ theta)
        theta[self.na : self.na + self.nb] += miss / self.nb
        return theta

    def check(self, theta: np.ndarray) -> float:
        """``c @ theta − gain``: how far ``theta`` is off the constraint."""
        return float(self.vector @ theta) - float(self.gain)


def constrained_least_squares(
    R: np.ndarray, r: np.ndarray, sse0: float, rows: int, constraint: StaticGain
) -> tuple[np.ndarray, np.ndarray, float]:
    """min ‖Φθ − y‖² subject to ``constraint``, from the QR factors of [Φ | y].

    Parameters
    ----------
    R : numpy.ndarray, shape (d, d)
        Triangular factor of Φ.
    r : numpy.ndarray, shape (d,)
        Qᵀy (the first d entries).
    sse0 : float
        The unconstrained residual sum of squares (‖y‖² − ‖r‖²).
    rows : int
        Number of regression rows.
    constraint : StaticGain
        The equality.

    Returns
    -------
    theta : numpy.ndarray, shape (d,)
        The constrained estimate (exactly on the constraint).
    covariance : numpy.ndarray, shape (d, d)
        λ·N (NᵀΦᵀΦN)⁻¹ Nᵀ with λ = SSE/(rows − d + 1).
    sse : float
        Its residual sum of squares.
    """
    N = constraint.basis
    theta0 = constraint.project(np.zeros(R.shape[1]))
    M = R @ N
    eta, *_ = linalg.lstsq(M, r - R @ theta0)
    theta = theta0 + N @ eta
    extra = r - R @ theta
    sse = float(sse0 + extra @ extra)
    free = N.shape[1]
    lam = sse / max(rows - free, 1)
    R2 = linalg.qr(M, mode="r")[0][:free]
    R2inv = linalg.solve_triangular(R2, np.eye(free))
    cov = lam * N @ (R2inv @ R2inv.T) @ N.T
    return theta, (cov + cov.T) / 2, sse
