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
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy import linalg, stats
from scipy import signal as sps

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
    d = int(extra.get("n_free", model.n_params))  # a constrained estimate has fewer
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
    y : numpy.ndarray, shape (N,), or (N, ny) for several outputs
        Measured output.
    yhat : numpy.ndarray, shape of ``y``
        Simulated (``horizon=inf``) or k-step-predicted model output.
    fit_percent : float, or numpy.ndarray of shape (ny,) for several outputs
        NRMSE fit in percent, per output (as MATLAB's ``compare`` returns it).
    mse : float, or numpy.ndarray of shape (ny,)
        Mean squared error per output.
    horizon : float
        Prediction horizon in samples (inf = simulation).
    """

    y: np.ndarray
    yhat: np.ndarray
    fit_percent: float | np.ndarray
    mse: float | np.ndarray
    horizon: float


def _from_control(model, data: IOData):
    """A python-control model as the rwlab state-space model that compare simulates.

    A discrete model must be sampled at the data's Ts (``dt=True``, "discrete,
    unspecified", takes it); a continuous one is discretised by zero-order hold at
    the data's Ts, as MATLAB's ``compare`` does for data sampled with a ZOH, with a
    warning saying so. A model without noise model: its prediction is its simulation.
    """
    import warnings

    import control

    from rwlab.errors import ModelError, RwlabWarning
    from rwlab.ident.ssmodel import SSModel

    if not isinstance(model, control.LTI):
        return model
    if control.isctime(model, strict=True):
        warnings.warn(
            f"a continuous-time model: discretised by zero-order hold at the data's "
            f"Ts = {data.Ts:g} s (MATLAB's compare does the same)",
            RwlabWarning,
            stacklevel=4,  # the caller of compare()
        )
        model = control.sample_system(model, data.Ts, method="zoh")
    elif model.dt is not True and not math.isclose(model.dt, data.Ts, rel_tol=1e-9):
        raise ModelError(
            f"the model is sampled at dt = {model.dt:g} s and the data at Ts = {data.Ts:g} s; "
            "resample one of them (control.sample_system, IOData.resample)"
        )
    ss = control.ss(model)
    D = np.asarray(ss.D, dtype=float)
    return SSModel(ss.A, ss.B, ss.C, D, Ts=data.Ts, feedthrough=bool(np.any(D != 0)))


def _model_output(model, data: IOData, horizon: float, initial) -> np.ndarray:
    """Any model's k-step prediction on ``data`` as an (N, ny) array."""
    if not isinstance(data, IOData):
        raise DataError("compare and resid need an IOData with measured inputs and outputs")
    model = _from_control(model, data)
    if not callable(getattr(model, "predict", None)):
        from rwlab.errors import ModelError

        raise ModelError(
            f"compare takes an rwlab model or a python-control TransferFunction or StateSpace, "
            f"not {type(model).__name__}"
        )
    nu, ny = getattr(model, "nu", data.nu), getattr(model, "ny", 1)
    if (nu, ny) != (data.nu, data.ny):
        raise DataError(
            f"the model has {nu} input(s) and {ny} output(s); the data have {data.nu} and "
            f"{data.ny}: select the matching channels"
        )
    yhat = np.asarray(model.predict(data, horizon, initial=initial), dtype=float)
    return yhat.reshape(data.N, data.ny)


def compare(
    model, data: IOData, horizon: float | None = None, initial: str = "estimate"
) -> CompareResult:
    """Simulate (default) or predict ``horizon`` steps ahead and score against ``data``.

    Works on every model with MATLAB's ``predict`` semantics: ``PolyModel``,
    ``SSModel`` (any number of outputs), ``FIRModel`` and the nonlinear models,
    and on python-control's ``TransferFunction`` and ``StateSpace``: a discrete
    one at the data's Ts, a continuous one discretised by zero-order hold at it
    (with a warning, as MATLAB's ``compare`` does for ZOH data).

    Parameters
    ----------
    model : PolyModel, SSModel, FIRModel, ServoModel, WheelGreyBox, NLARXModel, or control.LTI
    data : IOData
        Usually the validation record, with the model's inputs and outputs.
    horizon : int or numpy.inf, optional
        Samples ahead, ``numpy.inf`` for simulation. The default is simulation
        for a model with inputs and 1-step prediction for a time series (a
        model without input simulates to zero).
    initial : {'estimate', 'zero', 'steady'}
        'estimate' (default, as MATLAB's ``compare``): the initial state that
        best fits ``data``'s output; 'zero' or 'steady' pre-sample values.

    Returns
    -------
    CompareResult
        Measured and model outputs, fit % and MSE.
    """
    if horizon is None:
        nu = getattr(model, "ninputs", None) or getattr(model, "nu", data.nu)
        horizon = np.inf if nu else 1
    yhat = _model_output(model, data, horizon, initial)
    y = data.y.copy()
    fits = np.array([fit_percent(y[:, i], yhat[:, i]) for i in range(data.ny)])
    mses = np.array([mse(y[:, i], yhat[:, i]) for i in range(data.ny)])
    if data.ny == 1:
        return CompareResult(y[:, 0], yhat[:, 0], float(fits[0]), float(mses[0]), float(horizon))
    return CompareResult(y, yhat, fits, mses, float(horizon))


@dataclass(frozen=True)
class ResidResult:
    """Residual analysis (MATLAB ``resid``), every output and every input.

    Attributes
    ----------
    residuals : numpy.ndarray, shape (N,), or (N, ny) for several outputs
        One-step prediction errors e(t).
    lags : numpy.ndarray, shape (M+1,)
        0..M for the autocorrelation.
    acf : numpy.ndarray, shape (M+1,)
        Normalised autocorrelation of the first output's residual (acf[0] = 1).
    acf_bound : float
        Confidence bound z/√N for acf at lags ≥ 1.
    ccf_lags : numpy.ndarray, shape (2M+1,)
        −M..M; r_ue(τ) correlates u(t) with e(t+τ): positive τ, the input leads
        the residual (where a model error shows); negative τ, the residual
        leads the input (feedback: the input was computed from past outputs).
    ccf : numpy.ndarray, shape (2M+1,)
        Normalised cross-correlation of the first input with the first residual.
    ccf_bound : float
        Confidence bound z·sqrt(Σₖ r_e(k) r_u(k))/√N of ``ccf``.
    confidence : float
        Confidence level of the bounds and tests (0.99 = MATLAB's default).
    whiteness_p : float
        Ljung–Box portmanteau p-value for lags 1..M, Bonferroni-adjusted over
        the outputs (ny × the smallest p, at most 1).
    independence_p : float
        NaN for a time series. Otherwise the p-value of the joint test that e
        is uncorrelated with the input at the lags where a model error shows,
        τ = nk..M (nk the model's input delay, 1 without feedthrough): the
        input is prewhitened by a least-squares AR(M) model, and
        ζ = N rᵀ R⁻¹ r (r the cross-correlations of e with the whitened input
        at those lags, R the Toeplitz matrix of e's autocorrelation) is
        referred to χ²(M − nk + 1). With a coloured input the raw
        cross-correlations at neighbouring lags are strongly dependent, so
        summing their squares would reject a true model far more often than
        1 − confidence (Ljung, System Identification, §16.6). One test per
        input and output, Bonferroni-adjusted (nu·ny × the smallest p).
    feedback_p : float
        The same test on the other lags, −M..nk−1 (the residual leading the
        input): a small value is a sign of feedback in the data, not a model
        error (Ljung §16.6), and does not enter :attr:`independent`.
    input_p : numpy.ndarray, shape (nu,)
        Unadjusted independence p-value per input (smallest over the outputs).
    acf_all : numpy.ndarray, shape (M+1, ny)
        Autocorrelation of every output's residual.
    ccf_all : numpy.ndarray, shape (2M+1, ny, nu)
        Cross-correlation of every input with every residual.
    first_lag : int
        nk, the first lag of the independence test.
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
    feedback_p: float = math.nan
    input_p: np.ndarray = field(default_factory=lambda: np.zeros(0))
    acf_all: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    ccf_all: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0)))
    first_lag: int = 1

    @property
    def white(self) -> bool:
        """True when the Ljung–Box test does not reject whiteness at 1 − confidence."""
        return self.whiteness_p >= 1 - self.confidence

    @property
    def independent(self) -> bool:
        """True when the residuals show no significant correlation with any input at
        the lags where a model error shows (always True for a time series)."""
        if math.isnan(self.independence_p):
            return True
        return self.independence_p >= 1 - self.confidence

    @property
    def feedback(self) -> bool:
        """True when the residual significantly leads an input (feedback in the data)."""
        return not math.isnan(self.feedback_p) and self.feedback_p < 1 - self.confidence

    def to_dict(self) -> dict:
        d = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in asdict(self).items()}
        d.pop("residuals")
        d.update(white=self.white, independent=self.independent, feedback=self.feedback)
        return d


def _xcorr(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """r(τ) = Σₜ a(t+τ) b(t) / N for τ = −max_lag..max_lag (biased estimate, FFT)."""
    n = a.size
    size = 1 << math.ceil(math.log2(2 * n))
    full = np.fft.irfft(np.fft.rfft(a, size) * np.conj(np.fft.rfft(b, size)), size)
    return np.concatenate([full[-max_lag:], full[: max_lag + 1]]) / n if max_lag else full[:1] / n


def _prewhitened(u: np.ndarray, order: int) -> np.ndarray:
    """Innovations of a Yule–Walker AR(``order``) model of ``u`` (Levinson, no BLAS
    threads): samples order..N−1."""
    r = _xcorr(u, u, order)[order:]
    if r[0] <= 0:
        return u[order:].copy()
    a = linalg.solve_toeplitz(r[:order], r[1 : order + 1])
    return sps.lfilter(np.concatenate([[1.0], -a]), [1.0], u)[order:]


def _independence_p(e: np.ndarray, uw: np.ndarray, max_lag: int, lags: np.ndarray) -> float:
    """p-value of ζ = N rᵀ R⁻¹ r ~ χ²(len(lags)) on the prewhitened input ``uw``
    (samples M..N−1, see ResidResult).

    ``lags`` are consecutive lags in −M..M of r_ue(τ) (u leading e for τ > 0).
    """
    ew = e[max_lag:] - e[max_lag:].mean()
    n = ew.size
    ree = _xcorr(ew, ew, 2 * max_lag)[2 * max_lag :]
    r = _xcorr(ew, uw, max_lag)[lags + max_lag] / math.sqrt(ree[0] * float(uw @ uw) / n)
    R = linalg.toeplitz(ree[: lags.size] / ree[0])
    zeta = n * float(r @ linalg.lstsq(R, r)[0])
    return float(stats.chi2.sf(zeta, lags.size))


def _first_lag(model, j: int) -> int:
    """The input delay nk of input ``j``: the first lag at which a model error can show."""
    nk = getattr(model, "nk", None)
    if nk is not None:
        ks = np.atleast_1d(nk)
        return max(0, int(ks[j] if j < ks.size else ks[0]))
    D = getattr(model, "D", None)
    if getattr(model, "feedthrough", False) or (
        D is not None and np.ndim(D) == 2 and np.any(np.asarray(D)[:, j] != 0)
    ):
        return 0
    return 1


def resid(
    model, data: IOData, max_lag: int = 25, confidence: float = 0.99, initial: str = "zero"
) -> ResidResult:
    """Residual whiteness and input independence tests with confidence bounds.

    Every output's residual and every input are tested. For a time series (no
    input) only whiteness is tested, as MATLAB's ``resid``. The independence
    verdict uses the lags where a model error shows (the input leading the
    residual, τ ≥ nk); the other lags are reported apart (``feedback_p``), as a
    sign of feedback in the data (Ljung, §16.6): on closed-loop data the true
    model's residual leads the input, since the controller acts on it.

    Parameters
    ----------
    model : PolyModel, SSModel, FIRModel, ServoModel, WheelGreyBox or NLARXModel
        The model to test; its ``predict(data, 1, initial=...)`` gives the residuals.
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
    E = data.y - _model_output(model, data, 1, initial)
    N, ny, nu = E.shape[0], data.ny, data.nu
    z = stats.norm.ppf(0.5 + confidence / 2)
    k = np.arange(1, max_lag + 1)
    acf_all = np.empty((max_lag + 1, ny))
    white_p, rho_e = [], []
    for i in range(ny):
        ree = _xcorr(E[:, i], E[:, i], max_lag)
        r0 = ree[max_lag]
        if r0 <= 0:
            raise DataError("the residuals are identically zero; nothing to test")
        acf_all[:, i] = ree[max_lag:] / r0
        q_lb = N * (N + 2) * np.sum(acf_all[1:, i] ** 2 / (N - k))
        white_p.append(float(stats.chi2.sf(q_lb, max_lag)))
        rho_e.append(ree / r0)
    common = dict(
        residuals=E[:, 0].copy() if ny == 1 else E,
        lags=np.arange(max_lag + 1),
        acf=acf_all[:, 0].copy(),
        acf_bound=float(z / math.sqrt(N)),
        confidence=confidence,
        whiteness_p=min(1.0, ny * min(white_p)),
        acf_all=acf_all,
    )
    if nu == 0:
        nothing = np.zeros(0)
        return ResidResult(
            **common, ccf_lags=nothing, ccf=nothing, ccf_bound=math.nan, independence_p=math.nan
        )
    ccf_all = np.zeros((2 * max_lag + 1, ny, nu))
    p_ind = np.ones((ny, nu))
    p_fb = np.ones((ny, nu))
    bound = math.nan
    first = [_first_lag(model, j) for j in range(nu)]
    for j in range(nu):
        u = data.u[:, j] - data.u[:, j].mean()
        ruu = _xcorr(u, u, max_lag)
        su = ruu[max_lag]
        if su <= 0:
            continue
        nk = min(first[j], max_lag)
        uw = _prewhitened(u, max_lag)
        for i in range(ny):
            e = E[:, i]
            ccf_all[:, i, j] = _xcorr(e, u, max_lag) / math.sqrt(float(e @ e) / N * su)
            if i == 0 and j == 0:
                var_ccf = max(float(np.sum(rho_e[0] * ruu / su)), 1e-12) / N
                bound = float(z * math.sqrt(var_ccf))
            p_ind[i, j] = _independence_p(e, uw, max_lag, np.arange(nk, max_lag + 1))
            p_fb[i, j] = _independence_p(e, uw, max_lag, np.arange(-max_lag, nk))
    tests = nu * ny
    return ResidResult(
        **common,
        ccf_lags=np.arange(-max_lag, max_lag + 1),
        ccf=ccf_all[:, 0, 0].copy(),
        ccf_bound=bound,
        independence_p=min(1.0, tests * float(p_ind.min())),
        feedback_p=min(1.0, tests * float(p_fb.min())),
        input_p=p_ind.min(axis=0),
        ccf_all=ccf_all,
        first_lag=min(first),
    )
