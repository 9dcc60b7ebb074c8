"""Prediction-error estimation of ARMAX, OE and BJ models (MATLAB ``armax``, ``oe``, ``bj``).

All three are cases of ``A y = (B/F) u + (C/D) e``; the prediction error is

    ε(t) = (D/C)·(A y − (B/F) u).

It is minimised in the least-squares sense by Levenberg–Marquardt steps on the
Gauss–Newton Hessian ψᵀψ, with ψ = ∂ε/∂θ computed exactly by filtering:

    ∂ε/∂aᵢ =  (D/C) q⁻ⁱ y            ∂ε/∂bᵢ = −(D/(C F)) q⁻ⁱ u
    ∂ε/∂fᵢ =  (D/(C F)) q⁻ⁱ w        ∂ε/∂cᵢ = −(1/C) q⁻ⁱ ε
    ∂ε/∂dᵢ =  (1/C) q⁻ⁱ v            (w = (B/F) u, v = A y − w)

After every step, roots of C, D and F outside the unit circle are reflected
inside, so the predictor stays stable (as MATLAB does).

Starting values: ARMAX and BJ noise models from the Hannan–Rissanen two-stage
least squares (long ARX → residuals → linear regression); OE and BJ dynamics
from instrumental variables with simulated-output instruments. ARMAX is also
started from the output-error dynamics (A = F, C = 1): its likelihood can have
several minima (the detrended cascaded tanks' ARMAX3321 has two). Starts and a
first search use at most ``START_SAMPLES`` samples per experiment: they only
need to land in the basin of the optimum; the best is then refined on all data.

Pre-sample values (``initial=``): ``'zero'`` — all filters start from zero
(MATLAB ``InitialCondition = 'zero'``); ``'steady'`` — every signal held its
first value forever before the record (a record that starts at rest), i.e.
filters start in that equilibrium and shifts pad with the first value. Under
either convention the gradient formulas above are exact. ε is formed over
every sample. The covariance is
λ·(ψᵀψ)⁻¹ with λ = Σε²/(N − d), evaluated at the optimum.
"""

from __future__ import annotations

import sys
import types
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import linalg
from scipy import signal as sps

from rwlab.data import IOData, as_experiments
from rwlab.errors import DataError, EstimationError, RwlabWarning
from rwlab.ident.arx import check_order
from rwlab.ident.models import PolyModel
from rwlab.ident.polynomials import check_initial, filt, stabilize
from rwlab.ident.validation import estimation_report

__all__ = ["armax", "bj", "oe", "pem"]

START_SAMPLES = 10_000
MAX_ITER = "maximum iterations reached"
EXACT_FIT = 1e-24  # Σε² below this fraction of Σy²: the data are noise-free and fitted exactly
ESTIMATION_INITIAL = ("zero", "steady")  # what an estimator can assume before the record


@dataclass(frozen=True)
class _Orders:
    na: int
    nb: int
    nc: int
    nd: int
    nf: int
    nk: int
    steady: bool = False  # pre-sample values: zero, or each signal's first value

    @property
    def d(self) -> int:
        return self.na + self.nb + self.nc + self.nd + self.nf

    def unpack(self, theta: np.ndarray):
        """θ → (A, B, C, D, F) polynomials in q⁻¹."""
        i = np.cumsum([0, self.na, self.nb, self.nc, self.nd, self.nf])
        B = np.zeros(self.nk + self.nb)
        B[self.nk :] = theta[i[1] : i[2]]
        mon = lambda k: np.concatenate([[1.0], theta[i[k] : i[k + 1]]])  # noqa: E731
        return mon(0), B, mon(2), mon(3), mon(4)

    def pack(self, A, B, C, D, F) -> np.ndarray:
        return np.concatenate([A[1:], B[self.nk : self.nk + self.nb], C[1:], D[1:], F[1:]])


def _stabilized(orders: _Orders, theta: np.ndarray) -> np.ndarray:
    A, B, C, D, F = orders.unpack(theta)
    return orders.pack(A, B, stabilize(C), stabilize(D), stabilize(F))


def _signals(orders: _Orders, theta, y, u):
    """ε, w = (B/F) u and v = A y − w for one experiment."""
    A, B, C, D, F = orders.unpack(theta)
    st = orders.steady
    w = filt(B, F, u, st)
    v = (filt(A, [1.0], y, st) if orders.na else y) - w
    e = filt(D, C, v, st) if (orders.nc or orders.nd) else v
    return e, w, v


def _sse(orders, theta, experiments) -> float:
    total = 0.0
    for y, u in experiments:
        e = _signals(orders, theta, y, u)[0]
        total += float(e @ e)
    return total


def _jacobian_block(orders: _Orders, theta, y, u, e, w, v) -> np.ndarray:
    """ψᵀ = (∂ε/∂θ)ᵀ for one experiment, shape (d, N): one contiguous row per parameter."""
    _A, _B, C, D, F = orders.unpack(theta)
    N = len(y)
    psi_t = np.empty((orders.d, N))
    row = 0
    noise = orders.nc or orders.nd
    CF = np.convolve(C, F)
    st = orders.steady

    def put(signal, first_lag, count, sign):
        nonlocal row
        for i in range(count):
            k = min(first_lag + i, N)
            psi_t[row, :k] = signal[0] if (st and k and N) else 0.0
            psi_t[row, k:] = signal[: N - k]
            if sign < 0:
                psi_t[row] *= -1.0  # a contiguous row: safe in place
            row += 1

    if orders.na:
        put(filt(D, C, y, st) if noise else y, 1, orders.na, +1)
    if orders.nb:
        put(filt(D, CF, u, st) if (noise or orders.nf) else u, orders.nk, orders.nb, -1)
    if orders.nc:
        put(filt([1.0], C, e, st), 1, orders.nc, -1)
    if orders.nd:
        put(filt([1.0], C, v, st), 1, orders.nd, +1)
    if orders.nf:
        put(filt(D, CF, w, st), 1, orders.nf, +1)
    return psi_t


def _normal_equations(orders, theta, experiments):
    """ψᵀψ, ψᵀε and ε'ε summed over experiments at θ."""
    d = orders.d
    H = np.zeros((d, d))
    g = np.zeros(d)
    sse = 0.0
    for y, u in experiments:
        e, w, v = _signals(orders, theta, y, u)
        psi_t = _jacobian_block(orders, theta, y, u, e, w, v)
        H += psi_t @ psi_t.T
        g += psi_t @ e
        sse += float(e @ e)
    return H, g, sse


def _minimize(orders, theta, experiments, max_iter: int, tol: float):
    """Levenberg–Marquardt on ½Σε². Returns θ, H, sse, iterations, reason."""
    theta = _stabilized(orders, theta)
    mu = 1e-4
    reason = MAX_ITER
    it = 0
    H, g, sse = _normal_equations(orders, theta, experiments)
    exact = EXACT_FIT * sum(float(y @ y) for y, _ in experiments)
    for it in range(1, max_iter + 1):
        if sse <= exact:
            reason = "converged (exact fit)"
            break
        scale = np.sqrt(np.maximum(np.diag(H), 1e-300))
        Hs = H / np.outer(scale, scale)
        gs = g / scale
        while True:
            try:
                step = -linalg.solve(Hs + mu * np.eye(len(gs)), gs, assume_a="pos") / scale
            except (linalg.LinAlgError, ValueError):
                step = None
            if step is not None:
                trial = _stabilized(orders, theta + step)
                sse_trial = _sse(orders, trial, experiments)
                if sse_trial < sse:
                    break
            mu *= 10.0
            if mu > 1e12:
                return theta, H, sse, it, "no further decrease possible (local minimum)"
        improvement = (sse - sse_trial) / sse
        expected = float(-(g @ step)) / sse
        theta = trial
        mu = max(mu / 10.0, 1e-12)
        H, g, sse = _normal_equations(orders, theta, experiments)
        if improvement < tol and expected < 10 * tol:
            reason = "converged (relative improvement below tolerance)"
            break
    return theta, H, sse, it, reason


# -- starting values -------------------------------------------------------------------
def _lags(x: np.ndarray, first: int, count: int, n0: int) -> list[np.ndarray]:
    N = len(x)
    return [x[n0 - first - i : N - first - i] for i in range(count)]


def _least_squares(columns: list[np.ndarray], target: np.ndarray) -> np.ndarray:
    """Least squares by the (equilibrated) normal equations: accurate enough for a start,
    and far cheaper than a QR of the tall regressor matrix."""
    if not columns:
        return np.zeros(0)
    Phi = np.empty((len(columns), len(target)))  # one contiguous row per regressor
    for i, c in enumerate(columns):
        Phi[i] = c
    G = Phi @ Phi.T
    unit = np.sqrt(np.maximum(np.diag(G), 1e-300))
    theta, *_ = np.linalg.lstsq(G / np.outer(unit, unit), (Phi @ target) / unit, rcond=1e-12)
    return theta / unit


def _arma_hannan_rissanen(v: np.ndarray, nc: int, nd: int) -> tuple[np.ndarray, np.ndarray]:
    """C and D of v = (C/D) e by two-stage least squares (D is the AR part)."""
    if nc == 0 and nd == 0:
        return np.ones(1), np.ones(1)
    long = min(max(20, 3 * (nc + nd)), max(len(v) // 10, nc + nd + 1))
    a_long = _least_squares([-c for c in _lags(v, 1, long, long)], v[long:])
    ehat = np.convolve(v, np.concatenate([[1.0], a_long]))[: len(v)]
    n0 = max(nc, nd, long)
    cols = [-c for c in _lags(v, 1, nd, n0)] + _lags(ehat, 1, nc, n0)
    th = _least_squares(cols, v[n0:])
    D = np.concatenate([[1.0], th[:nd]])
    C = np.concatenate([[1.0], th[nd:]])
    return stabilize(C), stabilize(D)


def _initial_armax(orders: _Orders, experiments) -> np.ndarray:
    """Hannan–Rissanen: long ARX residuals ê, then y on lags of y, u and ê."""
    na, nb, nc, nk = orders.na, orders.nb, orders.nc, orders.nk
    long = max(10, 2 * (na + nc), na + nb)
    cols_all, targets = [], []
    ehats = []
    for y, u in experiments:
        n0 = max(long, nk + long - 1)
        cols = [-c for c in _lags(y, 1, long, n0)] + _lags(u, nk, long, n0)
        th = _least_squares(cols, y[n0:])
        A_long = np.concatenate([[1.0], th[:long]])
        B_long = np.concatenate([np.zeros(nk), th[long:]])
        ehat = np.convolve(y, A_long)[: len(y)] - np.convolve(u, B_long)[: len(u)]
        ehats.append(ehat)
    for (y, u), ehat in zip(experiments, ehats, strict=True):
        n0 = max(long, nk + long - 1, na, nk + nb - 1, nc)
        cols_all.append(
            np.column_stack(
                [-c for c in _lags(y, 1, na, n0)] + _lags(u, nk, nb, n0) + _lags(ehat, 1, nc, n0)
            )
        )
        targets.append(y[n0:])
    th = _least_squares(list(np.vstack(cols_all).T), np.concatenate(targets))
    A = np.concatenate([[1.0], th[:na]])
    B = np.zeros(nk + nb)
    B[nk:] = th[na : na + nb]
    C = stabilize(np.concatenate([[1.0], th[na + nb :]]))
    return orders.pack(A, B, C, np.ones(1), np.ones(1))


def _initial_oe(nb: int, nf: int, nk: int, experiments, iterations: int = 3):
    """B and F by ARX(nf, nb, nk), then instrumental variables with simulated instruments."""
    n0 = max(nf, nk + nb - 1)

    def regress(instrumented: bool, B, F):
        Phi, Z, T = [], [], []
        for y, u in experiments:
            cols = [-c for c in _lags(y, 1, nf, n0)] + _lags(u, nk, nb, n0)
            Phi.append(np.column_stack(cols))
            T.append(y[n0:])
            if instrumented:
                x = sps.lfilter(B, F, u)
                Z.append(np.column_stack([-c for c in _lags(x, 1, nf, n0)] + _lags(u, nk, nb, n0)))
        Phi, T = np.vstack(Phi), np.concatenate(T)
        if not instrumented:
            return _least_squares(list(Phi.T), T)
        Z = np.vstack(Z)
        return np.linalg.lstsq(Z.T @ Phi, Z.T @ T, rcond=None)[0]

    B = np.zeros(nk + nb)
    F = np.ones(1)
    th = regress(False, B, F)
    for i in range(iterations + 1):
        F = stabilize(np.concatenate([[1.0], th[:nf]]))
        B = np.zeros(nk + nb)
        B[nk:] = th[nf:]
        if i < iterations:
            th = regress(True, B, F)
    return B, F


def _initial_bj(orders: _Orders, experiments) -> np.ndarray:
    B, F = _initial_oe(orders.nb, orders.nf, orders.nk, experiments)
    v = np.concatenate([y - sps.lfilter(B, F, u) for y, u in experiments])
    C, D = _arma_hannan_rissanen(v, orders.nc, orders.nd)
    return orders.pack(np.ones(1), B, C, D, F)


# -- public estimators ---------------------------------------------------------------
def _prepare(data, orders: _Orders):
    experiments = as_experiments(data)
    first = experiments[0]
    if first.ny != 1 or first.nu != 1:
        raise DataError(
            "armax/oe/bj/pem estimate single-input single-output models; "
            f"the data have {first.nu} inputs and {first.ny} outputs"
        )
    N = sum(e.N for e in experiments)
    needed = orders.d + max(orders.na, orders.nk + orders.nb, orders.nc, orders.nd, orders.nf) + 1
    if N < needed:
        raise DataError(
            f"too few samples: {N} for a model with {orders.d} parameters; need at least {needed}"
        )
    if orders.nb and all(np.ptp(e.u[:, 0]) == 0 for e in experiments):
        raise EstimationError(
            "the input is constant: it is not persistently exciting, so B cannot be "
            "identified; use a PRBS, chirp or multisine input"
        )
    return experiments, [(e.y[:, 0], e.u[:, 0]) for e in experiments]


def _init_subset(series):
    return [(y[:START_SAMPLES], u[:START_SAMPLES]) for y, u in series]


def _search(orders, starts, series, max_iter, tol):
    """LM from every start on the first ``START_SAMPLES`` samples; the best, refined on all data.

    Several starts guard against local minima (ARMAX's likelihood has them);
    the short record makes each cheap, and from its optimum the full record
    needs only a step or two.
    """
    subset = _init_subset(series)
    whole = all(len(y) <= START_SAMPLES for y, _ in series)
    fits = [_minimize(orders, theta, subset, max_iter, tol) for theta in starts]
    best = min(fits, key=lambda fit: fit[2] if np.isfinite(fit[2]) else np.inf)
    return best if whole else _minimize(orders, best[0], series, max_iter, tol)


def _finish(orders, starts, experiments, series, method, max_iter, tol) -> PolyModel:
    theta, H, sse, iterations, reason = _search(orders, starts, series, max_iter, tol)
    if reason == MAX_ITER:
        warnings.warn(
            f"{method.split()[0]}: stopped after {iterations} iterations without converging; "
            "the model may not be the optimum (raise max_iter, or check orders and data)",
            RwlabWarning,
            stacklevel=3,
        )
    N = sum(len(y) for y, _ in series)
    lam = sse / max(N - orders.d, 1)
    scale = sum(float(y @ y) for y, _ in series)
    note = {}
    if sse <= EXACT_FIT * max(scale, 1e-300):
        # an exact fit: no noise to measure, and C and D are not identifiable from it
        cov = None
        note["note"] = "exact fit (noise-free data): noise model undetermined, no covariance"
    else:
        try:
            unit = np.sqrt(np.maximum(np.diag(H), 1e-300))  # equilibrate before inverting
            Hs = H / np.outer(unit, unit)
            if np.linalg.cond(Hs) > 1e12:
                warnings.warn(
                    f"{method.split()[0]}: the Hessian is nearly singular at the estimate, so "
                    "some parameters are barely identifiable and their covariance is unreliable "
                    "(near pole-zero cancellation: try lower orders)",
                    RwlabWarning,
                    stacklevel=3,
                )
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", linalg.LinAlgWarning)
                cov = lam * linalg.inv(Hs) / np.outer(unit, unit)
        except linalg.LinAlgError:
            raise EstimationError(
                "the Hessian is singular at the optimum: some parameters are not identifiable "
                "from these data (orders too high, or the input does not excite the system)"
            ) from None
        cov = (cov + cov.T) / 2
    if not np.all(np.isfinite(theta)):
        raise EstimationError("the search diverged; try lower orders or detrended data")
    A, B, C, D, F = orders.unpack(theta)
    first = experiments[0]
    model = PolyModel(
        A,
        B,
        C,
        D,
        F,
        Ts=first.Ts,
        nk=orders.nk,
        noise_variance=lam,
        covariance=cov,
        input_name=first.input_names[0],
        output_name=first.output_names[0],
    )
    model.report.update(
        estimation_report(
            model,
            experiments,
            method=method,
            loss=sse / N,
            iterations=iterations,
            termination=reason,
            initial_conditions="steady" if orders.steady else "zero",
            **note,
        )
    )
    return model


def armax(
    data: IOData | Sequence[IOData],
    na: int,
    nb: int,
    nc: int,
    nk: int = 1,
    *,
    max_iter: int = 100,
    tol: float = 1e-8,
    initial: str = "zero",
) -> PolyModel:
    """Estimate an ARMAX model ``A y = B u(t−nk) + C e`` (MATLAB ``armax(data,[na nb nc nk])``).

    Parameters
    ----------
    data : IOData or list of IOData
        SISO record(s).
    na, nb, nc, nk : int
        Orders of A, B, C (≥ 0; nb ≥ 1) and the input delay in samples.
    max_iter : int
        Maximum Levenberg–Marquardt iterations.
    tol : float
        Stop when the relative decrease of Σε² falls below this.
    initial : {'zero', 'steady'}
        Pre-sample values: zero (MATLAB ``InitialCondition='zero'``), or every
        signal held at its first sample (a record that starts at rest, in any
        units: use it for normalised or offset data).
    """
    orders = _Orders(
        check_order("na", na),
        check_order("nb", nb, 1),
        check_order("nc", nc),
        0,
        0,
        check_order("nk", nk),
        check_initial(initial, ESTIMATION_INITIAL) == "steady",
    )
    experiments, series = _prepare(data, orders)
    subset = _init_subset(series)
    starts = [_initial_armax(orders, subset)]
    if orders.na:  # also from the output-error dynamics: a start in another basin
        B, F = _initial_oe(orders.nb, orders.na, orders.nk, subset)
        C = np.concatenate([[1.0], np.zeros(orders.nc)])
        starts.append(orders.pack(F, B, C, np.ones(1), np.ones(1)))
    return _finish(
        orders, starts, experiments, series, "armax (prediction error, LM)", max_iter, tol
    )


def oe(
    data: IOData | Sequence[IOData],
    nb: int,
    nf: int,
    nk: int = 1,
    *,
    max_iter: int = 100,
    tol: float = 1e-8,
    initial: str = "zero",
) -> PolyModel:
    """Estimate an output-error model ``y = (B/F) u(t−nk) + e`` (MATLAB ``oe(data,[nb nf nk])``)."""
    orders = _Orders(
        0,
        check_order("nb", nb, 1),
        0,
        0,
        check_order("nf", nf),
        check_order("nk", nk),
        check_initial(initial, ESTIMATION_INITIAL) == "steady",
    )
    experiments, series = _prepare(data, orders)
    B, F = _initial_oe(orders.nb, orders.nf, orders.nk, _init_subset(series))
    theta0 = orders.pack(np.ones(1), B, np.ones(1), np.ones(1), F)
    return _finish(
        orders, [theta0], experiments, series, "oe (prediction error, LM)", max_iter, tol
    )


def bj(
    data: IOData | Sequence[IOData],
    nb: int,
    nc: int,
    nd: int,
    nf: int,
    nk: int = 1,
    *,
    max_iter: int = 100,
    tol: float = 1e-8,
    initial: str = "zero",
) -> PolyModel:
    """Estimate a Box–Jenkins model ``y = (B/F) u(t−nk) + (C/D) e`` (MATLAB ``bj``)."""
    orders = _Orders(
        0,
        check_order("nb", nb, 1),
        check_order("nc", nc),
        check_order("nd", nd),
        check_order("nf", nf),
        check_order("nk", nk),
        check_initial(initial, ESTIMATION_INITIAL) == "steady",
    )
    experiments, series = _prepare(data, orders)
    theta0 = _initial_bj(orders, _init_subset(series))
    return _finish(
        orders, [theta0], experiments, series, "bj (prediction error, LM)", max_iter, tol
    )


def pem(
    data: IOData | Sequence[IOData],
    init: PolyModel,
    *,
    max_iter: int = 100,
    tol: float = 1e-8,
    initial: str = "zero",
) -> PolyModel:
    """Refine any SISO ``PolyModel`` structure by prediction-error minimisation from ``init``.

    ``max_iter``, ``tol`` and ``initial`` as for :func:`armax`.
    """
    if init.nu != 1:
        raise DataError("pem refines single-input models")
    orders = _Orders(
        init.na,
        init.nb[0],
        init.nc,
        init.nd,
        init.nf,
        init.nk[0],
        check_initial(initial, ESTIMATION_INITIAL) == "steady",
    )
    experiments, series = _prepare(data, orders)
    theta0 = orders.pack(init.A, init.B, init.C, init.D, init.F)
    return _finish(
        orders, [theta0], experiments, series, "pem (prediction error, LM)", max_iter, tol
    )


class _CallableModule(types.ModuleType):
    """``rwlab.ident.pem`` is this module (``import rwlab.ident.pem`` reaches ``armax``, ``oe``,
    ...), and calling it calls the estimator :func:`pem`, MATLAB's name for both."""

    def __call__(self, data, init, **options) -> PolyModel:
        return pem(data, init, **options)

    __call__.__doc__ = pem.__doc__


sys.modules[__name__].__class__ = _CallableModule
