"""Recursive (online) ARX and ARMAX estimation, one sample at a time (MATLAB ``recursiveARX``).

``RecursiveARX`` and ``RecursiveARMAX`` keep the regressor history and the
parameter covariance between calls, so they run on a live telemetry stream:
call :meth:`RecursiveARX.update` with each new (y, u) sample. :func:`rarx`
runs one over a whole record and returns the parameter trajectory (MATLAB ``rarx``).

Two ways to follow parameters that change:

- ``method='forgetting'`` (MATLAB's ``ForgettingFactor``): recursive least
  squares discounting old data by λ per sample (λ = 1: no forgetting);
- ``method='kalman'`` (MATLAB's ``KalmanFilter``): the parameters are a random
  walk with covariance ``drift`` per sample, the measurement noise variance 1.

ARMAX uses the recursive pseudo-linear regression (RPLR, Ljung §11.3): the
C-part regressors are the a-posteriori residuals. Written here because no
maintained Python library offers recursive ARX/ARMAX with these options.
"""

from __future__ import annotations

import math

import numpy as np

from rwlab.data import IOData, check_Ts
from rwlab.errors import ConfigError, DataError
from rwlab.ident.models import PolyModel

__all__ = ["RecursiveARMAX", "RecursiveARX", "rarx"]


class RecursiveARX:
    """Online estimator of ``A(q) y(t) = B(q) u(t−nk) + e(t)`` (single input, single output).

    Parameters
    ----------
    na, nb, nk : int
        Orders and input delay in samples (MATLAB's ``[na nb nk]``).
    method : {'forgetting', 'kalman'}
        How the estimator follows changing parameters (see the module notes).
    forgetting : float
        λ in (0, 1] for ``'forgetting'`` (default 1, MATLAB's).
    drift : float or array_like, shape (d, d)
        Parameter random-walk covariance per sample for ``'kalman'``
        (default 0.1·I, MATLAB's ``ProcessNoiseCovariance``).
    initial_parameters : array_like, shape (d,), optional
        Start values (default zero).
    initial_covariance : float
        P(0) = this · I (default 1e4, MATLAB's ``InitialParameterCovariance``).
    """

    def __init__(
        self,
        na: int,
        nb: int,
        nk: int = 1,
        *,
        method: str = "forgetting",
        forgetting: float = 1.0,
        drift=0.1,
        initial_parameters=None,
        initial_covariance: float = 1e4,
    ) -> None:
        for name, value, low in (("na", na, 0), ("nb", nb, 0), ("nk", nk, 0)):
            if int(value) != value or value < low:
                raise ConfigError(f"{name} must be an integer ≥ {low}, got {value!r}")
        self.na, self.nb, self.nk = int(na), int(nb), int(nk)
        if method not in ("forgetting", "kalman"):
            raise ConfigError(f"method must be 'forgetting' or 'kalman', got {method!r}")
        if not 0 < forgetting <= 1:
            raise ConfigError(f"the forgetting factor must be in (0, 1], got {forgetting}")
        if not (initial_covariance > 0 and math.isfinite(initial_covariance)):
            raise ConfigError(f"initial_covariance must be > 0, got {initial_covariance}")
        d = self.n_params
        if d == 0:
            raise ConfigError("the model has no parameters to estimate")
        self.method, self.forgetting = method, float(forgetting)
        self.drift = np.asarray(drift, float) * (np.eye(d) if np.ndim(drift) == 0 else 1.0)
        if self.drift.shape != (d, d):
            raise ConfigError(f"drift must be a number or a {d}×{d} matrix")
        theta = np.zeros(d) if initial_parameters is None else initial_parameters
        self.theta = np.array(theta, dtype=float).reshape(d)
        self.P = float(initial_covariance) * np.eye(d)
        self._y = np.zeros(self.na)  # y(t−1) … y(t−na)
        self._u = np.zeros(self.nk + self.nb)  # u(t) … u(t−nk−nb+1)
        self._e = np.zeros(self._nc)  # residuals e(t−1) … e(t−nc)

    _nc = 0

    @property
    def n_params(self) -> int:
        return self.na + self.nb + self._nc

    def _regressor(self) -> np.ndarray:
        return np.concatenate([-self._y, self._u[self.nk : self.nk + self.nb], self._e])

    def update(self, y: float, u: float) -> float:
        """Take one sample; return the prediction ŷ(t) made before it (MATLAB's EstimatedOutput)."""
        y, u = float(y), float(u)
        if not (math.isfinite(y) and math.isfinite(u)):
            raise DataError(f"recursive estimation needs finite samples, got y={y}, u={u}")
        self._u = np.concatenate([[u], self._u[:-1]])
        phi = self._regressor()
        yhat = float(phi @ self.theta)
        Pphi = self.P @ phi
        lam = self.forgetting if self.method == "forgetting" else 1.0
        gain = Pphi / (lam + phi @ Pphi)
        self.theta = self.theta + gain * (y - yhat)
        self.P = self.P - np.outer(gain, Pphi)
        self.P = self.P / lam if self.method == "forgetting" else self.P + self.drift
        self.P = (self.P + self.P.T) / 2
        if self.na:
            self._y = np.concatenate([[y], self._y[:-1]])
        if self._nc:
            residual = y - float(phi @ self.theta)  # a-posteriori: RPLR
            self._e = np.concatenate([[residual], self._e[:-1]])
        return yhat

    @property
    def A(self) -> np.ndarray:
        return np.concatenate([[1.0], self.theta[: self.na]])

    @property
    def B(self) -> np.ndarray:
        return np.concatenate([np.zeros(self.nk), self.theta[self.na : self.na + self.nb]])

    def to_poly(self, Ts: float) -> PolyModel:
        """The current estimate as a ``PolyModel`` with sample time ``Ts`` (s)."""
        C = np.concatenate([[1.0], self.theta[self.na + self.nb :]])
        B = self.B if self.nb else None
        return PolyModel(self.A, B, C, Ts=check_Ts(Ts), nk=self.nk if self.nb else None)


class RecursiveARMAX(RecursiveARX):
    """Online estimator of ``A y = B u(t−nk) + C e`` by recursive pseudo-linear regression.

    Parameters as :class:`RecursiveARX`, with ``nc`` the order of C.

    Parameters
    ----------
    na, nb, nc : int
        Orders of A, B and C.
    nk : int
        Input delay, samples.
    **options
        ``method``, ``forgetting``, ``drift``, ``initial_parameters``,
        ``initial_covariance``: as for :class:`RecursiveARX`.
    """

    def __init__(self, na: int, nb: int, nc: int, nk: int = 1, **options) -> None:
        if int(nc) != nc or nc < 0:
            raise ConfigError(f"nc must be an integer ≥ 0, got {nc!r}")
        self._nc = int(nc)
        super().__init__(na, nb, nk, **options)


def rarx(data: IOData, na: int, nb: int, nk: int = 1, **options) -> tuple[np.ndarray, np.ndarray]:
    """Run :class:`RecursiveARX` over a record (MATLAB ``rarx``).

    Parameters
    ----------
    data : IOData
        Single-input single-output record.
    na, nb : int
        Orders of A and B.
    nk : int
        Input delay, samples.
    **options
        As for :class:`RecursiveARX`.

    Returns
    -------
    theta : numpy.ndarray, shape (N, na + nb)
        The estimate after each sample.
    yhat : numpy.ndarray, shape (N,)
        The prediction of each sample made before it.
    """
    if not isinstance(data, IOData) or data.ny != 1 or data.nu != 1:
        raise DataError("rarx needs an IOData with one input and one output")
    est = RecursiveARX(na, nb, nk, **options)
    theta = np.empty((data.N, est.n_params))
    yhat = np.empty(data.N)
    for t in range(data.N):
        yhat[t] = est.update(data.y[t, 0], data.u[t, 0])
        theta[t] = est.theta
    return theta, yhat
