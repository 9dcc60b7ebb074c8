"""The ECSS-E-ST-60-10C pointing error indices of one run, and the requirement they answer.

Per body axis, over the run's steady window (t ≥ the window's start) of the
logged trace, with e(t) the pointing error (the rotation vector of the true
attitude relative to the target) and k(t) the knowledge error (the estimate's
error, 2 (q ⊗ q̂⁻¹)_v), each per run:

- APE, absolute performance error: max |e(t)|;
- MPE, mean performance error: |mean of e| over the window;
- RPE, relative performance error: max |e(t) − mean of e over the window of
  ``rpe_window_s`` centred on t|;
- PDE, performance drift error: max |mean of e over [t, t + Δ) − mean of e over
  [t + Δs, t + Δs + Δ)|, Δ = ``drift_window_s``, Δs = ``drift_separation_s``
  (None when the window is shorter than Δ + Δs);
- AKE, MKE, KDE: the same for k as APE, MPE and PDE (absolute, mean and drift
  knowledge errors).

For the statistical interpretations (see :mod:`rwlab.campaign.budget`) each run
also gives, for the total error |e|: the fraction of its steady time within the
requirement and the ``probability``-quantile of |e| over its steady time. And
how the run converged: the time it first came within the requirement (acquired), the
time after which it stayed within it (settled: after a later miss, the miss's end), and
the time every σ the filter logs (attitude, and rate or gyro bias) first came
within 1.5× of its median over the run's second half.

Everything here comes from the logged trace (``SimResult`` rows): content
faster than the logging interval is not seen (the total APE, from every step,
is the kernel's ``steady_max_error_deg``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rwlab.errors import ConfigError

__all__ = ["AXES", "COLUMNS", "INTERPRETATIONS", "PointingRequirement", "run_indices"]

AXES = ("x", "y", "z")
#: Each index's ``results.parquet`` column, ``{}`` the axis (APE and AKE keep the names of
#: earlier versions).
COLUMNS = {
    "APE": "steady_max_error_{}_deg",
    "MPE": "mpe_{}_deg",
    "RPE": "rpe_{}_deg",
    "PDE": "pde_{}_deg",
    "AKE": "knowledge_error_{}_deg",
    "MKE": "mke_{}_deg",
    "KDE": "kde_{}_deg",
}
INTERPRETATIONS = ("ensemble", "temporal", "mixed")
FILTER_SETTLED = 1.5  # σ within this factor of its second-half median: the filter converged


@dataclass(frozen=True)
class PointingRequirement:
    """A pointing requirement as ECSS-E-ST-60-10C states one, and the windows of its indices.

    Attributes
    ----------
    ape_deg : float, optional
        The APE bound on the total error, degrees (None: the scenario's
        ``control.pointing_requirement_deg``).
    rpe_deg : float, optional
        An RPE bound per axis, degrees (None: RPE is reported, with no verdict).
    rpe_window_s : float
        The RPE's window, s (the requirement's; ECSS leaves it to the mission).
    probability : float
        P_C: the share the requirement must hold for (of runs, of time, or of both:
        see ``interpretation``).
    confidence : float
        The confidence level of every bound the budget gives.
    interpretation : {'ensemble', 'temporal', 'mixed'}
        The statistical interpretation the verdict uses (ECSS-E-ST-60-10C; ESA
        pointing error engineering handbook ESSB-HB-E-003).
    drift_window_s, drift_separation_s : float
        The PDE's and KDE's averaging window and the time between the two windows, s.
    """

    ape_deg: float | None = None
    rpe_deg: float | None = None
    rpe_window_s: float = 60.0
    probability: float = 0.95
    confidence: float = 0.95
    interpretation: str = "ensemble"
    drift_window_s: float = 600.0
    drift_separation_s: float = 3600.0

    def __post_init__(self) -> None:
        for name in ("ape_deg", "rpe_deg"):
            v = getattr(self, name)
            if v is not None and not (_real(v) and v > 0):
                raise ConfigError(f"{name} must be a positive number of degrees, got {v!r}")
        for name in ("rpe_window_s", "drift_window_s", "drift_separation_s"):
            v = getattr(self, name)
            if not (_real(v) and v > 0):
                raise ConfigError(f"{name} must be a positive number of seconds, got {v!r}")
        for name in ("probability", "confidence"):
            v = getattr(self, name)
            if not (_real(v) and 0 < v < 1):
                raise ConfigError(f"{name} must be in (0, 1), got {v!r}")
        if self.interpretation not in INTERPRETATIONS:
            raise ConfigError(
                f"interpretation must be one of {', '.join(INTERPRETATIONS)}, "
                f"got {self.interpretation!r}"
            )

    def bound_deg(self, scenario_requirement_deg: float) -> float:
        """The APE bound: ``ape_deg``, or the scenario's requirement.

        Parameters
        ----------
        scenario_requirement_deg : float
            The scenario's ``control.pointing_requirement_deg``.

        Returns
        -------
        float
            Degrees.
        """
        return scenario_requirement_deg if self.ape_deg is None else float(self.ape_deg)


def _real(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def run_indices(
    t: np.ndarray,
    error_axes_deg: np.ndarray,
    knowledge_axes_deg: np.ndarray | None,
    total_error_deg: np.ndarray,
    steady_from_s: float,
    req: PointingRequirement,
    bound_deg: float,
    filter_sigma: np.ndarray | None = None,
) -> dict[str, float | None]:
    """One run's ECSS indices and convergence, as a flat row (degrees, seconds, fractions).

    Parameters
    ----------
    t : numpy.ndarray, shape (K,)
        Logged times, s (evenly spaced).
    error_axes_deg : numpy.ndarray, shape (K, 3)
        Pointing error about x, y, z, degrees.
    knowledge_axes_deg : numpy.ndarray, shape (K, 3), optional
        Knowledge error about x, y, z, degrees (None: no filter).
    total_error_deg : numpy.ndarray, shape (K,)
        The total pointing error, degrees.
    steady_from_s : float
        Start of the steady window, s.
    req : PointingRequirement
        Windows and the probability of the time quantile.
    bound_deg : float
        The APE bound on the total error, degrees.
    filter_sigma : numpy.ndarray, shape (K, m), optional
        The filter's logged 1σ (attitude, then rate or gyro bias; for its convergence).

    Returns
    -------
    dict
        Every :data:`COLUMNS` entry per axis, ``steady_rms_error_<axis>_deg`` and
        ``steady_mean_error_<axis>_deg``; ``time_within_requirement_fraction``,
        ``time_quantile_error_deg``, ``acquired_s``, ``settled_s``, ``filter_converged_s``.
    """
    steady = t >= steady_from_s
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    rpe_w = max(1, round(req.rpe_window_s / dt))
    drift_w = max(1, round(req.drift_window_s / dt))
    drift_s = max(1, round(req.drift_separation_s / dt))
    e = error_axes_deg[steady]
    k = knowledge_axes_deg[steady] if knowledge_axes_deg is not None else None
    out: dict[str, float | None] = {}
    for i, a in enumerate(AXES):
        ei = e[:, i]
        mean = float(np.mean(ei)) if ei.size else 0.0
        out[f"steady_rms_error_{a}_deg"] = float(np.sqrt(np.mean(ei**2))) if ei.size else 0.0
        out[f"steady_mean_error_{a}_deg"] = mean
        out[COLUMNS["APE"].format(a)] = _max_abs(ei)
        out[COLUMNS["MPE"].format(a)] = abs(mean)
        out[COLUMNS["RPE"].format(a)] = _rpe(ei, rpe_w)
        out[COLUMNS["PDE"].format(a)] = _drift(ei, drift_w, drift_s)
        ki = k[:, i] if k is not None else None
        out[COLUMNS["AKE"].format(a)] = _max_abs(ki) if ki is not None else None
        out[COLUMNS["MKE"].format(a)] = (
            abs(float(np.mean(ki))) if ki is not None and ki.size else None
        )
        out[COLUMNS["KDE"].format(a)] = _drift(ki, drift_w, drift_s) if ki is not None else None
    total = total_error_deg[steady]
    out["time_within_requirement_fraction"] = (
        float(np.mean(total <= bound_deg)) if total.size else 1.0
    )
    out["time_quantile_error_deg"] = (
        float(np.quantile(total, req.probability, method="inverted_cdf")) if total.size else 0.0
    )
    out["acquired_s"] = _acquired(t, total_error_deg, bound_deg)
    out["settled_s"] = _settled(t, total_error_deg, bound_deg)
    out["filter_converged_s"] = _filter_converged(t, filter_sigma)
    return out


def _max_abs(x: np.ndarray) -> float:
    return float(np.max(np.abs(x))) if x.size else 0.0


def _moving_mean(x: np.ndarray, width: int) -> np.ndarray:
    """Means of x[j : j + width] for every j (x.size − width + 1 of them)."""
    c = np.concatenate([[0.0], np.cumsum(x)])
    return (c[width:] - c[:-width]) / width


def _rpe(e: np.ndarray, width: int) -> float:
    """max |e(t) − mean of e over the window centred on t| (0 when the trace is shorter than
    one window). The window is ``width`` samples made odd (one more when even): an even one
    is centred half a sample off t, which reads a ramp's slope as RPE."""
    width += 1 - width % 2
    if e.size < width:
        return 0.0
    mean = _moving_mean(e, width)
    centre = e[width // 2 : width // 2 + mean.size]
    return float(np.max(np.abs(centre - mean)))


def _drift(x: np.ndarray, width: int, separation: int) -> float | None:
    """max |mean over [j, j + width) − mean over [j + separation, j + separation + width)|, or
    None when the trace holds no such pair."""
    if x.size < width + separation:
        return None
    mean = _moving_mean(x, width)
    return float(np.max(np.abs(mean[separation:] - mean[:-separation])))


def _acquired(t: np.ndarray, total: np.ndarray, bound: float) -> float | None:
    """The first time the total error is within ``bound`` (None: never)."""
    inside = np.flatnonzero(total <= bound)
    return float(t[inside[0]]) if inside.size else None


def _settled(t: np.ndarray, total: np.ndarray, bound: float) -> float | None:
    """The time after which the total error stays within ``bound`` (None: it ends outside)."""
    outside = np.flatnonzero(total > bound)
    if outside.size == 0:
        return float(t[0]) if t.size else 0.0
    if outside[-1] == t.size - 1:
        return None
    return float(t[outside[-1] + 1])


def _filter_converged(t: np.ndarray, sigma: np.ndarray | None) -> float | None:
    """The first time every logged σ of the filter is within :data:`FILTER_SETTLED` of its
    median over the run's second half (None without a filter)."""
    if sigma is None or sigma.size == 0 or not np.any(sigma):
        return None
    level = FILTER_SETTLED * np.median(sigma[sigma.shape[0] // 2 :], axis=0)
    first = np.flatnonzero(np.all(sigma <= level, axis=1))
    return float(t[first[0]]) if first.size else None
