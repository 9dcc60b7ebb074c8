"""The grey-box wheel's standard deviations: how :func:`rwlab.ident.greybox.greybox_fit`
forms them, and the terms beyond the fit's own statistics.

σ of each estimated parameter is the root sum of squares of its budget's terms:

- ``statistical``: the least-squares sandwich covariance with a Newey–West long-run
  covariance of the scores (the simulation errors are coloured);
- ``inertia``: J's datasheet tolerance, for the parameters the record identifies only
  divided by J (:data:`NEEDS_J`);
- ``current_limit``: the configured current limit's tolerance where it is held;
- ``structure``: a bias envelope measured per wheel model against units of known truth,
  kept with its measurement in ``greybox_structure.json`` (:func:`structure_error`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rwlab.errors import DataError

__all__ = ["NEEDS_J", "STRUCTURE_ERROR", "STRUCTURE_FILE", "Uncertainty", "structure_error"]

ESTIMATED = ("torque_constant", "coulomb", "breakaway", "viscous", "accel_limit", "kp", "ki")
CLAMP = "current_limit"  # estimated too when the record shows the clamp binding


@dataclass(frozen=True)
class Uncertainty:
    """How :func:`greybox_fit` forms its standard deviations (module docstring).

    Parameters
    ----------
    inertia_tolerance : float
        J's datasheet tolerance, ± as a fraction (uniform within it: σ_J/J =
        tolerance/√3; default ±2 %, rotor machining). It enters the standard
        deviation of every parameter that needs J (kt, τc, τbrk, b).
    current_limit_tolerance : float
        How far the unit's current clamp may sit from the driver's configured
        limit, ± as a fraction (uniform; default ±2 %: current-sense shunt 1 % +
        reference 1 %). With the limit held at its configured value it enters
        every σ through the fit's sensitivity to it; it also sets how close to
        the configured limit a measured current counts as at the clamp.
    hac_lags : int, optional
        Lags of the Newey–West long-run covariance of the scores (0: residuals
        taken as white); None (default) chooses them by Andrews' AR(1) plug-in.
    structure_error : dict, optional
        Relative bias envelope of each estimated parameter that the model's structure
        leaves (what it does not model: the firmware's Hall-speed feedback, k_t's
        fall with temperature, friction drift, torque ripple); None:
        ``wheel_model``'s envelope measured on the twin (:func:`structure_error`; it
        holds on a real wheel only as far as the twin is right); ``{}`` for none.
    wheel_model : str
        Whose measured envelope ``structure_error=None`` means (:func:`structure_error`;
        default ``'rw90'``); a model without one gets the widest measured, said so.
    """

    inertia_tolerance: float = 0.02
    hac_lags: int | None = None
    structure_error: dict | None = None
    current_limit_tolerance: float = 0.02
    wheel_model: str = "rw90"

    def __post_init__(self) -> None:
        for name in ("inertia_tolerance", "current_limit_tolerance"):
            tol = getattr(self, name)
            if isinstance(tol, bool) or not (math.isfinite(tol) and 0 <= tol < 1):
                raise DataError(f"{name} must be a fraction in [0, 1), got {tol!r}")
        lags = self.hac_lags
        bad = isinstance(lags, bool) or not isinstance(lags, (int, np.integer))
        if lags is not None and (bad or lags < 0):
            raise DataError(f"hac_lags must be a non-negative integer or None, got {lags!r}")
        shape = self.structure_error or {}
        if not set(shape) <= {*ESTIMATED, CLAMP} or not all(
            math.isfinite(v) and v >= 0 for v in shape.values()
        ):
            raise DataError(
                f"structure_error maps estimated parameters {ESTIMATED} to relative errors ≥ 0"
            )


NEEDS_J = ("torque_constant", "coulomb", "breakaway", "viscous")  # identified only as x/J

STRUCTURE_FILE = Path(__file__).with_name("greybox_structure.json")
"""The measured structure-error envelopes, one per wheel model, each with its measurement."""


def structure_error(wheel_model: str = "rw90") -> tuple[dict, str]:
    """The structure-error envelope of ``wheel_model`` from :data:`STRUCTURE_FILE`.

    Parameters
    ----------
    wheel_model : str
        A wheel model's name (a preset's, lower case).

    Returns
    -------
    envelope : dict
        Relative bias of each estimated parameter.
    source : str
        Where it comes from: the model's own measurement, or, for a wheel model
        without one, the widest envelope of every calibrated model (each parameter's
        largest), said so.
    """
    models = json.loads(STRUCTURE_FILE.read_text())["models"]
    entry = models.get(str(wheel_model).lower())
    if entry is not None:
        return dict(entry["relative_error"]), (
            f"the {wheel_model} envelope measured by `{entry['measurement']['command']}`"
        )
    widest: dict = {}
    for other in models.values():
        for k, v in other["relative_error"].items():
            widest[k] = max(widest.get(k, 0.0), v)
    return widest, (
        f"{wheel_model} has no measured envelope in {STRUCTURE_FILE.name}: the widest of "
        f"{', '.join(sorted(models))} (calibrate it: bench/bench_greybox_z.py --calibrate)"
    )


STRUCTURE_ERROR = structure_error("rw90")[0]
"""The RW90's bias envelope, read from :data:`STRUCTURE_FILE` (its measurement is there):
the relative error the model's structure left on each estimate (the RMS relative error of
the J-free quantities against the units' truth, three records; judged on other units).
It is not noise: on every nominal twin unit α and kt/J come out low by about this much
(z −0.6 to −1.1), and it is most of their σ. What the grey box
leaves out: the firmware's loop runs on the Hall speed (late and coarse), k_t falls with
the magnet's temperature, friction drifts over a record, torque ripple and cogging. On a
real wheel it holds only as far as the twin is right about these effects; a wheel with
others (a different loop, a different sensor) needs its own calibration against a unit
whose parameters are measured.

``breakaway`` is calibrated on its own records: the PRBS leaves it unidentified, and on
slow reversals through zero (``python bench/greybox_breakaway.py``; the units and the
numbers are the ``breakaway`` entry of ``greybox_structure.json``'s measurement) its raw
estimate reads high by up to +0.87 (RMS 0.56), with or without stiction in the unit: at
rest the Hall speed and the drive's zero-speed behaviour dwell like stiction; on a
second set of units RMS 0.83, up to +1.31. With this term no record shows a breakaway
beyond 2 σ of Coulomb: it is reported unidentified."""


def uncertainty_budget(
    fit_std: dict, fitted: dict, clamp: dict | None, unc: Uncertainty, inertia: float
) -> tuple[dict, dict, dict]:
    """σ of each parameter with a statistical σ, as the root sum of squares of its budget
    (module docstring); also the x/J ratios' σ. ``clamp``: the held current limit's term
    per parameter (None: the limit was estimated). Returns (std, ratios, budget)."""
    shape = (
        structure_error(unc.wheel_model)[0] if unc.structure_error is None else unc.structure_error
    )
    rel_j = unc.inertia_tolerance / math.sqrt(3.0)
    std, ratios, budget = {}, {}, {}
    for k, s_fit in fit_std.items():
        parts = {"statistical": s_fit, "structure": abs(fitted[k]) * shape.get(k, 0.0)}
        if clamp is not None:
            parts["current_limit"] = clamp.get(k, 0.0)
        if k in NEEDS_J:  # value = (value/J)·J: the record fixes the ratio, J its datasheet
            ratio = math.sqrt(sum(v**2 for v in parts.values())) / inertia
            ratios[f"{k}/inertia"] = {"value": fitted[k] / inertia, "std": ratio}
            parts["inertia"] = abs(fitted[k]) * rel_j
        budget[k] = parts
        std[k] = math.sqrt(sum(v**2 for v in parts.values()))
    return std, ratios, budget


def sandwich_covariance(fun, jac, n_y: int, seen, lags: int | None) -> tuple[np.ndarray, int]:
    """Covariance of the least-squares estimate H⁻¹ S H⁻¹ (H = JᵀJ) with S the long-run
    covariance of the per-sample scores gₜ = Σ_outputs Jₜᵀrₜ: the simulation errors are
    coloured (a missed ramp is wrong for many samples), which λ(JᵀJ)⁻¹ ignores, and the
    two outputs' errors are scaled, not weighted by their variances. Hand-written
    (Newey–West 1987, Bartlett weights; bandwidth by Andrews 1991, AR(1) plug-in):
    statsmodels has it, but is not a dependency for these lines."""
    d = jac.shape[1]
    blocks = range(0, fun.size, n_y)  # speed rows, then current rows: the same instants
    scores = sum(jac[a : a + n_y] * fun[a : a + n_y, None] for a in blocks)
    scores = np.asarray(scores)[:, seen]
    if lags is None:
        lags = _andrews_lags(scores)
    S = scores.T @ scores
    for lag in range(1, lags + 1):
        G = scores[lag:].T @ scores[:-lag]
        S += (1.0 - lag / (lags + 1.0)) * (G + G.T)
    J = jac[:, seen]
    Hinv = np.linalg.pinv(J.T @ J)
    cov = np.zeros((d, d))
    cov[np.ix_(seen, seen)] = Hinv @ S @ Hinv
    return cov, lags


def _andrews_lags(scores: np.ndarray) -> int:
    """Andrews' (1991) bandwidth for the Bartlett kernel from AR(1) fits of each score
    series: 1.1447·(α̂·N)^(1/3), α̂ = Σ4ρ²σ⁴/((1−ρ)⁶(1+ρ)²) / Σσ⁴/(1−ρ)⁴; at most N/4."""
    n = scores.shape[0]
    num = den = 0.0
    for x in scores.T:
        x = x - x.mean()
        if not np.any(x):
            continue
        rho = float(np.clip(x[1:] @ x[:-1] / (x[:-1] @ x[:-1]), -0.99, 0.99))
        s4 = float(np.var(x[1:] - rho * x[:-1])) ** 2
        num += 4 * rho**2 * s4 / ((1 - rho) ** 6 * (1 + rho) ** 2)
        den += s4 / (1 - rho) ** 4
    if den == 0:
        return 0
    return int(min(math.ceil(1.1447 * (num / den * n) ** (1 / 3)), n // 4))
