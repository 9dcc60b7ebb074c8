"""The detector protocol: one fault model each, a registry by fault name.

As python-can's ``BusABC`` with its interface registry, every detector is a
subclass of :class:`Detector` that registers itself under its fault's name
(:data:`REGISTRY`, :func:`detector`); the pipeline knows detectors only
through this interface.

A model-based detector is one fault's model in the residual channels: for a
candidate size θ it predicts each channel's residual p(θ) per sample, and the
log-likelihood gain of θ over the healthy wheel at sample k is

    ℓ_k(θ) = Σ_channels w_k · (r_k·p_k(θ) − p_k(θ)²/2),   w = 1/(σ²κ)

(Gaussian residuals of the measured noise model, :mod:`~rwlab.diagnose.noise`).
Summed over a window it is the window's log-likelihood ratio; its maximum over
θ the generalised likelihood ratio (GLR), θ̂ the maximum-likelihood size, and
{θ : ℓ(θ̂) − ℓ(θ) ≤ χ²₁(0.95)/2} the profile-likelihood 95 % interval. Because
every fault's ℓ is on the same samples and channels, the sizes of different
faults compare by likelihood: that is the isolation
(:mod:`~rwlab.diagnose.isolation`).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.stats import chi2

from rwlab.diagnose.features import Features
from rwlab.errors import ConfigError

__all__ = ["REGISTRY", "Detector", "Fit", "crossing", "detector", "profile_fit"]

HALF_CHI2_95 = float(chi2.ppf(0.95, 1)) / 2  # 1.92: the profile likelihood's 95 % drop
# Huber's constant for 95 % efficiency at the normal (Huber 1964; textbook, not tuned)
HUBER_C = 1.345

REGISTRY: dict[str, type[Detector]] = {}


@dataclass(frozen=True)
class Fit:
    """One fault model fitted on a window.

    Attributes
    ----------
    fault : str
        The fault's name (:data:`rwlab.wheel.faults.FAULTS`).
    size : float
        Maximum-likelihood size, in ``unit``.
    ci95 : tuple of 2 float
        Profile-likelihood 95 % interval (a bound at the grid's edge is that edge).
    log_lr : float
        Log-likelihood ratio of the fitted size over the nearest healthy size.
    unit : str
    """

    fault: str
    size: float
    ci95: tuple[float, float]
    log_lr: float
    unit: str

    def size_text(self) -> str:
        """The size and its interval as a console line shows them.

        Returns
        -------
        str
            '×2.01 [1.89, 2.15]' for a factor, '0.49 A [0.45, 0.52]' for a size in a
            unit; empty for a fault with no size (a frozen reading).
        """
        if math.isnan(self.size):
            return ""
        (lo, hi), x = self.ci95, "×" if self.unit == "factor" else ""
        unit = "" if x else f" {self.unit}"
        return f"{x}{self.size:.3g}{unit} [{lo:.3g}, {hi:.3g}]"


def profile_fit(
    fault: str,
    unit: str,
    grid: np.ndarray,
    ll: np.ndarray,
    healthy: np.ndarray,
    dispersion: float = 1.0,
    worse: int = 0,
) -> Fit:
    """The GLR fit of one window from its log-likelihood over the grid.

    Parameters
    ----------
    fault, unit : str
    grid : numpy.ndarray, shape (G,)
        Candidate sizes, increasing.
    ll : numpy.ndarray, shape (G,)
        Log-likelihood gain of each size over the reference wheel.
    healthy : numpy.ndarray of bool, shape (G,)
        The sizes a healthy wheel may have (the zone).
    dispersion : float
        φ ≥ 1: the interval is the quasi-likelihood's, ll/φ (the model's misfit
        measured on healthy records); the log-LR stays the likelihood's, so the
        faults' log-LRs compare on one scale.
    worse : {1, -1, 0}
        The side of the zone a fault takes the size to (+1: up, −1: down, 0: either):
        the sizes on the other side are no fault and are not fitted (a one-sided GLR).

    Returns
    -------
    Fit
    """
    any_healthy = healthy.any()
    if worse and any_healthy:
        edge = grid[healthy].min() if worse > 0 else grid[healthy].max()
        ll = np.where(worse * (grid - edge) >= 0, ll, -np.inf)
    # (array methods, not numpy's functions: the same reductions without their wrappers;
    # a calibration fits ~10⁴ windows)
    top_ll = float(ll.max())
    tied = (ll >= top_ll - 1e-9).nonzero()[0]  # a flat top (a clamp never reached): the
    centre = float(grid[healthy].mean()) if any_healthy else float(grid[0])
    best = int(tied[np.abs(grid[tied] - centre).argmin()])  # size nearest the healthy
    cut = ll[best] - HALF_CHI2_95 * dispersion
    inside = (ll >= cut).nonzero()[0]
    top = float(ll[best])
    zone = float(ll[healthy].max()) if any_healthy else 0.0
    return Fit(
        fault,
        float(grid[best]),
        (
            crossing(grid, ll, top, cut, inside[0], -1),
            crossing(grid, ll, top, cut, inside[-1], 1),
        ),
        max(0.0, top - zone),
        unit,
    )


def crossing(grid: np.ndarray, ll: np.ndarray, top: float, cut: float, i: int, step: int) -> float:
    """Where the log-likelihood falls to ``cut`` between grid point i (inside) and its
    neighbour on the ``step`` side: the signed root √(2(top − ll)) interpolated linearly,
    exact for a quadratic profile (ll itself, interpolated, put the end inside the true one,
    up to 7× too narrow where a window pins the size within one grid step; before, the grid
    point, a zero-width interval); the grid's edge where the likelihood never falls that
    far.

    Parameters
    ----------
    grid : numpy.ndarray, shape (G,)
        Candidate sizes, increasing.
    ll : numpy.ndarray, shape (G,)
        Log-likelihood over the grid.
    top : float
        The profile's top, ll's largest value.
    cut : float
        The level whose crossing is sought (≤ ``top``).
    i : int
        A grid index where ll ≥ ``cut``.
    step : {1, -1}
        The side to look on.

    Returns
    -------
    float
        The size where ll crosses ``cut``, in the grid's unit.
    """
    j = i + step
    if not 0 <= j < len(grid) or not np.isfinite(ll[j]):
        return float(grid[i])
    root_i, root_j, root_cut = (math.sqrt(2.0 * max(top - v, 0.0)) for v in (ll[i], ll[j], cut))
    share = (root_cut - root_i) / (root_j - root_i)
    return float(grid[i] + share * (grid[j] - grid[i]))


class Detector(ABC):
    """One fault's model in the residual channels (module docstring).

    Subclasses set ``fault`` (the registry key), ``unit`` and ``healthy_size`` and
    give the candidate sizes and the per-sample log-likelihood gains.
    """

    fault: ClassVar[str]
    unit: ClassVar[str]
    healthy_size: ClassVar[float]
    # the side of the healthy zone the fault takes the size to (a fault makes a wheel
    # worse): +1 up, −1 down, 0 either (:func:`profile_fit`)
    worse: ClassVar[int] = 0
    # the record's own reference (:meth:`Features.own`) fits the unit's whole law on this
    # detector's channel: against it a healthy unit sits at the healthy size
    own_law: ClassVar[bool] = False
    # the detector reads the reach at the acceleration limit (:meth:`limit_gains`)
    reads_limit: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        if getattr(cls, "fault", None):
            REGISTRY[cls.fault] = cls

    @abstractmethod
    def grid(self, features: Features) -> np.ndarray:
        """Candidate sizes, increasing, shape (G,), in ``unit``."""

    @abstractmethod
    def gains(
        self, features: Features, weights: dict[str, np.ndarray], grid: np.ndarray
    ) -> np.ndarray:
        """Per-sample log-likelihood gain of each size over the healthy wheel, shape (N, G).

        Parameters
        ----------
        features : Features
        weights : dict of str to numpy.ndarray
            1/(σ²κ) per channel and sample (:meth:`NoiseModel.weights`).
        grid : numpy.ndarray, shape (G,)
        """

    def limit_gains(
        self, features: Features, weights: dict[str, np.ndarray], grid: np.ndarray
    ) -> np.ndarray | None:
        """Against the record's own past, the per-sample gains read at the acceleration
        limit against the unit's own reach there (``Features.limit_reference``,
        whose reference lags ``LIMIT_REFERENCE_LAG_S``), shape (N, G); None (the
        default): the detector reads none.

        Parameters
        ----------
        features : Features
            Against the own past (``Features.own(law=True)``).
        weights : dict of str to numpy.ndarray
        grid : numpy.ndarray, shape (G,)

        Returns
        -------
        numpy.ndarray or None
        """
        return None

    def refine(
        self,
        features: Features,
        weights: dict[str, np.ndarray],
        fit: Fit,
        a: int,
        k: int,
    ) -> Fit:
        """The size and interval of ``fit`` (this detector's on samples [a, k)) read again
        where its gains mix evidence that does not measure the size; as it is by default.

        Parameters
        ----------
        features : Features
        weights : dict of str to numpy.ndarray
        fit : Fit
            The window's GLR fit.
        a, k : int
            The window's first and past-the-last samples.

        Returns
        -------
        Fit
        """
        return fit

    @staticmethod
    def shortfall(
        features: Features,
        clamp_a: np.ndarray,
        torque_factor: np.ndarray | float = 1.0,
        friction_factor: np.ndarray | float = 1.0,
    ) -> np.ndarray:
        """The acceleration residual the driver's limits make, rpm/s, shape (N, G).

        Below its acceleration limit the loop's integrator makes up a lost torque or added
        friction until the driver's current clamp binds: the wheel falls short only where
        it would need more than L, reaching c₀·α = ±F_k·L − c₃ − F_f·friction current
        (current-balance units). At the limit the loop's request is capped and its
        integrator holds (anti-windup): the driver gives the current a healthy wheel needs
        for the limit, i = c₀·α_limit + friction current + c₃, clamped at ±L, and the wheel
        reaches c₀·α = F_k·(i − c₃) − F_f·friction current: short of the limit for a weak
        motor or worn bearings, beyond it for a stronger motor.

        Parameters
        ----------
        features : Features
        clamp_a : float or numpy.ndarray, shape (G,)
            The driver's current clamp L, A.
        torque_factor : float or numpy.ndarray, shape (G,)
            The motor's torque constant over the healthy one, F_k.
        friction_factor : float or numpy.ndarray, shape (G,)
            The bearings' friction over the healthy one, F_f.

        Returns
        -------
        numpy.ndarray, shape (N, G)
            Measured less demanded acceleration the limits make, rpm/s (0 where none binds).
        """
        c0, _, _, c3 = features.scales.current_model
        demand = features.demand_accel_rpm_s[:, None]
        friction = np.asarray(friction_factor) * features.friction_current_a[:, None]
        torque = np.asarray(torque_factor)
        clamp = np.asarray(clamp_a)
        d = np.sign(demand)
        reach = (d * torque * clamp - c3 - friction) / c0
        below = np.where(d * demand > d * reach, reach - demand, 0.0)
        healthy = features.friction_current_a[:, None]
        asked = c0 * demand + healthy  # the current a healthy wheel needs, less c₃
        cut = np.clip(asked + c3, -clamp, clamp) - c3 - asked  # what the clamp takes off it
        # (torque·(asked + cut) − friction)/c₀ − demand, written so that it is exactly 0
        # where neither factor differs from 1 and the clamp cuts nothing: the clamp's test
        # of where it binds (``!= 0``) read rounding (~1e-13 rpm/s) as binding on every
        # sample of an acceleration-mode record
        at_limit = ((torque - 1.0) * asked + (healthy - friction) + torque * cut) / c0
        return np.where(features.saturated[:, None], at_limit, below)

    @staticmethod
    def level_cost(miss: np.ndarray, w: np.ndarray) -> np.ndarray:
        """−w·ρ(miss): what a reading off the level a fault holds it at costs, shape of ``miss``.

        Parameters
        ----------
        miss : numpy.ndarray, shape (N, G)
            The reading less the level, per sample and candidate size.
        w : numpy.ndarray, shape (N,)
            1/σ² of the reading (0: the sample is not read).

        Returns
        -------
        numpy.ndarray, shape (N, G)
            ρ is Huber's loss at ``HUBER_C`` σ, as in :meth:`channel_gain`.
        """
        w = w[:, None]
        return -w * _huber(miss, HUBER_C / np.sqrt(np.where(w > 0, w, np.inf)))

    @staticmethod
    def channel_gain(r: np.ndarray, w: np.ndarray, p: np.ndarray) -> np.ndarray:
        """w·(ρ(r) − ρ(r − p)) for residuals r, weights w (N,) and predictions p (N, G).

        ρ is Huber's loss at ``HUBER_C`` inflated σ (σ√κ = 1/√w): w·(r·p − p²/2), the
        Gaussian log-LR, where both r and r − p lie within it, linear beyond. One
        sample the noise model misjudges (a slew's entry, a reversal) then adds at most
        ``HUBER_C``·|p|·√w to a window, not (r·p)·w: on healthy twin records single
        samples gave a weak motor a log-LR of 860 and so a threshold that blinded it.

        Parameters
        ----------
        r : numpy.ndarray, shape (N,)
            A channel's residuals.
        w : numpy.ndarray, shape (N,)
            Their weights 1/(σ²κ) (0: the sample is not read).
        p : numpy.ndarray, shape (N, G) or broadcastable to it
            The residual each candidate size predicts.

        Returns
        -------
        numpy.ndarray, shape (N, G)
            Each sample's log-likelihood gain of each size over the healthy wheel.
        """
        # a sample of weight 0, or whose row of predictions is all 0, gains exactly 0 (with
        # finite r, w and p): Huber's loss is evaluated on the other rows only (a steady-speed
        # channel weighs about half the samples, a clamp binds on few); the same numbers
        n = r.shape[0]
        p = np.broadcast_to(p, np.broadcast_shapes((n, 1), np.shape(p)))
        out = np.zeros(p.shape)
        finite = np.isfinite(r) & np.isfinite(w)
        moved = np.any(p != 0, axis=1)
        rows = (moved & (w != 0)) | ~finite
        unweighted = moved & (w == 0) & finite
        if unweighted.any():  # 0·(ρ(r) − ρ(r − p)) is 0 unless p is not finite
            rows[unweighted] = ~np.isfinite(p[unweighted]).all(axis=1)
        if not rows.any():
            return out
        w, r = w[rows], r[rows]
        scale = HUBER_C / np.sqrt(np.where(w > 0, w, np.inf))[:, None]
        out[rows] = w[:, None] * (_huber(r[:, None], scale) - _huber(r[:, None] - p[rows], scale))
        return out


def _huber(x: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Huber's loss ρ_c(x): x²/2 for |x| ≤ c, c·|x| − c²/2 beyond."""
    a = np.abs(x)
    return np.where(a <= c, 0.5 * x * x, c * a - 0.5 * c * c)


def detector(fault: str) -> Detector:
    """The registered detector of a fault.

    Parameters
    ----------
    fault : str

    Returns
    -------
    Detector

    Raises
    ------
    ConfigError
        No detector for that fault.
    """
    if fault not in REGISTRY:
        raise ConfigError(f"no detector for {fault!r}; known: {', '.join(sorted(REGISTRY))}")
    return REGISTRY[fault]()
