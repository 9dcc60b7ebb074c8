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
"""

from __future__ import annotations

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
RANDOM_STARTS = 6  # random stable F starts of oe and bj, besides the IV and ARX ones
MAX_ITER = "maximum iterations reached"
EXACT_FIT = 1e-24  # Σε² below this fraction of Σy²: the data are noise-free and fitted exactly
ESTIMATION_INITIAL = ("zero", "steady")  # what an estimator can assume before the record


def _per_input_tuple(value, nu: int) -> tuple[int, ...]:
    values = np.atleast_1d(np.asarray(value, dtype=int)).tolist()
    return tuple(values * nu if len(values) == 1 and nu != 1 else values)


@dataclass(frozen=True)
class _Orders:
    """Orders of ``A y = Σⱼ (Bⱼ/Fⱼ) uⱼ(t−nkⱼ) + (C/D) e``; nb, nf, nk per input.

    An int for nb, nf or nk means one input (nb) or the same for every input (nf, nk);
    ``nb=()`` means no input (a time series).
    """

    na: int
    nb: tuple[int, ...]
    nc: int
    nd: int
    nf: tuple[int, ...]
    nk: tuple[int, ...]
    steady: bool = False  # pre-sample values: zero, or each signal's first value

    def __post_init__(self):
        nb = tuple(int(b) for b in np.atleast_1d(self.nb))
        object.__setattr__(self, "nb", nb)
        for name in ("nf", "nk"):
            values = _per_input_tuple(getattr(self, name), len(nb))
            if len(values) != len(nb):
                raise DataError(f"{name} needs one value per input ({len(nb)}), got {values}")
            object.__setattr__(self, name, values)

    @property
    def nu(self) -> int:
        return len(self.nb)

    @property
    def d(self) -> int:
        return self.na + sum(self.nb) + self.nc + self.nd + sum(self.nf)

    def unpack(self, theta: np.ndarray):
        """θ → (A, [B₁ …], C, D, [F₁ …]) polynomials in q⁻¹."""
        pos = 0

        def take(n: int) -> np.ndarray:
            nonlocal pos
            pos += n
            return theta[pos - n : pos]

        A = np.concatenate([[1.0], take(self.na)])
        Bs = [np.concatenate([np.zeros(k), take(b)]) for b, k in zip(self.nb, self.nk, strict=True)]
        C = np.concatenate([[1.0], take(self.nc)])
        D = np.concatenate([[1.0], take(self.nd)])
        Fs = [np.concatenate([[1.0], take(f)]) for f in self.nf]
        return A, Bs, C, D, Fs

    def pack(self, A, Bs, C, D, Fs) -> np.ndarray:
        bs = [B[k : k + b] for B, b, k in zip(Bs, self.nb, self.nk, strict=True)]
        fs = [F[1 : f + 1] for F, f in zip(Fs, self.nf, strict=True)]
        return np.concatenate([A[1 : self.na + 1], *bs, C[1:], D[1:], *fs])


def _stabilized(orders: _Orders, theta: np.ndarray) -> np.ndarray:
    A, Bs, C, D, Fs = orders.unpack(theta)
    return orders.pack(A, Bs, stabilize(C), stabilize(D), [stabilize(F) for F in Fs])


def _columns(u: np.ndarray) -> np.ndarray:
    """Inputs as an (N, nu) array (a 1-D u is one input)."""
    return u[:, None] if u.ndim == 1 else u


def _signals(orders: _Orders, theta, y, u):
    """ε, [wⱼ = (Bⱼ/Fⱼ) uⱼ] and v = A y − Σⱼ wⱼ for one experiment."""
    A, Bs, C, D, Fs = orders.unpack(theta)
    st = orders.steady
    u = _columns(u)
    ws = [filt(B, F, u[:, j], st) for j, (B, F) in enumerate(zip(Bs, Fs, strict=True))]
    v = filt(A, [1.0], y, st) if orders.na else y
    for w in ws:
        v = v - w
    e = filt(D, C, v, st) if (orders.nc or orders.nd) else v
    return e, ws, v


def _sse(orders, theta, experiments) -> float:
    total = 0.0
    for y, u in experiments:
        e = _signals(orders, theta, y, u)[0]
        total += float(e @ e)
    return total


def _jacobian_block(orders: _Orders, theta, y, u, e, ws, v) -> np.ndarray:
    """ψᵀ = (∂ε/∂θ)ᵀ for one experiment, shape (d, N): one contiguous row per parameter."""
    C, D, Fs = orders.unpack(theta)[2:]
    N = len(y)
    u = _columns(u)
    psi_t = np.empty((orders.d, N))
    row = 0
    noise = orders.nc or orders.nd
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

    def through_noise_and_f(x, F):  # (D/(C F)) x
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


def _stalled(Hs, gs, sse: float, tol: float) -> str:
    """Why no step decreases the loss: the optimum itself (the Gauss–Newton step
    promises less than the tolerance: rounding is all that is left), or not."""
    try:
        promised = float(gs @ linalg.solve(Hs + 1e-12 * np.eye(len(gs)), gs, assume_a="pos"))
    except (linalg.LinAlgError, ValueError):
        promised = np.inf
    if promised / max(sse, 1e-300) < 10 * tol:
        return "converged (no step decreases the loss further)"
    return "no further decrease possible (local minimum)"


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


def _input_lags(u: np.ndarray, nb, nk, n0: int) -> list[np.ndarray]:
    """Lagged columns uⱼ(t−nkⱼ−i), i < nbⱼ, of every input, rows t = n0..N−1."""
    u = _columns(u)
    return [
        c for j, (b, k) in enumerate(zip(nb, nk, strict=True)) for c in _lags(u[:, j], k, b, n0)
    ]


def _first_row(nb, nk, *others: int) -> int:
    return max([*others, *[k + b - 1 for b, k in zip(nb, nk, strict=True)], 0])


def _split_b(th: np.ndarray, nb, nk) -> list[np.ndarray]:
    """Consecutive coefficient blocks of θ → one B per input, with nk leading zeros."""
    out, pos = [], 0
    for b, k in zip(nb, nk, strict=True):
        out.append(np.concatenate([np.zeros(k), th[pos : pos + b]]))
        pos += b
    return out


def _initial_armax(orders: _Orders, experiments) -> np.ndarray:
    """Hannan–Rissanen: long ARX residuals ê, then y on lags of y, u and ê."""
    na, nb, nc, nk = orders.na, orders.nb, orders.nc, orders.nk
    long = max(10, 2 * (na + nc), na + max(nb, default=0))
    longs = (long,) * orders.nu
    cols_all, targets = [], []
    for y, u in experiments:
        n0 = _first_row(longs, nk, long)
        th = _least_squares(
            [-c for c in _lags(y, 1, long, n0)] + _input_lags(u, longs, nk, n0), y[n0:]
        )
        ehat = np.convolve(y, np.concatenate([[1.0], th[:long]]))[: len(y)]
        for j, B in enumerate(_split_b(th[long:], longs, nk)):
            ehat = ehat - np.convolve(_columns(u)[:, j], B)[: len(y)]
        n0 = max(_first_row(longs, nk, long), _first_row(nb, nk, na, nc))
        cols = (
            [-c for c in _lags(y, 1, na, n0)] + _input_lags(u, nb, nk, n0) + _lags(ehat, 1, nc, n0)
        )
        cols_all.append(np.column_stack(cols))
        targets.append(y[n0:])
    th = _least_squares(list(np.vstack(cols_all).T), np.concatenate(targets))
    A = np.concatenate([[1.0], th[:na]])
    Bs = _split_b(th[na:], nb, nk)
    C = stabilize(np.concatenate([[1.0], th[na + sum(nb) :]]))
    return orders.pack(A, Bs, C, np.ones(1), [np.ones(1)] * orders.nu)


def _initial_oe(nb, nf: int, nk, experiments, iterations: int = 3):
    """Bⱼ and a common F by ARX(nf, nb, nk), then instrumental variables with simulated
    instruments. Returns ([B₁ …], F)."""
    nb, nk = tuple(np.atleast_1d(nb)), tuple(np.atleast_1d(nk))
    n0 = _first_row(nb, nk, nf)

    def regress(instrumented: bool, Bs, F):
        Phi, Z, T = [], [], []
        for y, u in experiments:
            inputs = _input_lags(u, nb, nk, n0)
            Phi.append(np.column_stack([-c for c in _lags(y, 1, nf, n0)] + inputs))
            T.append(y[n0:])
            if instrumented:
                x = sum(sps.lfilter(B, F, _columns(u)[:, j]) for j, B in enumerate(Bs))
                Z.append(np.column_stack([-c for c in _lags(x, 1, nf, n0)] + inputs))
        Phi, T = np.vstack(Phi), np.concatenate(T)
        if not instrumented:
            return _least_squares(list(Phi.T), T)
        Z = np.vstack(Z)
        return np.linalg.lstsq(Z.T @ Phi, Z.T @ T, rcond=None)[0]

    th = regress(False, None, None)
    for i in range(iterations + 1):
        F = stabilize(np.concatenate([[1.0], th[:nf]]))
        Bs = _split_b(th[nf:], nb, nk)
        if i < iterations:
            th = regress(True, Bs, F)
    return Bs, F


def _initial_dynamics(orders: _Orders, experiments, sweeps: int = 2):
    """Bⱼ and Fⱼ per input: one input at a time on the output less the other inputs'
    simulated contributions (backfitting), each by :func:`_initial_oe`."""
    if orders.nu == 1:
        Bs, F = _initial_oe(orders.nb, orders.nf[0], orders.nk, experiments)
        return Bs, [F]
    Bs = [np.zeros(k + b) for b, k in zip(orders.nb, orders.nk, strict=True)]
    Fs = [np.ones(1)] * orders.nu
    for _ in range(sweeps):
        for j in range(orders.nu):
            parts = []
            for y, u in experiments:
                u = _columns(u)
                others = sum(sps.lfilter(Bs[i], Fs[i], u[:, i]) for i in range(orders.nu) if i != j)
                parts.append((y - others, u[:, j]))
            (Bs[j],), Fs[j] = _initial_oe(orders.nb[j], orders.nf[j], orders.nk[j], parts)
    return Bs, Fs


def _simulated(Bs, Fs, u) -> np.ndarray:
    u = _columns(u)
    return sum(
        (sps.lfilter(B, F, u[:, j]) for j, (B, F) in enumerate(zip(Bs, Fs, strict=True))),
        np.zeros(len(u)),
    )


def _initial_bj(orders: _Orders, experiments, dynamics=None) -> np.ndarray:
    Bs, Fs = _initial_dynamics(orders, experiments) if dynamics is None else dynamics
    v = np.concatenate([y - _simulated(Bs, Fs, u) for y, u in experiments])
    C, D = _arma_hannan_rissanen(v, orders.nc, orders.nd)
    return orders.pack(np.ones(1), Bs, C, D, Fs)


def _random_monic(rng: np.random.Generator, n: int) -> np.ndarray:
    """A monic polynomial of degree n with random roots inside radius 0.95
    (complex pairs and real roots equally likely)."""
    roots: list[complex] = []
    while len(roots) < n:
        if n - len(roots) >= 2 and rng.random() < 0.5:
            z = np.sqrt(rng.uniform(0.0, 0.95**2)) * np.exp(1j * rng.uniform(0, np.pi))
            roots += [z, np.conj(z)]
        else:
            roots.append(rng.uniform(-0.95, 0.95))
    return np.real(np.poly(roots)) if n else np.ones(1)


def _b_given_f(orders: _Orders, Fs, experiments) -> list[np.ndarray]:
    """Bⱼ by least squares once the Fⱼ are fixed: y is linear in B given F."""
    cols_all, targets = [], []
    for y, u in experiments:
        u = _columns(u)
        n0 = _first_row(orders.nb, orders.nk)
        filtered = np.column_stack([sps.lfilter([1.0], F, u[:, j]) for j, F in enumerate(Fs)])
        cols_all.append(np.column_stack(_input_lags(filtered, orders.nb, orders.nk, n0)))
        targets.append(y[n0:])
    th = _least_squares(list(np.vstack(cols_all).T), np.concatenate(targets))
    return _split_b(th, orders.nb, orders.nk)


def _dynamics_starts(orders: _Orders, experiments, count: int) -> list[tuple[list, list]]:
    """Starting (B, F) pairs for OE and BJ: instrumental variables, plain ARX, and
    ``count`` random stable Fⱼ with Bⱼ by least squares given them.

    The output-error loss has local minima (a resonance fitted by the wrong
    pole pair); one start stops in one of them about once in a hundred
    records at low signal-to-noise ratio. The random generator is seeded
    with a constant, so estimates are reproducible.
    """
    starts = [_initial_dynamics(orders, experiments)]
    if orders.nu == 1:
        n0 = _first_row(orders.nb, orders.nk, orders.nf[0])
        cols, targets = [], []
        for y, u in experiments:
            lags = [-c for c in _lags(y, 1, orders.nf[0], n0)]
            cols.append(np.column_stack(lags + _input_lags(u, orders.nb, orders.nk, n0)))
            targets.append(y[n0:])
        th = _least_squares(list(np.vstack(cols).T), np.concatenate(targets))
        F = stabilize(np.concatenate([[1.0], th[: orders.nf[0]]]))
        starts.append((_split_b(th[orders.nf[0] :], orders.nb, orders.nk), [F]))
    rng = np.random.default_rng(20240522)
    for _ in range(count if any(orders.nf) else 0):
        Fs = [_random_monic(rng, f) for f in orders.nf]
        try:
            starts.append((_b_given_f(orders, Fs, experiments), Fs))
        except (linalg.LinAlgError, ValueError):
            continue
    return starts


# -- public estimators ---------------------------------------------------------------
def _input_orders(name: str, value, nu: int, minimum: int) -> tuple[int, ...]:
    """One order per input (MATLAB's order vectors); a scalar applies to every input."""
    if nu == 0:
        if value is None or (isinstance(value, Sequence) and len(value) == 0):
            return ()
        raise DataError(
            f"the data have no input (a time series), so {name} must be omitted or []; "
            "an ARMA model is armax(data, na, nc=...)"
        )
    if value is None:
        raise DataError(f"{name} is required: the data have {nu} input(s)")
    values = list(value) if isinstance(value, Sequence) else [value] * nu
    if len(values) != nu:
        raise DataError(f"{name} needs one value per input ({nu}), got {values}")
    return tuple(check_order(name, v, minimum) for v in values)


def _prepare(data, orders: _Orders, what: str):
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


def _padded(rows: list[np.ndarray]) -> np.ndarray:
    """Rows of different lengths as one array, padded with trailing zeros."""
    out = np.zeros((len(rows), max([len(r) for r in rows] + [1])))
    for j, r in enumerate(rows):
        out[j, : len(r)] = r
    return out


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
        )
    )
    return model


def _nu(data) -> int:
    return as_experiments(data)[0].nu


def armax(
    data: IOData | Sequence[IOData],
    na: int,
    nb=None,
    nc: int | None = None,
    nk=1,
    *,
    max_iter: int = 100,
    tol: float = 1e-8,
    initial: str = "zero",
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

    Returns
    -------
    PolyModel
        With ``noise_variance`` = Σε²/(N − d) and covariance λ (ψᵀψ)⁻¹.
    """
    nu = _nu(data)
    if nc is None:
        raise DataError("armax needs nc, the order of C (armax(data, na, nb, nc, nk))")
    nb = _input_orders("nb", nb, nu, 1)
    orders = _Orders(
        check_order("na", na),
        nb,
        check_order("nc", nc),
        0,
        (0,) * nu,
        _input_orders("nk", nk if nu else None, nu, 0),
        check_initial(initial, ESTIMATION_INITIAL) == "steady",
    )
    experiments, series = _prepare(data, orders, "armax")
    subset = _init_subset(series)
    starts = [_initial_armax(orders, subset)]
    if orders.na and orders.nu:  # also from the output-error dynamics: a start in another basin
        Bs, F = _initial_oe(orders.nb, orders.na, orders.nk, subset)
        C = np.concatenate([[1.0], np.zeros(orders.nc)])
        starts.append(orders.pack(F, Bs, C, np.ones(1), [np.ones(1)] * orders.nu))
    return _finish(
        orders, starts, experiments, series, "armax (prediction error, LM)", max_iter, tol
    )


def _check_starts(starts) -> int:
    if isinstance(starts, bool) or not isinstance(starts, (int, np.integer)) or starts < 0:
        raise DataError(f"starts must be a non-negative integer, got {starts!r}")
    return int(starts)


def _needs_input(what: str, nu: int) -> None:
    if nu == 0:
        raise DataError(f"{what} needs an input; for a time series use ar, arx or armax")


def oe(
    data: IOData | Sequence[IOData],
    nb,
    nf,
    nk=1,
    *,
    max_iter: int = 100,
    tol: float = 1e-8,
    initial: str = "zero",
    starts: int = RANDOM_STARTS,
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
    max_iter, tol, initial
        As for :func:`armax`.
    starts : int
        Random stable starts besides the instrumental-variable and ARX ones (≥ 0).

    Returns
    -------
    PolyModel
        The output-error model with its covariance and estimation report.
    """
    nu = _nu(data)
    _needs_input("oe", nu)
    orders = _Orders(
        0,
        _input_orders("nb", nb, nu, 1),
        0,
        0,
        _input_orders("nf", nf, nu, 0),
        _input_orders("nk", nk, nu, 0),
        check_initial(initial, ESTIMATION_INITIAL) == "steady",
    )
    experiments, series = _prepare(data, orders, "oe")
    thetas = [
        orders.pack(np.ones(1), Bs, np.ones(1), np.ones(1), Fs)
        for Bs, Fs in _dynamics_starts(orders, _init_subset(series), _check_starts(starts))
    ]
    return _finish(orders, thetas, experiments, series, "oe (prediction error, LM)", max_iter, tol)


def bj(
    data: IOData | Sequence[IOData],
    nb,
    nc: int,
    nd: int,
    nf,
    nk=1,
    *,
    max_iter: int = 100,
    tol: float = 1e-8,
    initial: str = "zero",
    starts: int = RANDOM_STARTS,
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
    max_iter, tol, initial, starts
        As for :func:`oe` and :func:`armax`.

    Returns
    -------
    PolyModel
        The Box–Jenkins model with its covariance and estimation report.
    """
    nu = _nu(data)
    _needs_input("bj", nu)
    orders = _Orders(
        0,
        _input_orders("nb", nb, nu, 1),
        check_order("nc", nc),
        check_order("nd", nd),
        _input_orders("nf", nf, nu, 0),
        _input_orders("nk", nk, nu, 0),
        check_initial(initial, ESTIMATION_INITIAL) == "steady",
    )
    experiments, series = _prepare(data, orders, "bj")
    subset = _init_subset(series)
    thetas = [
        _initial_bj(orders, subset, dynamics)
        for dynamics in _dynamics_starts(orders, subset, _check_starts(starts))
    ]
    return _finish(orders, thetas, experiments, series, "bj (prediction error, LM)", max_iter, tol)


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
    orders = _Orders(
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
