"""Non-parametric estimates: ``spa``, ``etfe`` (frequency responses) and ``impulseest`` (FIR).

MATLAB's names and defaults:

- ``spa`` — Blackman–Tukey spectral analysis with a Hann lag window of size
  ``min(N/10, 30)``, at 128 frequencies (1…128)·π/(128·Ts);
  ``G = Φyu Φu⁻¹`` and the noise spectrum ``Φv = Φy − G Φuy``, with the
  asymptotic standard deviation of G (Ljung, *System Identification*, §6.4).
- ``etfe`` — the raw empirical transfer-function estimate Y(ω)/U(ω) (or the
  periodogram of a time series) at the same default frequencies. MATLAB's
  optional frequency smoothing is not offered: ``spa`` is that smoothing.
- ``impulseest`` — a regularised FIR estimate with the tuned-correlated ('TC')
  kernel whose hyperparameters maximise the marginal likelihood (empirical
  Bayes; Chen, Ohlsson & Ljung 2012), MATLAB's default; ``'none'`` is plain
  least squares. The coefficients' standard deviations are the posterior ones.

Spectra carry MATLAB's scaling Φ(ω) = Ts Σ R(τ) e^{−iωτTs}. Written here
because scipy's spectral tools estimate spectra only, without MATLAB's
conventions, the noise spectrum or the variance of G.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize
from threadpoolctl import threadpool_limits

from rwlab._display import ShortRepr
from rwlab.data import IOData, as_experiments
from rwlab.errors import DataError, EstimationError

__all__ = ["FIRModel", "FrequencyResponse", "etfe", "impulseest", "spa"]


@dataclass(frozen=True, repr=False)
class FrequencyResponse(ShortRepr):
    """A frequency response estimate (MATLAB ``idfrd``).

    Attributes
    ----------
    omega : numpy.ndarray, shape (nw,)
        Frequencies in rad/s.
    response : numpy.ndarray, shape (nw, ny, nu), complex
        G(e^{iωTs}) for each output and input (nu = 0 for a time series).
    Ts : float
        Sample time in seconds.
    response_sd : numpy.ndarray, shape (nw, ny, nu), or None
        Standard deviation of the complex response, sqrt(E|Ĝ − G|²). For a
        circular complex Gaussian error the standard deviation of |G| is about
        ``response_sd / √2`` (see :meth:`magnitude_sd`).
    spectrum : numpy.ndarray, shape (nw, ny, ny), or None
        Noise spectrum Φv (output spectrum for a time series), unit² · s.
    method : str
        'spa', 'etfe' or 'impulseest'.
    report : dict
        Method notes; for 'spa', ``bias``: the window's resolution and bias
        indicator (see :func:`spa`).
    """

    omega: np.ndarray
    response: np.ndarray
    Ts: float
    response_sd: np.ndarray | None = None
    spectrum: np.ndarray | None = None
    method: str = ""
    report: dict = field(default_factory=dict)

    def magnitude_db(self) -> np.ndarray:
        """20 log₁₀ |G|, shape (nw, ny, nu)."""
        return 20 * np.log10(np.abs(self.response))

    def phase_deg(self) -> np.ndarray:
        """Unwrapped phase of G along frequency in degrees, shape (nw, ny, nu)."""
        return np.degrees(np.unwrap(np.angle(self.response), axis=0))

    def magnitude_sd(self) -> np.ndarray | None:
        """Standard deviation of |G| (circular complex Gaussian error assumed)."""
        return None if self.response_sd is None else self.response_sd / np.sqrt(2)

    def to_pandas(self):
        """Magnitude (dB) and phase (deg) per channel pair, one row per frequency.

        Returns
        -------
        pandas.DataFrame
            Index ``omega_rad_s``; columns ``magnitude_db[y,u]`` and ``phase_deg[y,u]``.
        """
        from rwlab._display import pandas

        pd = pandas()
        mag, ph = self.magnitude_db(), self.phase_deg()
        cols = {}
        for i in range(mag.shape[1]):
            for j in range(mag.shape[2]):
                cols[f"magnitude_db[{i},{j}]"] = mag[:, i, j]
                cols[f"phase_deg[{i},{j}]"] = ph[:, i, j]
        return pd.DataFrame(cols, index=pd.Index(self.omega, name="omega_rad_s"))

    def to_dict(self) -> dict:
        """Plain-JSON form: real and imaginary parts separately."""
        opt = lambda a: None if a is None else np.asarray(a).tolist()  # noqa: E731
        return {
            "method": self.method,
            "Ts": self.Ts,
            "omega": self.omega.tolist(),
            "response_real": self.response.real.tolist(),
            "response_imag": self.response.imag.tolist(),
            "response_sd": opt(self.response_sd),
            "spectrum_real": opt(None if self.spectrum is None else self.spectrum.real),
            "report": self.report,
        }


def _frequencies(omega, Ts: float, n: int = 128) -> np.ndarray:
    if omega is None:
        return np.arange(1, n + 1) / n * np.pi / Ts
    w = np.atleast_1d(np.asarray(omega, dtype=float))
    if w.ndim != 1 or w.size == 0 or not np.all(np.isfinite(w)) or np.any(w < 0):
        raise DataError("omega must be a 1-D array of finite frequencies ≥ 0 in rad/s")
    return w


def _one_record(data, what: str) -> IOData:
    experiments = as_experiments(data)
    if len(experiments) != 1:
        raise DataError(f"{what} takes one record; estimate each experiment separately")
    return experiments[0]


def spa(
    data: IOData, window_size: int | None = None, omega=None, *, _bias_check: bool = True
) -> FrequencyResponse:
    """Blackman–Tukey spectral analysis (MATLAB ``spa``).

    Parameters
    ----------
    data : IOData
        nu ≥ 0 inputs, ny ≥ 1 outputs. Remove means first (``detrend``) when
        the record has offsets, as in MATLAB.
    window_size : int, optional
        Size M of the Hann lag window, in samples (default ``min(N/10, 30)``).
    omega : array_like, optional
        Frequencies in rad/s (default 128 values (1…128)·π/(128 Ts)).

    Returns
    -------
    FrequencyResponse
        ``response`` G, ``response_sd`` from Var Ĝᵢⱼ ≈ (Σ W²/N) Φvᵢᵢ [Φu⁻¹]ⱼⱼ,
        and ``spectrum`` Φv (Φy for a time series). ``bias`` holds the
        window's bias bound (below).

    Notes
    -----
    ``response_sd`` is the variance part only. The lag window also smooths G
    over a frequency band of width about 2π/(M Ts) rad/s, a bias of order
    (1/M²)·|G''(ω)| that the ±σ band leaves out: at a resonance sharper than
    the window (half-power width below 2π/(M Ts)) the band can miss the
    truth most of the time (measured: 42 % coverage of a ±1σ band at a
    lightly damped peak). ``report['bias']`` states the resolution and a
    per-frequency bias estimate, ``|Ĝ − Ĝ_M/2|/3``: the bias grows as M⁻², so
    halving the window quadruples it (Richardson); it is largest where
    smoothing flattens a peak. Raise ``M`` there.
    """
    d = _one_record(data, "spa")
    N, ny, nu = d.N, d.ny, d.nu
    M = min(N // 10, 30) if window_size is None else int(window_size)
    if not 1 <= M < N:
        raise DataError(f"window_size must be between 1 and N − 1 = {N - 1}, got {window_size}")
    w = _frequencies(omega, d.Ts)
    z = np.hstack([d.y, d.u])
    lags = np.arange(M + 1)
    lag_window = 0.5 * (1 + np.cos(np.pi * lags / M))
    R = np.array([z[k:].T @ z[: N - k] / N for k in lags])  # R[k] = E z(t+k) z(t)ᵀ
    E = np.exp(-1j * np.outer(w, lags) * d.Ts)  # (nw, M+1)
    WR = lag_window[:, None, None] * R
    half = np.einsum("wk,kij->wij", E[:, 1:], WR[1:])
    Phi = d.Ts * (R[0][None] + half + np.conj(np.swapaxes(half, 1, 2)))
    Phi_y = Phi[:, :ny, :ny]
    if nu == 0:
        return FrequencyResponse(w, np.zeros((w.size, ny, 0), complex), d.Ts, None, Phi_y, "spa")
    Phi_yu, Phi_u = Phi[:, :ny, ny:], Phi[:, ny:, ny:]
    try:
        Phi_u_inv = np.linalg.inv(Phi_u)
    except np.linalg.LinAlgError:
        raise EstimationError("the input spectrum is singular: the inputs do not excite") from None
    G = Phi_yu @ Phi_u_inv
    Phi_v = Phi_y - G @ np.conj(np.swapaxes(Phi_yu, 1, 2))
    cw = lag_window[0] ** 2 + 2 * np.sum(lag_window[1:] ** 2)
    var = cw / N * np.einsum("wi,wj->wij", np.real(np.diagonal(Phi_v, axis1=1, axis2=2)),
                             np.real(np.diagonal(Phi_u_inv, axis1=1, axis2=2)))  # fmt: skip
    bias = None
    if M >= 4 and _bias_check:
        coarse = spa(d, M // 2, w, _bias_check=False).response
        bias = {
            "window_size": M,
            "resolution_rad_s": 2 * np.pi / (M * d.Ts),
            "estimate": (np.abs(G - coarse) / 3).tolist(),
            "note": "response_sd is the variance part only; the window smooths G over "
            "about resolution_rad_s, a bias the ±σ band leaves out (largest at sharp "
            "resonances). estimate = |G − G(M/2)|/3 (the bias grows as M⁻²: Richardson), "
            "an indicator that also carries the estimates' noise.",
        }
    return FrequencyResponse(
        w, G, d.Ts, np.sqrt(np.clip(var, 0, None)), Phi_v, "spa", {"bias": bias}
    )


def _dft(x: np.ndarray, w: np.ndarray, Ts: float, chunk: int = 4096) -> np.ndarray:
    """X(ω) = Σₜ x(t) e^{−iωtTs} for x (N, m) at ω (nw,): shape (nw, m), in chunks of samples."""
    out = np.zeros((w.size, x.shape[1]), complex)
    for k in range(0, x.shape[0], chunk):
        t = np.arange(k, min(k + chunk, x.shape[0]))
        out += np.exp(-1j * np.outer(w, t) * Ts) @ x[t]
    return out


def etfe(data: IOData, omega=None) -> FrequencyResponse:
    """Empirical transfer-function estimate Y(ω)/U(ω) (MATLAB ``etfe``, unsmoothed).

    One input (any number of outputs), or a time series, for which the result
    is the periodogram Ts |Y(ω)|²/N in ``spectrum``. Exact at the excited
    frequencies for a noise-free record with a periodic input over whole periods.

    Parameters
    ----------
    data : IOData
        One input (or none), any number of outputs.
    omega : array_like, optional
        Frequencies, rad/s (default the FFT grid up to Nyquist).

    Returns
    -------
    FrequencyResponse
        ``response`` of shape (nw, ny, 1) (``spectrum`` for a time series).
    """
    d = _one_record(data, "etfe")
    w = _frequencies(omega, d.Ts)
    Y = _dft(d.y, w, d.Ts)
    if d.nu == 0:
        spectrum = d.Ts / d.N * np.einsum("wi,wj->wij", Y, np.conj(Y))
        return FrequencyResponse(
            w, np.zeros((w.size, d.ny, 0), complex), d.Ts, None, spectrum, "etfe"
        )
    if d.nu != 1:
        raise DataError("etfe needs one input (or none); use spa for several inputs")
    U = _dft(d.u, w, d.Ts)[:, 0]
    if np.any(np.abs(U) < 1e-12 * max(np.abs(U).max(), 1e-300)):
        raise EstimationError("the input has no energy at some of the frequencies; choose omega")
    return FrequencyResponse(w, (Y / U[:, None])[:, :, None], d.Ts, method="etfe")


@dataclass(frozen=True, repr=False)
class FIRModel(ShortRepr):
    """A finite impulse response estimate (MATLAB ``impulseest``'s FIR model).

    ``y_i(t) = Σⱼ Σₖ g[k, i, j] u_j(t − nk − k) + v_i(t)``, k = 0 … n−1.

    Attributes
    ----------
    coefficients : numpy.ndarray, shape (n, ny, nu)
        Impulse-response coefficients (response to a unit pulse, per sample).
    sd : numpy.ndarray, shape (n, ny, nu)
        Their standard deviations (posterior ones when regularised).
    Ts : float
    nk : int
        Delay of the first coefficient in samples.
    noise_variance : numpy.ndarray, shape (ny,)
    covariance : list of numpy.ndarray
        Per output, the (n·nu)² covariance of [g[:, i, 0], g[:, i, 1], ...].
    report : dict
        Kernel and hyperparameters per output.
    """

    coefficients: np.ndarray
    sd: np.ndarray
    Ts: float
    nk: int
    noise_variance: np.ndarray
    covariance: list = field(repr=False)
    report: dict = field(default_factory=dict)

    @property
    def lags(self) -> np.ndarray:
        """Sample index of each coefficient, shape (n,)."""
        return self.nk + np.arange(self.coefficients.shape[0])

    @property
    def nu(self) -> int:
        """Number of inputs."""
        return int(self.coefficients.shape[2])

    @property
    def ny(self) -> int:
        """Number of outputs."""
        return int(self.coefficients.shape[1])

    def simulate(self, u, initial: str = "zero") -> np.ndarray:
        """Noise-free output ``Σₖ gₖ u(t − nk − k)``, shape (N, ny).

        Parameters
        ----------
        u : array_like, shape (N,) or (N, nu), or IOData
            Inputs; an IOData with its outputs for ``initial='estimate'``.
        initial : {'zero', 'steady', 'estimate'}
            Pre-sample inputs zero; held at ``u[0]``; or fitted to the measured
            outputs by least squares (the FIR's state is its past inputs; the
            minimum-norm solution where they are not all determined).
        """
        from rwlab.ident.polynomials import check_initial

        initial = check_initial(initial)
        data = u if isinstance(u, IOData) else None
        arr = np.asarray(data.u if data is not None else u, dtype=float)
        arr = arr[:, None] if arr.ndim == 1 else arr
        if arr.ndim != 2 or arr.shape[1] != self.nu or not np.all(np.isfinite(arr)):
            raise DataError(f"u must be finite with shape (N, {self.nu}); got {np.shape(arr)}")
        N, n = arr.shape[0], self.coefficients.shape[0]
        memory = self.nk + n - 1
        pad = (
            np.repeat(arr[:1], memory, axis=0)
            if initial == "steady"
            else np.zeros((memory, self.nu))
        )
        full = np.vstack([pad, arr])
        y = np.zeros((N, self.ny))
        for j in range(self.nu):
            for i in range(self.ny):
                h = np.concatenate([np.zeros(self.nk), self.coefficients[:, i, j]])
                y[:, i] += np.convolve(full[:, j], h)[memory : memory + N]
        if initial != "estimate" or memory == 0:
            return y
        if data is None or data.ny != self.ny:
            raise DataError("initial='estimate' needs an IOData with the measured outputs")
        # y(t) gains Σ_m g[nk+... ] u(−m): one column per unknown past input sample and input
        cols = []
        for j in range(self.nu):
            for m in range(1, memory + 1):
                col = np.zeros((N, self.ny))
                for i in range(self.ny):
                    h = np.concatenate([np.zeros(self.nk), self.coefficients[:, i, j]])
                    t = np.arange(N)
                    idx = t + m
                    ok = idx < h.size
                    col[ok, i] = h[idx[ok]]
                cols.append(col.ravel())
        past, *_ = np.linalg.lstsq(np.column_stack(cols), (data.y - y).ravel(), rcond=None)
        return y + (np.column_stack(cols) @ past).reshape(y.shape)

    def predict(self, data: IOData, horizon: float = 1, initial: str = "zero") -> np.ndarray:
        """k-step prediction, shape (N, ny): an FIR estimate has no noise model (its
        disturbance is white, MATLAB's FIR ``idpoly`` with C = D = 1), so every
        horizon's prediction is the simulation.

        Parameters
        ----------
        data : IOData
        horizon : int or numpy.inf
            Samples ahead (≥ 1).
        initial : {'zero', 'steady', 'estimate'}
            As for :meth:`simulate`.
        """
        if not isinstance(data, IOData) or (data.nu, data.ny) != (self.nu, self.ny):
            raise DataError(f"predict needs an IOData with {self.nu} inputs and {self.ny} outputs")
        if horizon != np.inf and (int(horizon) != horizon or horizon < 1):
            raise DataError(f"horizon must be a positive integer or inf, got {horizon}")
        return self.simulate(data, initial)

    def step_response(self) -> np.ndarray:
        """Cumulative sum of the coefficients, shape (n, ny, nu)."""
        return np.cumsum(self.coefficients, axis=0)

    def frequency_response(self, omega=None) -> FrequencyResponse:
        """G(e^{iωTs}) = Σₖ gₖ e^{−iω(nk+k)Ts} with its exact (linear) standard deviation."""
        w = _frequencies(omega, self.Ts)
        n, ny, nu = self.coefficients.shape
        F = np.exp(-1j * np.outer(w, self.lags) * self.Ts)  # (nw, n)
        G = np.einsum("wk,kij->wij", F, self.coefficients)
        sd = np.empty((w.size, ny, nu))
        for i in range(ny):
            cov = self.covariance[i]
            for j in range(nu):
                blk = cov[j * n : (j + 1) * n, j * n : (j + 1) * n]
                sd[:, i, j] = np.sqrt(np.real(np.einsum("wk,kl,wl->w", F, blk, np.conj(F))))
        return FrequencyResponse(w, G, self.Ts, sd, method="impulseest")


def _regressors(experiments: list[IOData], n: int, nk: int) -> tuple[np.ndarray, np.ndarray]:
    """Φ with columns u_j(t − nk − k), j-major, and the matching outputs (rows t ≥ nk + n − 1)."""
    rows, targets = [], []
    first = nk + n - 1
    for d in experiments:
        if d.N <= first:
            continue
        cols = [d.u[first - nk - k : d.N - nk - k, j] for j in range(d.nu) for k in range(n)]
        rows.append(np.column_stack(cols))
        targets.append(d.y[first:])
    if not rows:
        raise DataError(f"the data are shorter than the FIR length nk + n = {first + 1}")
    return np.vstack(rows), np.vstack(targets)


def _tc_kernel(n: int, c: float, lam: float) -> np.ndarray:
    k = np.arange(1, n + 1)
    return c * lam ** np.maximum.outer(k, k)


def _factor(P: np.ndarray) -> np.ndarray:
    """L with L Lᵀ = P for a positive semi-definite P (eigenvalues clipped at 0)."""
    s, V = np.linalg.eigh(P)
    return V * np.sqrt(np.clip(s, 0, None))


def _prior(hyper: np.ndarray, n: int, nu: int) -> np.ndarray:
    """Block-diagonal TC prior, one (c, λ) per input from log c, logit λ."""
    P = np.zeros((n * nu, n * nu))
    for j in range(nu):
        c, lam = np.exp(hyper[2 * j]), 1 / (1 + np.exp(-hyper[2 * j + 1]))
        P[j * n : (j + 1) * n, j * n : (j + 1) * n] = _tc_kernel(n, c, lam)
    return P


def _posterior(L, Rphi, r, yy, sigma2, n_rows):
    """Negative log marginal likelihood, posterior mean and covariance (Woodbury, p × p)."""
    p = L.shape[1]
    S = sigma2 * np.eye(p) + L.T @ Rphi @ L
    cho = np.linalg.cholesky((S + S.T) / 2)
    b = L.T @ r
    v = np.linalg.solve(cho, b)
    quad = (yy - v @ v) / sigma2
    logdet = (n_rows - p) * np.log(sigma2) + 2 * np.sum(np.log(np.diag(cho)))
    Sinv_LT = np.linalg.solve(S, L.T)
    return 0.5 * (quad + logdet), L @ (Sinv_LT @ r), sigma2 * L @ Sinv_LT


def impulseest(
    data: IOData | Sequence[IOData], n: int = 70, nk: int = 0, *, kernel: str = "TC"
) -> FIRModel:
    """Regularised FIR estimate of the impulse response (MATLAB ``impulseest``).

    Parameters
    ----------
    data : IOData or list of IOData
        At least one input; any number of outputs (each estimated separately).
    n : int
        Number of coefficients (rwlab's default 70; MATLAB chooses one from the data).
    nk : int
        Delay of the first coefficient in samples (default 0, as MATLAB).
    kernel : {'TC', 'none'}
        Tuned-correlated prior P(k, l) = c λ^max(k,l) per input, hyperparameters
        c, λ and the noise variance by maximum marginal likelihood; or ordinary
        least squares (no prewhitening is applied).

    Returns
    -------
    FIRModel
    """
    experiments = as_experiments(data)
    nu, ny = experiments[0].nu, experiments[0].ny
    if nu == 0:
        raise DataError("impulseest needs at least one input; use spa for a time series")
    if int(n) != n or n < 1 or int(nk) != nk or nk < 0:
        raise DataError(f"n must be ≥ 1 and nk ≥ 0 (integers), got n={n}, nk={nk}")
    if kernel not in ("TC", "none"):
        raise DataError(f"kernel must be 'TC' or 'none', got {kernel!r}")
    n, nk = int(n), int(nk)
    Phi, Y = _regressors(experiments, n, nk)
    p = n * nu
    if Phi.shape[0] <= p:
        raise DataError(f"{Phi.shape[0]} usable samples are too few for {p} FIR coefficients")
    Rphi = Phi.T @ Phi
    coef = np.empty((n, ny, nu))
    sd = np.empty((n, ny, nu))
    noise, covs, hyper_out = np.empty(ny), [], []
    ls, *_ = np.linalg.lstsq(Phi, Y, rcond=None)
    for i in range(ny):
        y = Y[:, i]
        res = y - Phi @ ls[:, i]
        sigma2_ls = float(res @ res) / (len(y) - p)
        if kernel == "none":
            cov = sigma2_ls * np.linalg.inv(Rphi)
            theta, sigma2 = ls[:, i], sigma2_ls
        else:
            r, yy = Phi.T @ y, float(y @ y)
            scale = max(float(np.max(ls[:, i] ** 2)), 1e-12)

            def cost(h, r=r, yy=yy):
                L = _factor(_prior(h[:-1], n, nu))
                return _posterior(L, Rphi, r, yy, np.exp(h[-1]), len(Y))[0]

            h0 = np.concatenate([np.tile([np.log(scale), np.log(0.9 / 0.1)], nu),
                                 [np.log(sigma2_ls)]])  # fmt: skip
            with threadpool_limits(1, user_api="blas"):  # small matrices: threads only cost
                opt = optimize.minimize(cost, h0, method="L-BFGS-B")
            h = opt.x
            sigma2 = float(np.exp(h[-1]))
            _, theta, cov = _posterior(_factor(_prior(h[:-1], n, nu)), Rphi, r, yy, sigma2, len(y))
            hyper_out.append(
                {
                    "c": np.exp(h[:-1:2]).tolist(),
                    "lambda": (1 / (1 + np.exp(-h[1:-1:2]))).tolist(),
                    "noise_variance": sigma2,
                    "converged": bool(opt.success),
                }
            )
        noise[i] = sigma2
        covs.append(cov)
        coef[:, i, :] = theta.reshape(nu, n).T
        sd[:, i, :] = np.sqrt(np.clip(np.diag(cov), 0, None)).reshape(nu, n).T
    return FIRModel(
        coef, sd, experiments[0].Ts, nk, noise, covs,
        {"kernel": kernel, "n": n, "nk": nk, "hyperparameters": hyper_out},
    )  # fmt: skip
