"""Nonlinear block-oriented model: a rate-limited tracking loop with input and output limits.

A linear model cannot follow a system whose output rate saturates (a reaction
wheel's acceleration limit shapes almost every PRBS transition). This module
estimates a block-oriented model whose linear part and limits are fitted
together from the data, by simulation error (one-step prediction hides the
saturation: the measured output carries it into the predictor).

Structure ``"servo"`` — a Lur'e (feedback block) model, equations per sample
``k`` (Ts), integrated with ``M`` sub-steps of ``h = Ts/M``; ``sat`` clips to the
input limits, ``clip_α`` to ±α, the output clip to the output limits::

    r_old = g·sat(u[k−1]) + c,   r_new = g·sat(u[k]) + c
    for j = 0..M−1:
        f = clip((τ − j·h)/h, 0, 1)          share of the sub-step still on u[k−1]
        e = f·r_old + (1 − f)·r_new − w
        z = kp·e + I
        if |z| < α:  I ← I + ki·e·h           (integrate only when unsaturated)
        w ← clip_out(w + h·clip_α(z))
    y[k+1] = w

Input saturation → static gain g and offset c → PI law → rate limit α → integrator
→ output limit: the linear part is ``g (kp s + ki)/(s² + kp s + ki)`` with the
input delay τ (0 ≤ τ < Ts, on top of the one sample between a command and the
next measurement). With α = ∞ it is exactly linear, so the fit starts from the
linear model's two slowest poles and DC gain. It is the model of any tracking
loop with a rate limit and conditional-integration anti-windup (a wheel's speed
loop, a servo actuator, a valve positioner).

A Hammerstein–Wiener form (input saturation → linear → output rate limit, the
limit outside the dynamics) was tried first and is the structure
``IdentifiedWheel`` flew before this model: on the simulated RW90's PRBS it
gains only ~1 point of fit over ARX221, because the linear block keeps
integrating while the output is held at the rate limit. ``bench/bench_nonlinear.py``
reports both.

No library estimates this structure (sysidentpy's NARMAX is polynomial; it is
compared against in the benchmark), so the simulation is written here and
compiled with numba; the fit is ``scipy.optimize.least_squares``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from typing import TypeVar

import numpy as np
from numba import njit
from scipy.optimize import OptimizeResult, least_squares

from rwlab.data import IOData
from rwlab.errors import DataError, EstimationError, ModelError
from rwlab.ident.models import PolyModel

T = TypeVar("T")
R = TypeVar("R")

__all__ = ["ServoModel", "load_kernels", "servo_advance", "servo_fit"]

STRUCTURE = "servo"
INITIAL = ("steady", "estimate")
DELAY_STARTS = (0.1, 0.25, 0.5)  # the delay's starting values, shares of Ts


@njit(cache=True, nogil=True)
def servo_advance(
    w: float, integral: float, u_prev: float, u: float, p: np.ndarray
) -> tuple[float, float]:
    """One sample of the servo model: ``(w, I, u[k−1], u[k]) → (w, I)`` at the next sample.

    The model's simulation (``IdentifiedWheel.step`` and the fit call it; the fit's
    finite differences run the same sub-steps, :func:`_substep`, side by side). ``p`` =
    (g, c, kp, ki, α, τ, Ts, substeps, u_lo, u_hi, y_lo, y_hi), float64 array of shape (12,).
    """
    m = int(p[7])
    h = p[6] / m
    r_old, r_new = _reference(u_prev, p), _reference(u, p)
    for j in range(m):
        f = _share(p[5], j, h)
        w, integral = _substep(w, integral, r_old, r_new, f, p[2], p[3], p[4], h, p[10], p[11])
    return w, integral


@njit(cache=True, nogil=True)
def _reference(u: float, p: np.ndarray) -> float:
    """The loop's reference for the input ``u``: g·sat(u) + c."""
    return p[0] * min(max(u, p[8]), p[9]) + p[1]


@njit(cache=True, nogil=True)
def _share(tau: float, j: int, h: float) -> float:
    """f: the share of sub-step ``j`` (of length ``h``) still on the previous input."""
    return min(max((tau - j * h) / h, 0.0), 1.0)


@njit(cache=True, nogil=True)
def _substep(
    w: float,
    integral: float,
    r_old: float,
    r_new: float,
    f: float,
    kp: float,
    ki: float,
    alpha: float,
    h: float,
    lo: float,
    hi: float,
) -> tuple[float, float]:
    """One sub-step (the module docstring's loop body): ``(w, I)`` after it."""
    e = f * r_old + (1.0 - f) * r_new - w
    z = kp * e + integral
    if abs(z) < alpha:
        integral += ki * e * h
    return min(max(w + h * min(max(z, -alpha), alpha), lo), hi), integral


@njit(cache=True, nogil=True)  # nogil: the fit's starts run in threads
def _simulate(u: np.ndarray, w0: float, i0: float, p: np.ndarray) -> np.ndarray:
    n = u.size
    y = np.empty(n)
    w, integral = w0, i0
    y[0] = w
    for k in range(n - 1):
        w, integral = servo_advance(w, integral, u[k - 1] if k else u[0], u[k], p)
        y[k + 1] = w
    return y


@njit(cache=True, nogil=True)
def _simulate_many(u: np.ndarray, w0: float, i0: float, P: np.ndarray) -> np.ndarray:
    """:func:`_simulate` for each row of ``P`` (K, 12), shape (K, N): the rows' sub-steps
    interleaved, so that K independent chains of arithmetic fill the processor's pipeline
    (one simulation waits on each sub-step's result). Every row's numbers are its own
    simulation's, operation for operation. The rows share Ts and the sub-step count."""
    K, n = P.shape[0], u.size
    m = int(P[0, 7])
    h = P[0, 6] / m
    Q = np.ascontiguousarray(P.T)  # parameter by parameter: Q[i] holds every row's p[i]
    Y = np.empty((K, n))
    w, integral = np.full(K, w0), np.full(K, i0)
    r_old, r_new = np.empty(K), np.empty(K)
    Y[:, 0] = w0
    for k in range(n - 1):
        for q in range(K):
            r_old[q] = _reference(u[k - 1] if k else u[0], P[q])
            r_new[q] = _reference(u[k], P[q])
        for j in range(m):
            for q in range(K):
                f = _share(Q[5, q], j, h)
                w[q], integral[q] = _substep(
                    w[q], integral[q], r_old[q], r_new[q], f,
                    Q[2, q], Q[3, q], Q[4, q], h, Q[10, q], Q[11, q],
                )  # fmt: skip
        Y[:, k + 1] = w
    return Y


def load_kernels() -> None:
    """Load the servo fit's compiled simulation now (from numba's cache, else compiled).

    A process's first compiled call also starts numba itself (≈ 0.2 s, measured): a
    process that waits for its work (``rwlab identify``'s figure child) pays it first.
    """
    p = np.array([1.0, 0.0, 1.0, 1.0, 1.0, 0.0, 1.0, 1.0, -np.inf, np.inf, -np.inf, np.inf])
    _simulate(np.zeros(2), 0.0, 0.0, p)
    _simulate_many(np.zeros(2), 0.0, 0.0, p[None, :].copy())


@dataclass(frozen=True)
class ServoModel:
    """A rate-limited tracking loop (structure ``"servo"``, equations in the module docstring).

    Attributes
    ----------
    Ts : float
        Sample time, s.
    gain, offset : float
        Reference ``r = gain·sat(u) + offset``, output units per input unit and output units.
    kp, ki : float
        PI law on the tracking error, 1/s and 1/s².
    rate_limit : float
        α, the largest output rate, output units per second.
    delay : float
        τ, input delay within the sample, s (0 ≤ τ < Ts).
    input_limits, output_limits : tuple of float
        Saturations (lo, hi), in input and output units (±inf: none).
    substeps : int
        Integration sub-steps per sample.
    """

    Ts: float
    gain: float
    offset: float
    kp: float
    ki: float
    rate_limit: float
    delay: float = 0.0
    input_limits: tuple[float, float] = (-math.inf, math.inf)
    output_limits: tuple[float, float] = (-math.inf, math.inf)
    substeps: int = 100

    nu = 1
    structure = STRUCTURE

    def __post_init__(self) -> None:
        values = [self.Ts, self.gain, self.offset, self.kp, self.ki, self.rate_limit, self.delay]
        if not all(math.isfinite(float(v)) for v in values):
            raise ModelError(f"servo model parameters must be finite, got {values}")
        if self.Ts <= 0 or self.kp <= 0 or self.ki < 0 or self.rate_limit <= 0:
            raise ModelError("a servo model needs Ts > 0, kp > 0, ki ≥ 0 and rate_limit > 0")
        if not 0 <= self.delay < self.Ts:
            raise ModelError(f"delay must lie in [0, Ts), got {self.delay} s")
        for name in ("input_limits", "output_limits"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ModelError(f"{name} must be (lo, hi) with lo < hi, got {(lo, hi)}")
        if int(self.substeps) != self.substeps or self.substeps < 1:
            raise ModelError(f"substeps must be a positive integer, got {self.substeps}")

    @property
    def vector(self) -> np.ndarray:
        """The parameter vector ``servo_advance`` takes, shape (12,)."""
        return np.array(
            [
                self.gain,
                self.offset,
                self.kp,
                self.ki,
                self.rate_limit,
                self.delay,
                self.Ts,
                self.substeps,
                *self.input_limits,
                *self.output_limits,
            ],
            dtype=float,
        )

    @property
    def n_params(self) -> int:
        """Estimated parameters: g, c, kp, ki, α, τ."""
        return 6

    def simulate(self, u: np.ndarray, w0: float, integral0: float = 0.0) -> np.ndarray:
        """Output from the state (w0, I0) at sample 0 for inputs ``u`` (N,); returns (N,)."""
        u = np.array(u, dtype=float).ravel()
        if u.size == 0 or not np.all(np.isfinite(u)):
            raise DataError("u must be a non-empty finite sequence")
        return _simulate(u, float(w0), float(integral0), self.vector)

    def initial_state(self, data: IOData, initial: str = "steady") -> tuple[float, float]:
        """(w0, I0): at rest at the first output ('steady') or fitted to the output ('estimate')."""
        if initial not in INITIAL:
            raise DataError(f"initial must be one of {INITIAL}, got {initial!r}")
        u, y = _siso(data)
        if initial == "steady":
            return float(y[0]), 0.0
        p = self.vector
        scale = max(float(np.std(y)), 1e-12)
        sol = least_squares(
            lambda s: (_simulate(u, s[0], s[1], p) - y) / scale,
            [y[0], 0.0],
            x_scale=[scale, self.rate_limit],
        )
        return float(sol.x[0]), float(sol.x[1])

    def predict(self, data: IOData, horizon: float = np.inf, initial: str = "steady") -> np.ndarray:
        """Simulated output on ``data``, shape (N,).

        An output-error model predicts by simulating at every horizon (its noise
        model is 1), so ``compare`` and ``resid`` score the simulation error.
        """
        if horizon != np.inf and (int(horizon) != horizon or horizon < 1):
            raise DataError(f"horizon must be a positive integer or inf, got {horizon}")
        w0, i0 = self.initial_state(data, initial)
        return self.simulate(data.u[:, 0], w0, i0)

    def to_dict(self) -> dict:
        """Plain JSON (infinite limits as null)."""
        d = asdict(self)
        for name in ("input_limits", "output_limits"):
            d[name] = [None if math.isinf(v) else v for v in d[name]]
        return {"structure": STRUCTURE, **d}

    @classmethod
    def from_dict(cls, d: dict) -> ServoModel:
        """Inverse of ``to_dict``."""
        if d.get("structure") != STRUCTURE:
            raise ModelError(f"not a servo model: structure {d.get('structure')!r}")
        kw = {k: v for k, v in d.items() if k != "structure"}
        for name, inf in (("input_limits", math.inf), ("output_limits", math.inf)):
            lo, hi = kw.get(name, (None, None))
            kw[name] = (-inf if lo is None else float(lo), inf if hi is None else float(hi))
        try:
            return cls(**kw)
        except TypeError as exc:
            raise ModelError(f"bad servo model fields: {exc}") from None


def _siso(data: IOData) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(data, IOData) or data.nu != 1 or data.ny != 1:
        raise DataError("the servo model needs a single-input single-output IOData")
    return data.u[:, 0].copy(), data.y[:, 0].copy()


def _initial_guess(linear: PolyModel | None, data: IOData) -> tuple[float, float, float, float]:
    """(g, c, kp, ki) from a linear PolyModel on the same data, or from the data alone."""
    u, y = _siso(data)
    if linear is None:
        g, c = np.polyfit(u, y, 1)
        return float(g), float(c), 2.0 / data.Ts, 0.5 / data.Ts**2
    if linear.nu != 1 or not linear.is_stable():
        raise EstimationError("the servo fit starts from a stable single-input linear model")
    g = float(linear.dc_gain())
    # the operating point: the linear model's steady output is g·u around the data's means
    c = float(np.mean(y) - g * np.mean(u))
    s = np.log(np.asarray(linear.poles(), dtype=complex)) / linear.Ts
    slow = s[np.argsort(-s.real)][:2]
    if slow.size < 2:
        return g, c, float(-slow[0].real), 0.0
    return g, c, float(-(slow[0] + slow[1]).real), float((slow[0] * slow[1]).real)


def _pair(bounds: tuple[float, float]) -> tuple[float, float]:
    lo, hi = bounds  # a list from a caller or a TOML file becomes the model's tuple
    return float(lo), float(hi)


def in_threads(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(item) for item in items]``, each call in a thread of its own: independent
    starts of a fit whose compiled simulation releases the GIL run side by side on a
    machine's cores, and give the same results as one after the other.

    Parameters
    ----------
    fn : callable
        ``fn(item)``; it must not share mutable state between calls.
    items : iterable
        The arguments.

    Returns
    -------
    list
        ``fn(item)`` for each item, in order.
    """
    todo = list(items)
    if len(todo) < 2 or (os.cpu_count() or 1) < 2:
        return [fn(item) for item in todo]
    with ThreadPoolExecutor(max_workers=len(todo)) as pool:
        return list(pool.map(fn, todo))


def servo_fit(
    data: IOData,
    linear: PolyModel | None = None,
    *,
    input_limits: tuple[float, float] = (-math.inf, math.inf),
    output_limits: tuple[float, float] = (-math.inf, math.inf),
    substeps: int = 100,
) -> ServoModel:
    """Estimate the servo model by simulation error, starting from a linear model.

    Parameters
    ----------
    data : IOData
        Estimation data in physical units (SISO); the record should start at
        rest (the fit uses the 'steady' initial state).
    linear : PolyModel, optional
        A linear model of ``data`` (same units): its DC gain and two slowest
        poles start the fit. Without one, a line fit of y on u and slow poles.
    input_limits, output_limits : (lo, hi)
        Known saturations; not estimated (a record that never reaches them
        cannot tell where they are).
    substeps : int
        Integration sub-steps per sample.

    Returns
    -------
    ServoModel
        α, the PI gains, the gain, offset and delay as estimated. The rate
        limit starts at the largest output change per second in ``data``; the
        delay at each of :data:`DELAY_STARTS` (shares of Ts), the fit of least
        cost kept.
    """
    u, y = _siso(data)
    if data.N < 20:
        raise DataError(f"the servo fit needs at least 20 samples, got {data.N}")
    Ts = data.Ts
    slope = np.abs(np.diff(y)) / Ts
    if not np.any(slope > 0):
        raise DataError("the output never changes: nothing to fit")
    g0, c0, kp0, ki0 = _initial_guess(linear, data)
    x0 = np.array([g0, c0, max(kp0, 1e-3 / Ts), max(ki0, 0.0), float(slope.max()), 0.25 * Ts])
    lower = [-np.inf, -np.inf, 1e-6 / Ts, 0.0, 1e-9 * float(slope.max()), 0.0]
    upper = [np.inf, np.inf, np.inf, np.inf, np.inf, 0.999 * Ts]
    x0 = np.clip(x0, lower, upper)
    fixed = np.array([Ts, substeps, *input_limits, *output_limits], dtype=float)
    scale = float(np.std(y)) or 1.0

    def residuals(x: np.ndarray) -> np.ndarray:
        p = np.concatenate([x, fixed[:2], fixed[2:]])
        return (_simulate(u, y[0], 0.0, p) - y) / scale

    typical = np.abs(x0) + np.array([abs(g0) or 1.0, scale, 1.0 / Ts, 1.0 / Ts**2, 1.0, Ts]) * 1e-3

    # the delay makes the cost multimodal (it trades against the rate limit and the
    # offset): a single start at 0.25·Ts settled on one twin unit at 16× the best cost
    # (delay 0.17 s, offset +2.9 rpm, rate limit 315.5 rpm/s), a model that then raised
    # false speed-bias alarms on 10 of 11 healthy chirps; the best of several starts is kept
    def side_by_side(_fun: object, points: Iterable[np.ndarray]) -> list[np.ndarray]:
        """``map(residuals, points)`` for the finite-difference Jacobian (scipy's
        ``workers`` hook hands it its wrapper of ``residuals``): the perturbed parameter
        vectors simulated together (:func:`_simulate_many`), the same numbers."""
        P = np.array([np.concatenate([x, fixed]) for x in points])
        return list((_simulate_many(u, y[0], 0.0, P) - y) / scale)

    def start(share: float) -> OptimizeResult:
        x = x0.copy()
        x[5] = share * Ts
        return least_squares(
            residuals, x, bounds=(lower, upper), x_scale=typical, workers=side_by_side
        )

    fits = in_threads(start, DELAY_STARTS)  # the simulation releases the GIL
    sol = min(fits, key=lambda f: f.cost if np.all(np.isfinite(f.x)) else math.inf)
    if not np.all(np.isfinite(sol.x)):
        raise EstimationError("the servo fit diverged; check the data and the linear model")
    g, c, kp, ki, alpha, tau = (float(v) for v in sol.x)
    return ServoModel(
        Ts,
        g,
        c,
        kp,
        ki,
        alpha,
        tau,
        _pair(input_limits),
        _pair(output_limits),
        int(substeps),
    )
