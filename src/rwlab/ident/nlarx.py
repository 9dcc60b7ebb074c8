"""Nonlinear ARX with a piecewise-linear output function (MATLAB ``nlarx``).

    y(t) = L·φ(t) + c + Σⱼ wⱼ⁺·max(0, d(t) − kⱼ) + wⱼ⁻·max(0, −d(t) − kⱼ)

with the regressors φ(t) = [y(t−1) … y(t−na), u(t−nk) … u(t−nk−nb+1)] and the
custom regressor d(t) = u(t−nk) − y(t−1), the tracking error of a servo (MATLAB
``customreg``). The output function is linear plus hinges at the knots kⱼ on
d (MATLAB's ``idPiecewiseLinear`` on one regressor): it can bend where the
error is large, which is where a rate or current limit takes over, without
knowing which. Knots sit at quantiles of |d| on the estimation data.

Estimated by linear least squares on the one-step prediction error (MATLAB's
default focus), the number of knots chosen by the simulation fit on the last
``holdout`` share of the estimation data (never on the caller's validation
data). A black box: it carries no physical parameter, so it cannot take another
unit's known limits (compare ``rwlab.ident.greybox``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from rwlab.data import IOData
from rwlab.errors import DataError, ModelError
from rwlab.ident.validation import fit_percent

__all__ = ["NLARXModel", "nlarx"]

STRUCTURE = "nlarx"


@njit(cache=True)
def _simulate(u, y_init, na, nb, nk, theta, knots):  # pragma: no cover - compiled
    n = u.size
    y = np.empty(n)
    start = max(na, nb + nk - 1, nk)
    for t in range(n):
        if t < start:
            y[t] = y_init[t] if t < y_init.size else y_init[-1]
            continue
        s = theta[0]
        pos = 1
        for i in range(1, na + 1):
            s += theta[pos] * y[t - i]
            pos += 1
        for i in range(nb):
            s += theta[pos] * u[t - nk - i]
            pos += 1
        d = u[t - nk] - y[t - 1]
        for j in range(knots.size):
            s += theta[pos] * max(0.0, d - knots[j]) + theta[pos + 1] * max(0.0, -d - knots[j])
            pos += 2
        y[t] = s
    return y


@dataclass(frozen=True)
class NLARXModel:
    """A nonlinear ARX model (equations in the module docstring).

    Attributes
    ----------
    Ts : float
        Sample time, s.
    na, nb, nk : int
        Output lags, input lags and input delay (samples).
    theta : tuple of float
        [c, a₁…a_na, b₀…b_{nb−1}, w₁⁺, w₁⁻, …] (output units per regressor unit).
    knots : tuple of float
        Hinge positions on d, input units.
    report : dict
        How the knots were chosen.
    """

    Ts: float
    na: int
    nb: int
    nk: int
    theta: tuple
    knots: tuple
    report: dict = field(default_factory=dict, compare=False)

    nu = 1
    ny = 1
    structure = STRUCTURE

    def __post_init__(self) -> None:
        if len(self.theta) != 1 + self.na + self.nb + 2 * len(self.knots):
            raise ModelError("theta's length does not match na, nb and the knots")
        if not np.all(np.isfinite(self.theta)) or not np.all(np.isfinite(self.knots)):
            raise ModelError("NLARX parameters must be finite")

    @property
    def n_params(self) -> int:
        """Number of estimated coefficients."""
        return len(self.theta)

    def simulate(self, u, y_init) -> np.ndarray:
        """Free-run output for inputs ``u`` (N,), the first samples taken from ``y_init``.

        Parameters
        ----------
        u : array_like, shape (N,)
        y_init : array_like
            Outputs before the regressors are full (at least one value).

        Returns
        -------
        numpy.ndarray, shape (N,)
        """
        u2 = np.array(u, dtype=float).ravel()
        y0 = np.array(y_init, dtype=float, ndmin=1).ravel()
        if u2.size == 0 or y0.size == 0 or not np.all(np.isfinite(u2)):
            raise DataError("u must be non-empty and finite, y_init non-empty")
        return _simulate(
            u2, y0, self.na, self.nb, self.nk, np.asarray(self.theta), np.asarray(self.knots)
        )

    def predict(self, data: IOData, horizon: float = np.inf, initial: str = "steady"):
        """k-step prediction on ``data``, shape (N,): 1 uses the measured outputs as
        regressors; ``inf`` (or any k > 1, approximated by simulation) runs free from
        the first measured outputs. ``initial`` is accepted for the common interface."""
        if not isinstance(data, IOData) or data.nu != 1 or data.ny != 1:
            raise DataError("the NLARX model needs a single-input single-output IOData")
        if horizon != np.inf and (int(horizon) != horizon or horizon < 1):
            raise DataError(f"horizon must be a positive integer or inf, got {horizon}")
        u, y = data.u[:, 0], data.y[:, 0]
        if horizon == 1:
            Phi, start = _regressors(u, y, self.na, self.nb, self.nk, np.asarray(self.knots))
            out = y.copy()
            out[start:] = Phi @ np.asarray(self.theta)
            return out
        first = max(self.na, self.nb + self.nk - 1, self.nk)
        return self.simulate(u, y[: max(first, 1)])

    def to_dict(self) -> dict:
        """Plain JSON."""
        return {
            "structure": STRUCTURE,
            "Ts": self.Ts,
            "na": self.na,
            "nb": self.nb,
            "nk": self.nk,
            "theta": list(self.theta),
            "knots": list(self.knots),
            "report": self.report,
        }

    @classmethod
    def from_dict(cls, d: dict) -> NLARXModel:
        """Inverse of :meth:`to_dict`."""
        try:
            return cls(
                float(d["Ts"]),
                int(d["na"]),
                int(d["nb"]),
                int(d["nk"]),
                tuple(float(v) for v in d["theta"]),
                tuple(float(v) for v in d["knots"]),
                dict(d.get("report", {})),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelError(f"bad NLARX model: {exc}") from None


def _regressors(u, y, na, nb, nk, knots) -> tuple[np.ndarray, int]:
    start = max(na, nb + nk - 1, nk, 1)
    N = y.size
    cols = [np.ones(N - start)]
    cols += [y[start - i : N - i] for i in range(1, na + 1)]
    cols += [u[start - nk - i : N - nk - i] for i in range(nb)]
    d = u[start - nk : N - nk] - y[start - 1 : N - 1]
    for k in knots:
        cols += [np.maximum(0.0, d - k), np.maximum(0.0, -d - k)]
    return np.column_stack(cols), start


def _fit(u, y, na, nb, nk, knots) -> np.ndarray:
    Phi, start = _regressors(u, y, na, nb, nk, knots)
    scale = np.linalg.norm(Phi, axis=0)
    scale[scale == 0] = 1.0
    theta, *_ = np.linalg.lstsq(Phi / scale, y[start:], rcond=None)
    return theta / scale


def nlarx(
    data: IOData,
    na: int = 2,
    nb: int = 2,
    nk: int = 1,
    *,
    knot_counts=(0, 1, 2, 4, 8),
    holdout: float = 0.3,
) -> NLARXModel:
    """Estimate a nonlinear ARX model with hinges on the tracking error (module docstring).

    Parameters
    ----------
    data : IOData
        SISO estimation data (any units; physical ones keep the knots meaningful).
    na, nb, nk : int
        Output lags (≥ 1), input lags (≥ 1) and delay (≥ 1), samples.
    knot_counts : sequence of int
        Candidate numbers of knots; the one whose model simulates best on the
        last ``holdout`` share of ``data`` (fitted on the rest) is refitted on all of it.
    holdout : float
        Share of ``data`` (its end) kept out of the fit to choose the number of knots.

    Returns
    -------
    NLARXModel
        ``report['selection']`` maps each knot count to its hold-out simulation fit %.
    """
    if not isinstance(data, IOData) or data.nu != 1 or data.ny != 1:
        raise DataError("nlarx needs a single-input single-output IOData")
    if min(na, nb, nk) < 1:
        raise DataError(f"nlarx needs na, nb, nk ≥ 1, got {na}, {nb}, {nk}")
    if not 0 < holdout < 1:
        raise DataError(f"holdout must be in (0, 1), got {holdout}")
    u, y = data.u[:, 0].copy(), data.y[:, 0].copy()
    cut = round((1 - holdout) * data.N)
    if cut < 10 * (na + nb + 2 * max(knot_counts) + 1) or data.N - cut < 20:
        raise DataError(f"{data.N} samples are too few for nlarx with these knots")
    first = max(na, nb + nk - 1, nk, 1)
    scores: dict[int, float] = {}
    for count in knot_counts:
        knots = _knots(u[:cut], y[:cut], nk, count)
        theta = _fit(u[:cut], y[:cut], na, nb, nk, knots)
        sim = _simulate(u[cut:], y[cut : cut + first], na, nb, nk, theta, knots)
        ok = np.all(np.isfinite(sim)) and np.ptp(y[cut:]) > 0
        scores[int(count)] = fit_percent(y[cut:], sim) if ok else -np.inf
    best = max(scores, key=lambda k: scores[k])
    knots = _knots(u, y, nk, best)
    theta = _fit(u, y, na, nb, nk, knots)
    return NLARXModel(
        data.Ts,
        na,
        nb,
        nk,
        tuple(float(v) for v in theta),
        tuple(float(k) for k in knots),
        {"selection": {str(k): v for k, v in scores.items()}, "knot_count": best},
    )


def _knots(u, y, nk, count) -> np.ndarray:
    if count == 0:
        return np.zeros(0)
    d = np.abs(u[: u.size - nk] - y[nk - 1 : y.size - 1]) if nk >= 1 else np.abs(u - y)
    return np.quantile(d, np.linspace(0.5, 0.95, count))
