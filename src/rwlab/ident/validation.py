"""Model quality: fit %, MSE, FPE, AIC, ``compare`` and ``resid`` (MATLAB semantics).

Definitions (N samples, d free parameters, V the loss = mean squared one-step
prediction error on the estimation data):

- fit % = 100·(1 − ‖y − ŷ‖ / ‖y − mean(y)‖)            (NRMSE, MATLAB ``compare``)
- FPE   = V·(1 + d/N)/(1 − d/N)                          (Akaike, MATLAB ``fpe``)
- AIC   = N·log V + 2d + N·(log 2π + 1)                  (raw, MATLAB ``aic(m,'aic')``)
- nAIC  = log V + 2d/N                                    (MATLAB ``aic(m)`` and ``selstruc``)
- BIC   = N·log V + d·log N + N·(log 2π + 1)

Initial conditions: ``compare`` estimates the initial state by least squares
by default, as MATLAB's ``compare`` does; ``resid`` and the estimation report
use zero initial conditions unless told otherwise (``initial='steady'`` for a
record that starts at rest, ``'estimate'`` for MATLAB's 'e').
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy import linalg, stats

from rwlab.data import IOData
from rwlab.errors import DataError

__all__ = [
    "CompareResult",
    "ResidResult",
    "compare",
    "estimation_report",
    "fit_percent",
    "fpe",
    "mse",
    "resid",
]


def fit_percent(y, yhat) -> float:
    """NRMSE fit in percent: 100·(1 − ‖y − ŷ‖ / ‖y − mean(y)‖).

    Parameters
    ----------
    y, yhat : array_like, shape (N,) or (N, ny)
        Measured and model outputs.

    Returns
    -------
    float
        The fit, % (100 is perfect; negative is worse than the mean).
    """
    y = np.asarray(y, float).ravel()
    yhat = np.asarray(yhat, float).ravel()
    if y.shape != yhat.shape:
        raise DataError(f"y and yhat differ in length ({y.size} vs {yhat.size})")
    den = np.linalg.norm(y - y.mean())
    if den == 0:
        raise DataError("fit % is undefined for a constant output")
    return float(100.0 * (1.0 - np.linalg.norm(y - yhat) / den))


def mse(y, yhat) -> float:
    """Mean squared error (1/N) Σ (y − ŷ)² (paper A, eq. 4).

    Parameters
    ----------
    y, yhat : array_like, shape (N,) or (N, ny)
        Measured and model outputs.

    Returns
    -------
    float
        The mean squared error, in the output's unit squared.
    """
    e = np.asarray(y, float).ravel() - np.asarray(yhat, float).ravel()
    return float(e @ e / e.size)


def fpe(loss: float, n_params: int, n_samples: int) -> float:
    """Akaike's final prediction error V·(1 + d/N)/(1 − d/N).

    Parameters
    ----------
    loss : float
        Loss V (mean squared prediction error).
    n_params : int
        Number of estimated parameters d.
    n_samples : int
        Number of samples N.

    Returns
    -------
    float
        The final prediction error.
    """
    if n_params >= n_samples:
        return math.inf
    return loss * (1 + n_params / n_samples) / (1 - n_params / n_samples)


def estimation_report(
    model, experiments: list[IOData], *, method: str, loss: float, **extra
) -> dict:
    """The numbers MATLAB puts in ``Report.Fit``: one-step prediction fit on the estimation data.

    Parameters
    ----------
    model : PolyModel or SSModel
        The estimated model.
    experiments : list of IOData
        The estimation records.
    method : str
        The estimator's name.
    loss : float
        Its final loss.
    **extra
        More entries for the report.

    Returns
    -------
    dict
        ``method``, ``loss``, ``mse``, ``fit_percent``, sample and parameter
        counts, and the extras.
    """
    y = np.concatenate([d.y[:, 0] for d in experiments])
    initial = extra.get("initial_conditions", "zero")
    yhat = np.concatenate([model.predict(d, 1, initial=initial) for d in experiments])
    N = y.size
    d = model.n_params
    V = max(float(loss), np.finfo(float).tiny)
    const = N * (math.log(2 * math.pi) + 1)
    report = {
        "method": method,
        "focus": "prediction",
        "initial_conditions": initial,
        "n_samples": N,
        "n_params": d,
        "loss": float(loss),
        "mse": mse(y, yhat),
        "fit_percent": fit_percent(y, yhat) if np.ptp(y) > 0 else float("nan"),
        "fpe": fpe(V, d, N),
        "aic": N * math.log(V) + 2 * d + const,
        "naic": math.log(V) + 2 * d / N,
        "bic": N * math.log(V) + d * math.log(N) + const,
    }
    report.update(extra)
    return report


@dataclass(frozen=True)
class CompareResult:
    """Model output against measured output (MATLAB ``compare``).

    Attributes
    ----------
    y : numpy.ndarray, shape (N,)
        Measured output.
    yhat : numpy.ndarray, shape (N,)
        Simulated (``horizon=inf``) or k-step-predicted model output.
    fit_percent : float
        NRMSE fit in percent.
    mse : float
        Mean squared error.
    horizon : float
        Prediction horizon in samples (inf = simulation).
    """

    y: np.ndarray
    yhat: np.ndarray
    fit_percent: float
    mse: float
    horizon: float


def compare(
    model, data: IOData, horizon: float | None = None, initial: str = "estimate"
) -> CompareResult:
    """Simulate (default) or predict ``horizon`` steps ahead and score against ``data``.

    ``horizon``: samples ahead, ``numpy.inf`` for simulation. The default is
    simulation for a model with inputs and 1-step prediction for a time
    series (a model without input simulates to zero, so only prediction says
    anything about it). ``initial``: 'estimate' (default, as MATLAB's
    ``compare``): the initial state that best fits ``data``'s output; 'zero'
    or 'steady' pre-sample values (see ``PolyModel.simulate``).

    Parameters
    ----------
    model : PolyModel or SSModel
        The model.
    data : IOData
        The record to score on (usually the validation part).
    horizon : float, optional
        Samples ahead, or ``numpy.inf`` for simulation.
    initial : {'estimate', 'zero', 'steady'}
        Initial conditions.

    Returns
    -------
    CompareResult
        Measured and model outputs, fit % and MSE.
    """
    if horizon is None:
        horizon = np.inf if model.nu else 1
    yhat = model.predict(data, horizon, initial=initial)
    y = data.y[:, 0]
    return CompareResult(y.copy(), yhat, fit_percent(y, yhat), mse(y, yhat), float(horizon))


@dataclass(frozen=True)
class ResidResult:
    """Residual analysis (MATLAB ``resid``).

    Attributes
    ----------
    residuals : numpy.ndarray, shape (N,)
        One-step prediction errors e(t).
    lags : numpy.ndarray, shape (M+1,)
        0..M for the autocorrelation.
    acf : numpy.ndarray, shape (M+1,)
        Normalised autocorrelation of e (acf[0] = 1).
    acf_bound : float
        Confidence bound z/√N for acf at lags ≥ 1.
    ccf_lags : numpy.ndarray, shape (2M+1,)
        −M..M; r_ue(τ) correlates u(t) with e(t+τ) (negative τ: e leads u, feedback).
    ccf : numpy.ndarray, shape (2M+1,)
        Normalised input–residual cross-correlation.
    ccf_bound : float
        Confidence bound z·sqrt(Σₖ r_e(k) r_u(k))/√N.
    confidence : float
        Confidence level of the bounds (0.99 = MATLAB's default).
    whiteness_p : float
        Ljung–Box portmanteau p-value for lags 1..M.
    independence_p : float
        NaN for a time series (no input: nothing to test; ``ccf`` is then empty).
        Otherwise the p-value of the joint test that e is uncorrelated with u at every lag
        −M..M: the input is prewhitened by a least-squares AR(M) model, and
        ζ = N rᵀ R⁻¹ r (r the 2M+1 cross-correlations of e with the whitened
        input, R the Toeplitz matrix of e's autocorrelation) is referred to χ²(2M+1).
        With a coloured input the raw cross-correlations at neighbouring lags are
        strongly dependent, so summing their squares would reject a true model
        far more often than 1 − confidence (Ljung, System Identification, §16.6).
    """

    residuals: np.ndarray
    lags: np.ndarray
    acf: np.ndarray
    acf_bound: float
    ccf_lags: np.ndarray
    ccf: np.ndarray
    ccf_bound: float
    confidence: float
    whiteness_p: float
    independence_p: float

    @property
    def white(self) -> bool:
        """True when the Ljung–Box test does not reject whiteness at 1 − confidence."""
        return self.whiteness_p >= 1 - self.confidence

    @property
    def independent(self) -> bool:
        """True when the residuals show no significant correlation with the input
        (always True for a time series, which has no input)."""
        if math.isnan(self.independence_p):
            return True
        return self.independence_p >= 1 - self.confidence

    def to_dict(self) -> dict:
        d = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in asdict(self).items()}
        d.pop("residuals")
        d.update(white=self.white, independent=self.independent)
        return d


def _xcorr(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """r(τ) = Σₜ a(t+τ) b(t) / N for τ = −max_lag..max_lag (biased estimate, FFT)."""
    n = a.size
    size = 1 << math.ceil(math.log2(2 * n))
    full = np.fft.irfft(np.fft.rfft(a, size) * np.conj(np.fft.rfft(b, size)), size)
    return np.concatenate([full[-max_lag:], full[: max_lag + 1]]) / n if max_lag else full[:1] / n


def _prewhitened(u: np.ndarray, order: int) -> np.ndarray:
    """Innovations of a least-squares AR(``order``) model of ``u``: samples order..N−1."""
    lags = np.column_stack([u[order - i : u.size - i] for i in range(1, order + 1)])
    a, *_ = np.linalg.lstsq(lags, u[order:], rcond=None)
    return u[order:] - lags @ a


def _independence_p(e: np.ndarray, u: np.ndarray, max_lag: int) -> float:
    """p-value of ζ = N rᵀ R⁻¹ r ~ χ²(2M+1) on the prewhitened input (see ResidResult)."""
    uw = _prewhitened(u, max_lag)
    ew = e[max_lag:] - e[max_lag:].mean()
    n = ew.size
    ree = _xcorr(ew, ew, 2 * max_lag)[2 * max_lag :]
    r = _xcorr(ew, uw, max_lag) / math.sqrt(ree[0] * float(uw @ uw) / n)
    R = linalg.toeplitz(ree[: 2 * max_lag + 1] / ree[0])
    zeta = n * float(r @ linalg.lstsq(R, r)[0])
    return float(stats.chi2.sf(zeta, 2 * max_lag + 1))


def resid(
    model, data: IOData, max_lag: int = 25, confidence: float = 0.99, initial: str = "zero"
) -> ResidResult:
    """Residual whiteness and input independence tests with confidence bounds.

    For a time series (no input) only whiteness is tested, as MATLAB's ``resid``.

    Parameters
    ----------
    model : PolyModel
        The model to test.
    data : IOData
        Usually the validation record.
    max_lag : int
        Largest lag M in samples (MATLAB default 25).
    confidence : float
        Level of the bounds and tests (MATLAB default 0.99).
    initial : {'zero', 'steady', 'estimate'}
        Initial conditions of the one-step predictor (see ``PolyModel.predict``).

    Returns
    -------
    ResidResult
        Auto- and cross-correlations, their bounds and the test outcomes.
    """
    if not 0 < confidence < 1:
        raise DataError(f"confidence must be in (0, 1), got {confidence}")
    if max_lag < 1 or max_lag >= data.N // 2:
        raise DataError(f"max_lag must be in 1..{data.N // 2 - 1}, got {max_lag}")
    e = data.y[:, 0] - model.predict(data, 1, initial=initial)
    N = e.size
    z = stats.norm.ppf(0.5 + confidence / 2)
    ree = _xcorr(e, e, max_lag)
    r0 = ree[max_lag]
    if r0 <= 0:
        raise DataError("the residuals are identically zero; nothing to test")
    acf = ree[max_lag:] / r0
    k = np.arange(1, max_lag + 1)
    q_lb = N * (N + 2) * np.sum(acf[1:] ** 2 / (N - k))
    common = dict(
        residuals=e,
        lags=np.arange(max_lag + 1),
        acf=acf,
        acf_bound=float(z / math.sqrt(N)),
        confidence=confidence,
        whiteness_p=float(stats.chi2.sf(q_lb, max_lag)),
    )
    if data.nu == 0:
        nothing = np.zeros(0)
        return ResidResult(
            **common, ccf_lags=nothing, ccf=nothing, ccf_bound=math.nan, independence_p=math.nan
        )
    u = data.u[:, 0] - data.u[:, 0].mean()
    ruu = _xcorr(u, u, max_lag)
    su = ruu[max_lag]
    ccf = _xcorr(e, u, max_lag) / math.sqrt(r0 * su) if su > 0 else np.zeros(2 * max_lag + 1)
    rho_u = ruu / su if su > 0 else np.zeros_like(ruu)
    rho_e = ree / r0
    var_ccf = max(float(np.sum(rho_e * rho_u)), 1e-12) / N
    independence_p = _independence_p(e, u, max_lag) if su > 0 else 1.0
    return ResidResult(
        **common,
        ccf_lags=np.arange(-max_lag, max_lag + 1),
        ccf=ccf,
        ccf_bound=float(z * math.sqrt(var_ccf)),
        independence_p=independence_p,
    )
