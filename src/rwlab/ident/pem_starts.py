"""The model structure of the prediction-error estimators and the starting values of
their search (``rwlab.ident.pem``).

ARMAX and BJ noise models from the Hannan–Rissanen two-stage least squares
(long ARX → residuals → linear regression); OE and BJ dynamics from
instrumental variables with simulated-output instruments, from plain ARX, and
from random stable F's with B by least squares given each. They only need to
land in the basin of the optimum; ``pem`` searches from all of them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import linalg
from scipy import signal as sps

from rwlab.errors import DataError
from rwlab.ident.arx import check_order
from rwlab.ident.polynomials import stabilize

Series = Sequence[tuple[np.ndarray, np.ndarray]]  # (y of shape (N,), u of (N, nu) or (N,)) each
Dynamics = tuple[list[np.ndarray], list[np.ndarray]]  # ([B₁ …], [F₁ …]), one pair per input


def _per_input_tuple(value: int | Sequence[int], nu: int) -> tuple[int, ...]:
    values = np.atleast_1d(np.asarray(value, dtype=int)).tolist()
    return tuple(values * nu if len(values) == 1 and nu != 1 else values)


@dataclass(frozen=True)
class Orders:
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

    def __post_init__(self) -> None:
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

    def unpack(
        self, theta: np.ndarray
    ) -> tuple[np.ndarray, list[np.ndarray], np.ndarray, np.ndarray, list[np.ndarray]]:
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

    def pack(
        self,
        A: np.ndarray,
        Bs: Sequence[np.ndarray],
        C: np.ndarray,
        D: np.ndarray,
        Fs: Sequence[np.ndarray],
    ) -> np.ndarray:
        bs = [B[k : k + b] for B, b, k in zip(Bs, self.nb, self.nk, strict=True)]
        fs = [F[1 : f + 1] for F, f in zip(Fs, self.nf, strict=True)]
        return np.concatenate([A[1 : self.na + 1], *bs, C[1:], D[1:], *fs])


def as_columns(u: np.ndarray) -> np.ndarray:
    """Inputs as an (N, nu) array (a 1-D u is one input)."""
    return u[:, None] if u.ndim == 1 else u


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


def _input_lags(u: np.ndarray, nb: Sequence[int], nk: Sequence[int], n0: int) -> list[np.ndarray]:
    """Lagged columns uⱼ(t−nkⱼ−i), i < nbⱼ, of every input, rows t = n0..N−1."""
    u = as_columns(u)
    return [
        c for j, (b, k) in enumerate(zip(nb, nk, strict=True)) for c in _lags(u[:, j], k, b, n0)
    ]


def _first_row(nb: Sequence[int], nk: Sequence[int], *others: int) -> int:
    return max([*others, *[k + b - 1 for b, k in zip(nb, nk, strict=True)], 0])


def _split_b(th: np.ndarray, nb: Sequence[int], nk: Sequence[int]) -> list[np.ndarray]:
    """Consecutive coefficient blocks of θ → one B per input, with nk leading zeros."""
    out, pos = [], 0
    for b, k in zip(nb, nk, strict=True):
        out.append(np.concatenate([np.zeros(k), th[pos : pos + b]]))
        pos += b
    return out


def initial_armax(orders: Orders, experiments: Series) -> np.ndarray:
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
            ehat = ehat - np.convolve(as_columns(u)[:, j], B)[: len(y)]
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


def initial_oe(
    nb: int | Sequence[int],
    nf: int,
    nk: int | Sequence[int],
    experiments: Series,
    iterations: int = 3,
) -> tuple[list[np.ndarray], np.ndarray]:
    """Bⱼ and a common F by ARX(nf, nb, nk), then instrumental variables with simulated
    instruments. Returns ([B₁ …], F)."""
    nb, nk = tuple(np.atleast_1d(nb)), tuple(np.atleast_1d(nk))
    n0 = _first_row(nb, nk, nf)

    def regress(instruments: tuple[list[np.ndarray], np.ndarray] | None) -> np.ndarray:
        """ARX by least squares (no instruments), or IV with the outputs that ([B₁ …], F)
        simulate as instruments."""
        Phi, Z, T = [], [], []
        for y, u in experiments:
            inputs = _input_lags(u, nb, nk, n0)
            Phi.append(np.column_stack([-c for c in _lags(y, 1, nf, n0)] + inputs))
            T.append(y[n0:])
            if instruments is not None:
                Bs, F = instruments
                x = _simulated(Bs, [F] * len(Bs), u)
                Z.append(np.column_stack([-c for c in _lags(x, 1, nf, n0)] + inputs))
        phi, target = np.vstack(Phi), np.concatenate(T)
        if instruments is None:
            return _least_squares(list(phi.T), target)
        z = np.vstack(Z)
        return np.linalg.lstsq(z.T @ phi, z.T @ target, rcond=None)[0]

    th = regress(None)
    for i in range(iterations + 1):
        F = stabilize(np.concatenate([[1.0], th[:nf]]))
        Bs = _split_b(th[nf:], nb, nk)
        if i < iterations:
            th = regress((Bs, F))
    return Bs, F


def _initial_dynamics(orders: Orders, experiments: Series, sweeps: int = 2) -> Dynamics:
    """Bⱼ and Fⱼ per input: one input at a time on the output less the other inputs'
    simulated contributions (backfitting), each by :func:`initial_oe`."""
    if orders.nu == 1:
        Bs, F = initial_oe(orders.nb, orders.nf[0], orders.nk, experiments)
        return Bs, [F]
    Bs = [np.zeros(k + b) for b, k in zip(orders.nb, orders.nk, strict=True)]
    Fs = [np.ones(1)] * orders.nu
    for _ in range(sweeps):
        for j in range(orders.nu):
            parts = []
            for y, u in experiments:
                u = as_columns(u)
                others = sum(sps.lfilter(Bs[i], Fs[i], u[:, i]) for i in range(orders.nu) if i != j)
                parts.append((y - others, u[:, j]))
            (Bs[j],), Fs[j] = initial_oe(orders.nb[j], orders.nf[j], orders.nk[j], parts)
    return Bs, Fs


def _simulated(Bs: Sequence[np.ndarray], Fs: Sequence[np.ndarray], u: np.ndarray) -> np.ndarray:
    u = as_columns(u)
    return sum(
        (sps.lfilter(B, F, u[:, j]) for j, (B, F) in enumerate(zip(Bs, Fs, strict=True))),
        np.zeros(len(u)),
    )


def initial_bj(orders: Orders, experiments: Series, dynamics: Dynamics | None = None) -> np.ndarray:
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


def _b_given_f(orders: Orders, Fs: Sequence[np.ndarray], experiments: Series) -> list[np.ndarray]:
    """Bⱼ by least squares once the Fⱼ are fixed: y is linear in B given F."""
    cols_all, targets = [], []
    for y, u in experiments:
        u = as_columns(u)
        n0 = _first_row(orders.nb, orders.nk)
        filtered = np.column_stack([sps.lfilter([1.0], F, u[:, j]) for j, F in enumerate(Fs)])
        cols_all.append(np.column_stack(_input_lags(filtered, orders.nb, orders.nk, n0)))
        targets.append(y[n0:])
    th = _least_squares(list(np.vstack(cols_all).T), np.concatenate(targets))
    return _split_b(th, orders.nb, orders.nk)


def dynamics_starts(orders: Orders, experiments: Series, count: int) -> list[Dynamics]:
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


# -- order checks of the estimators -----------------------------------------------
def input_orders(
    name: str, value: int | Sequence[int] | None, nu: int, minimum: int
) -> tuple[int, ...]:
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


def check_starts(starts: object) -> int:
    if isinstance(starts, bool) or not isinstance(starts, (int, np.integer)) or starts < 0:
        raise DataError(f"starts must be a non-negative integer, got {starts!r}")
    return int(starts)


def needs_input(what: str, nu: int) -> None:
    if nu == 0:
        raise DataError(f"{what} needs an input; for a time series use ar, arx or armax")
