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
from instrumental variables with simulated-output instruments, from plain ARX,
and from ``RANDOM_STARTS`` random stable F's with B by least squares given
each (the output-error loss has local minima: a single start stopped in one
in about 1 % of 8-parameter OE fits at low signal-to-noise ratio, see
``bench/check_pem_optimum.py --oe-runs``). ARMAX is also
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

Why this module is long: ARMAX, OE and BJ share one prediction-error search (its
residual, Jacobian and step control); split by model, each part would re-state it.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
from scipy import linalg

from rwlab.data import IOData, as_experiments
from rwlab.errors import DataError, EstimationError, RwlabWarning
from rwlab.ident.arx import check_order
from rwlab.ident.gain_constraint import StaticGain
from rwlab.ident.models import PolyModel
from rwlab.ident.pem_starts import (
    Orders,
    as_columns,
    check_starts,
    dynamics_starts,
    initial_armax,
    initial_bj,
    initial_oe,
    input_orders,
    needs_input,
)
from rwlab.ident.polynomials import check_initial, filt, stabilize
from rwlab.ident.validation import estimation_report

__all__ = ["armax", "bj", "oe", "pem"]

START_SAMPLES = 10_000
RANDOM_STARTS = 6  # random stable F starts of oe and bj, besides the IV and ARX ones
SCREEN_ITER = 15  # iterations from each of many starts before the best is followed
MAX_ITER = "maximum iterations reached"
EXACT_FIT = 1e-24  # Σε² below this fraction of Σy²: the data are noise-free and fitted exactly
ESTIMATION_INITIAL = ("zero", "steady")  # what an estimator can assume before the record

Series = list[tuple[np.ndarray, np.ndarray]]  # (y of shape (N,), u of shape (N, nu)) per record
Fit = tuple[np.ndarray, np.ndarray, float, int, str]  # θ, ψᵀψ, Σε², iterations, why it stopped
InputOrders = int | Sequence[int]  # one per input, or one for every input


def _stabilized(orders: Orders, theta: np.ndarray, gain: StaticGain | None = None) -> np.ndarray:
    """Roots of C, D and F reflected inside the unit circle; back on ``gain``'s constraint
    (reflecting F's roots changes F(1))."""
    A, Bs, C, D, Fs = orders.unpack(theta)
    theta = orders.pack(A, Bs, stabilize(C), stabilize(D), [stabilize(F) for F in Fs])
    return theta if gain is None else gain.project(theta)


def _reduced(
    H: np.ndarray, g: np.ndarray, gain: StaticGain | None
) -> tuple[np.ndarray, np.ndarray]:
    """ψᵀψ and ψᵀε in the coordinates η the constraint leaves free (θ = θ₀ + Nη)."""
    if gain is None:
        return H, g
    N = gain.basis
    return N.T @ H @ N, N.T @ g


def _signals(
    orders: Orders, theta: np.ndarray, y: np.ndarray, u: np.ndarray
) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """ε, [wⱼ = (Bⱼ/Fⱼ) uⱼ] and v = A y − Σⱼ wⱼ for one experiment."""
    A, Bs, C, D, Fs = orders.unpack(theta)
    st = orders.steady
    u = as_columns(u)
    ws = [filt(B, F, u[:, j], st) for j, (B, F) in enumerate(zip(Bs, Fs, strict=True))]
    v = filt(A, [1.0], y, st) if orders.na else y
    for w in ws:
        v = v - w
    e = filt(D, C, v, st) if (orders.nc or orders.nd) else v
    return e, ws, v


def _sse(orders: Orders, theta: np.ndarray, experiments: Series) -> float:
    total = 0.0
    for y, u in experiments:
        e = _signals(orders, theta, y, u)[0]
        total += float(e @ e)
    return total


def _jacobian_block(
    orders: Orders,
    theta: np.ndarray,
    y: np.ndarray,
    u: np.ndarray,
    e: np.ndarray,
    ws: list[np.ndarray],
    v: np.ndarray,
) -> np.ndarray:
    """ψᵀ = (∂ε/∂θ)ᵀ for one experiment, shape (d, N): one contiguous row per parameter."""
    C, D, Fs = orders.unpack(theta)[2:]
    N = len(y)
    u = as_columns(u)
    psi_t = np.empty((orders.d, N))
    row = 0
    noise = orders.nc or orders.nd
    st = orders.steady

    def put(signal: np.ndarray, first_lag: int, count: int, sign: int) -> None:
        nonlocal row
        for i in range(count):
            k = min(first_lag + i, N)
            psi_t[row, :k] = signal[0] if (st and k and N) else 0.0
            psi_t[row, k:] = signal[: N - k]
            if sign < 0:
                psi_t[row] *= -1.0  # a contiguous row: safe in place
            row += 1

    def through_noise_and_f(x: np.ndarray, F: np.ndarray) -> np.ndarray:  # (D/(C F)) x
        return filt(D, np.convolve(C, F), x, st) if (noise or len(F) > 1) else x

    if orders.na:
        put(filt(D, C, y, st) if noise else y, 1, orders.na, +1)
    for j, (b, k) in enumerate(zip(orders.nb, orders.nk, strict=True)):
        if b:
            put(through_noise_and_f(u[:, j], Fs[j]), k, b, -1)
    if orders.nc:
        put(filt([1.0], C, e, st), 1, orders.nc, -1)
    if orders.nd:
        put(filt([1.0], C, v, st), 1, orders.nd, +1)
    for j, f in enumerate(orders.nf):
        if f:
            put(through_noise_and_f(ws[j], Fs[j]), 1, f, +1)
    return psi_t


def _normal_equations(
    orders: Orders, theta: np.ndarray, experiments: Series
) -> tuple[np.ndarray, np.ndarray, float]:
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


def _stalled(Hs: np.ndarray, gs: np.ndarray, sse: float, tol: float) -> str:
    """Why no step decreases the loss: the optimum itself (the Gauss–Newton step
    promises less than the tolerance: rounding is all that is left), or not."""
    try:
        promised = float(gs @ linalg.solve(Hs + 1e-12 * np.eye(len(gs)), gs, assume_a="pos"))
    except (linalg.LinAlgError, ValueError):
        promised = np.inf
    if promised / max(sse, 1e-300) < 10 * tol:
        return "converged (no step decreases the loss further)"
    return "no further decrease possible (local minimum)"


def _minimize(
    orders: Orders,
    theta: np.ndarray,
    experiments: Series,
    max_iter: int,
    tol: float,
    gain: StaticGain | None = None,
) -> Fit:
    """Levenberg–Marquardt on ½Σε² (on the free coordinates of ``gain``'s constraint,
    when given). Returns θ, H, sse, iterations, reason."""
    theta = _stabilized(orders, theta, gain)
    N = None if gain is None else gain.basis
    mu = 1e-4
    reason = MAX_ITER
    it = 0
    H, g, sse = _normal_equations(orders, theta, experiments)
    exact = EXACT_FIT * sum(float(y @ y) for y, _ in experiments)
    for it in range(1, max_iter + 1):
        if sse <= exact:
            reason = "converged (exact fit)"
            break
        Hr, gr = _reduced(H, g, gain)
        scale = np.sqrt(np.maximum(np.diag(Hr), 1e-300))
        Hs = Hr / np.outer(scale, scale)
        gs = gr / scale
        while True:
            try:
                step = -linalg.solve(Hs + mu * np.eye(len(gs)), gs, assume_a="pos") / scale
            except (linalg.LinAlgError, ValueError):
                step = None
            if step is not None:
                step = step if N is None else N @ step
                trial = _stabilized(orders, theta + step, gain)
                sse_trial = _sse(orders, trial, experiments)
                if sse_trial < sse:
                    break
            mu *= 10.0
            if mu > 1e12:
                return theta, H, sse, it, _stalled(Hs, gs, sse, tol)
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
def _prepare(
    data: IOData | Sequence[IOData], orders: Orders, what: str
) -> tuple[list[IOData], Series]:
    experiments = as_experiments(data)
    first = experiments[0]
    if first.ny != 1:
        raise DataError(f"{what} estimates single-output models; the data have {first.ny} outputs")
    if first.nu != orders.nu:
        raise DataError(f"{what}: the orders are for {orders.nu} inputs, the data have {first.nu}")
    N = sum(e.N for e in experiments)
    lags = [k + b for b, k in zip(orders.nb, orders.nk, strict=True)]
    needed = orders.d + max(orders.na, *lags, orders.nc, orders.nd, *orders.nf, 0) + 1
    if N < needed:
        raise DataError(
            f"too few samples: {N} for a model with {orders.d} parameters; need at least {needed}"
        )
    for j, b in enumerate(orders.nb):
        if b and all(np.ptp(e.u[:, j]) == 0 for e in experiments):
            raise EstimationError(
                f"input {first.input_names[j]!r} is constant: it is not persistently exciting, "
                "so B cannot be identified; use a PRBS, chirp or multisine input"
            )
    return experiments, [(e.y[:, 0], e.u) for e in experiments]


def _init_subset(series: Series) -> Series:
    return [(y[:START_SAMPLES], u[:START_SAMPLES]) for y, u in series]


def _search(
    orders: Orders,
    starts: Sequence[np.ndarray],
    series: Series,
    max_iter: int,
    tol: float,
    gain: StaticGain | None = None,
) -> Fit:
    """LM from every start on the first ``START_SAMPLES`` samples; the best, refined on all data.

    Several starts guard against local minima (ARMAX's likelihood has them);
    the short record makes each cheap, and from its optimum the full record
    needs only a step or two.
    """
    subset = _init_subset(series)
    whole = all(len(y) <= START_SAMPLES for y, _ in series)
    # many starts: a short search from each, then the best one's to convergence
    first = min(max_iter, SCREEN_ITER) if len(starts) > 2 else max_iter
    fits = [_minimize(orders, theta, subset, first, tol, gain) for theta in starts]
    best = min(fits, key=lambda fit: fit[2] if np.isfinite(fit[2]) else np.inf)
    if best[4] == MAX_ITER and first < max_iter:
        best = _minimize(orders, best[0], subset, max_iter, tol, gain)
    return best if whole else _minimize(orders, best[0], series, max_iter, tol, gain)


def _padded(rows: list[np.ndarray]) -> np.ndarray:
    """Rows of different lengths as one array, padded with trailing zeros."""
    out = np.zeros((len(rows), max([len(r) for r in rows] + [1])))
    for j, r in enumerate(rows):
        out[j, : len(r)] = r
    return out


def _finish(
    orders: Orders,
    starts: Sequence[np.ndarray],
    experiments: list[IOData],
    series: Series,
    method: str,
    max_iter: int,
    tol: float,
    gain: StaticGain | None = None,
) -> PolyModel:
    theta, H, sse, iterations, reason = _search(orders, starts, series, max_iter, tol, gain)
    if reason == MAX_ITER:
        warnings.warn(
            f"{method.split()[0]}: stopped after {iterations} iterations without converging; "
            "the model may not be the optimum (raise the iteration limit: max_iter, "
            "`rwlab ident ... --max-iter`; or check orders and data)",
            RwlabWarning,
            stacklevel=3,
        )
    N = sum(len(y) for y, _ in series)
    free = orders.d - (gain is not None)
    lam = sse / max(N - free, 1)
    basis = None if gain is None else gain.basis
    H = H if basis is None else basis.T @ H @ basis
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
            if basis is not None:  # back to θ: rank d − 1, the constrained sum has no variance
                cov = basis @ cov @ basis.T
        except linalg.LinAlgError:
            raise EstimationError(
                "the Hessian is singular at the optimum: some parameters are not identifiable "
                "from these data (orders too high, or the input does not excite the system)"
            ) from None
        cov = (cov + cov.T) / 2
    if not np.all(np.isfinite(theta)):
        raise EstimationError("the search diverged; try lower orders or detrended data")
    A, Bs, C, D, Fs = orders.unpack(theta)
    first = experiments[0]
    one = orders.nu == 1
    model = PolyModel(
        A,
        (Bs[0] if one else _padded(Bs)) if orders.nu else None,
        C,
        D,
        (Fs[0] if one else _padded(Fs)) if orders.nu else None,
        Ts=first.Ts,
        nk=orders.nk,
        nb=orders.nb,
        nf=orders.nf,
        noise_variance=lam,
        covariance=cov,
        input_name=first.input_names[0] if one else first.input_names,
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
            **({} if gain is None else {"dc_gain": float(gain.gain), "n_free": free}),
        )
    )
    return model


def _nu(data: IOData | Sequence[IOData]) -> int:
    return as_experiments(data)[0].nu


def armax(
    data: IOData | Sequence[IOData],
    na: int,
    nb: InputOrders | None = None,
    nc: int | None = None,
    nk: InputOrders = 1,
    *,
    max_iter: int = 100,
    tol: float = 1e-8,
    initial: str = "zero",
    dc_gain: float | None = None,
) -> PolyModel:
    """Estimate ``A y = Σⱼ Bⱼ uⱼ(t−nkⱼ) + C e`` (MATLAB ``armax(data,[na nb nc nk])``).

    With no input (a time series, ``IOData(None, y, Ts)``) this is the ARMA
    model ``A y = C e`` (MATLAB ``armax(data,[na nc])``): call
    ``armax(data, na, nc=nc)``.

    Parameters
    ----------
    data : IOData or list of IOData
        Single-output record(s), with any number of inputs (0 for a time series).
    na, nc : int
        Orders of A and C (≥ 0).
    nb : int or sequence of int
        Number of B coefficients per input (≥ 1); omit (or ``[]``) for a time series.
    nk : int or sequence of int
        Input delay in samples per input (default 1).
    max_iter : int
        Maximum Levenberg–Marquardt iterations.
    tol : float
        Stop when the relative decrease of Σε² falls below this.
    initial : {'zero', 'steady'}
        Pre-sample values: zero (MATLAB ``InitialCondition='zero'``), or every
        signal held at its first sample (a record that starts at rest, in any
        units: use it for normalised or offset data).
    dc_gain : float, optional
        A known static gain K (single input): the search keeps ``B(1) = K·A(1)·F(1)``
        exactly, on the d − 1 free coordinates (:mod:`rwlab.ident.gain_constraint`;
        beyond MATLAB). Also for :func:`oe` and :func:`bj`.

    Returns
    -------
    PolyModel
        With ``noise_variance`` = Σε²/(N − d) and covariance λ (ψᵀψ)⁻¹; with
        ``dc_gain``, Σε²/(N − d + 1), the constrained covariance (rank d − 1) and
        ``report['dc_gain']``.
    """
    nu = _nu(data)
    if nc is None:
        raise DataError("armax needs nc, the order of C (armax(data, na, nb, nc, nk))")
    nb = input_orders("nb", nb, nu, 1)
    orders = Orders(
        check_order("na", na),
        nb,
        check_order("nc", nc),
        0,
        (0,) * nu,
        input_orders("nk", nk if nu else None, nu, 0),
        check_initial(initial, ESTIMATION_INITIAL) == "steady",
    )
    gain = StaticGain.of(dc_gain, orders)
    experiments, series = _prepare(data, orders, "armax")
    subset = _init_subset(series)
    starts = [initial_armax(orders, subset)]
    if orders.na and orders.nu:  # also from the output-error dynamics: a start in another basin
        Bs, F = initial_oe(orders.nb, orders.na, orders.nk, subset)
        C = np.concatenate([[1.0], np.zeros(orders.nc)])
        starts.append(orders.pack(F, Bs, C, np.ones(1), [np.ones(1)] * orders.nu))
    return _finish(orders, starts, experiments, series, _method("armax", gain), max_iter, tol, gain)


def _method(name: str, gain: StaticGain | None) -> str:
    extra = "" if gain is None else ", static gain constrained"
    return f"{name} (prediction error, LM{extra})"


def oe(
    data: IOData | Sequence[IOData],
    nb: InputOrders,
    nf: InputOrders,
    nk: InputOrders = 1,
    *,
    max_iter: int = 100,
    tol: float = 1e-8,
    initial: str = "zero",
    starts: int = RANDOM_STARTS,
    dc_gain: float | None = None,
) -> PolyModel:
    """Estimate ``y = Σⱼ (Bⱼ/Fⱼ) uⱼ(t−nkⱼ) + e`` (MATLAB ``oe(data,[nb nf nk])``).

    ``nb`` (≥ 1), ``nf`` and ``nk`` are one value per input, or one for all
    (MATLAB's order vectors); ``max_iter``, ``tol``, ``initial`` as for
    :func:`armax`. ``starts`` (≥ 0) random stable F's, with B by least squares
    given each, are searched besides the instrumental-variable and ARX starts;
    the lowest loss wins (the output-error loss has local minima).

    Parameters
    ----------
    data : IOData or sequence of IOData
        Estimation record(s).
    nb, nf : int or sequence of int
        Orders of B (≥ 1) and F, per input.
    nk : int or sequence of int
        Input delay, samples, per input.
    max_iter, tol, initial, dc_gain
        As for :func:`armax`.
    starts : int
        Random stable starts besides the instrumental-variable and ARX ones (≥ 0).

    Returns
    -------
    PolyModel
        The output-error model with its covariance and estimation report.
    """
    nu = _nu(data)
    needs_input("oe", nu)
    orders = Orders(
        0,
        input_orders("nb", nb, nu, 1),
        0,
        0,
        input_orders("nf", nf, nu, 0),
        input_orders("nk", nk, nu, 0),
        check_initial(initial, ESTIMATION_INITIAL) == "steady",
    )
    gain = StaticGain.of(dc_gain, orders)
    experiments, series = _prepare(data, orders, "oe")
    thetas = [
        orders.pack(np.ones(1), Bs, np.ones(1), np.ones(1), Fs)
        for Bs, Fs in dynamics_starts(orders, _init_subset(series), check_starts(starts))
    ]
    return _finish(orders, thetas, experiments, series, _method("oe", gain), max_iter, tol, gain)


def bj(
    data: IOData | Sequence[IOData],
    nb: InputOrders,
    nc: int,
    nd: int,
    nf: InputOrders,
    nk: InputOrders = 1,
    *,
    max_iter: int = 100,
    tol: float = 1e-8,
    initial: str = "zero",
    starts: int = RANDOM_STARTS,
    dc_gain: float | None = None,
) -> PolyModel:
    """Estimate ``y = Σⱼ (Bⱼ/Fⱼ) uⱼ(t−nkⱼ) + (C/D) e`` (MATLAB ``bj(data,[nb nc nd nf nk])``).

    ``nb``, ``nf``, ``nk`` and ``starts`` as for :func:`oe` (the noise model of
    each start by Hannan–Rissanen on its output error); other options as for
    :func:`armax`.

    Parameters
    ----------
    data : IOData or sequence of IOData
        Estimation record(s).
    nb, nf : int or sequence of int
        Orders of B and F, per input.
    nc, nd : int
        Orders of the noise model's C and D.
    nk : int or sequence of int
        Input delay, samples, per input.
    max_iter, tol, initial, starts, dc_gain
        As for :func:`oe` and :func:`armax`.

    Returns
    -------
    PolyModel
        The Box–Jenkins model with its covariance and estimation report.
    """
    nu = _nu(data)
    needs_input("bj", nu)
    orders = Orders(
        0,
        input_orders("nb", nb, nu, 1),
        check_order("nc", nc),
        check_order("nd", nd),
        input_orders("nf", nf, nu, 0),
        input_orders("nk", nk, nu, 0),
        check_initial(initial, ESTIMATION_INITIAL) == "steady",
    )
    gain = StaticGain.of(dc_gain, orders)
    experiments, series = _prepare(data, orders, "bj")
    subset = _init_subset(series)
    thetas = [
        initial_bj(orders, subset, dynamics)
        for dynamics in dynamics_starts(orders, subset, check_starts(starts))
    ]
    return _finish(orders, thetas, experiments, series, _method("bj", gain), max_iter, tol, gain)


def pem(
    data: IOData | Sequence[IOData],
    init: PolyModel,
    *,
    max_iter: int = 100,
    tol: float = 1e-8,
    initial: str = "zero",
) -> PolyModel:
    """Refine any ``PolyModel`` structure by prediction-error minimisation from ``init``.

    ``max_iter``, ``tol`` and ``initial`` as for :func:`armax`.

    Parameters
    ----------
    data : IOData or sequence of IOData
        Estimation record(s).
    init : PolyModel
        Initial model; its structure (orders, delays) is kept.
    max_iter, tol, initial
        As for :func:`armax`.

    Returns
    -------
    PolyModel
        The refined model with its covariance and estimation report.
    """
    nu = init.nu
    orders = Orders(
        init.na,
        tuple(init.nb),
        init.nc,
        init.nd,
        tuple(init._nf),
        tuple(init.nk),
        check_initial(initial, ESTIMATION_INITIAL) == "steady",
    )
    if nu and min(orders.nb) < 1:
        raise DataError("pem needs at least one B coefficient per input")
    experiments, series = _prepare(data, orders, "pem")
    return _finish(
        orders, [init.parameters], experiments, series, "pem (prediction error, LM)", max_iter, tol
    )
