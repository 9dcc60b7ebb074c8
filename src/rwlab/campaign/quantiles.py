"""Distribution-free bounds for a Monte Carlo budget: order statistics and Clopper–Pearson.

With n independent runs of a statistic X (e.g. each run's steady-state maximum
pointing error), the r-th smallest value X_(r) bounds the p-quantile ξ_p from
above with confidence P(X_(r) ≥ ξ_p) = P(Bin(n, p) ≤ r − 1) — whatever X's
distribution (the number of runs below ξ_p is binomial). The largest value
bounds it at 1 − pⁿ, so a 95 % bound on the 99.73 % quantile needs
n ≥ ln 0.05 / ln 0.9973 ≈ 1108 runs. The fraction of runs meeting a
requirement gets the one-sided Clopper–Pearson lower bound.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import beta, binom

from rwlab.errors import ConfigError

__all__ = [
    "PROBABILITIES",
    "clopper_pearson_lower",
    "order_statistic_bound",
    "quantile_table",
    "runs_needed",
]

PROBABILITIES = (0.5, 0.9, 0.99, 0.9973)


def _check(p: float, confidence: float) -> None:
    if not (0 < p < 1 and 0 < confidence < 1):
        raise ConfigError(f"p and confidence must be in (0, 1), got {p!r}, {confidence!r}")


def order_statistic_bound(n: int, p: float, confidence: float = 0.95) -> int | None:
    """The smallest rank r (1-based) with P(X_(r) ≥ ξ_p) ≥ ``confidence`` among n runs, or
    None when even the largest (r = n) falls short.

    Parameters
    ----------
    n : int
        Number of runs.
    p : float
        The quantile's probability, in (0, 1).
    confidence : float
        In (0, 1).

    Returns
    -------
    int or None
        The rank r of the bounding order statistic.
    """
    _check(p, confidence)
    r = np.arange(1, n + 1)
    ok = np.flatnonzero(binom.cdf(r - 1, n, p) >= confidence)
    return int(r[ok[0]]) if ok.size else None


def runs_needed(p: float, confidence: float = 0.95) -> int:
    """The fewest runs whose largest value bounds ξ_p at ``confidence``: ⌈ln(1 − c) / ln p⌉.

    Parameters
    ----------
    p, confidence : float
        In (0, 1).

    Returns
    -------
    int
        Runs.
    """
    _check(p, confidence)
    n = math.ceil(math.log(1 - confidence) / math.log(p) - 1e-9)
    while 1 - p**n < confidence:  # guard the rounding
        n += 1
    return n


def clopper_pearson_lower(successes: int, n: int, confidence: float = 0.95) -> float:
    """One-sided Clopper–Pearson lower bound of a success probability from ``successes`` of n.

    Parameters
    ----------
    successes, n : int
        0 ≤ successes ≤ n, n ≥ 1.
    confidence : float
        In (0, 1).

    Returns
    -------
    float
        The bound, in [0, 1].
    """
    if not (0 <= successes <= n and n >= 1):
        raise ConfigError(f"need 0 ≤ successes ≤ n and n ≥ 1, got {successes}, {n}")
    if successes == 0:
        return 0.0
    return float(beta.ppf(1 - confidence, successes, n - successes + 1))


def quantile_table(values, confidence: float = 0.95, probabilities=PROBABILITIES) -> list[dict]:
    """``{p, estimate, upper_bound, confidence, runs_needed}`` for each p: the estimate is the
    order statistic X_(⌈np⌉), the bound X_(r) of :func:`order_statistic_bound` (None when the
    runs cannot support it), ``runs_needed`` the fewest runs for any bound (:func:`runs_needed`).

    Parameters
    ----------
    values : (n,) array
        One value per run (finite).
    confidence : float
    probabilities : sequence of float

    Returns
    -------
    list of dict
    """
    x = np.sort(np.asarray(values, dtype=float))
    if x.size == 0 or not np.all(np.isfinite(x)):
        raise ConfigError("a quantile table needs at least one finite value per run")
    n = x.size
    out = []
    for p in probabilities:
        r = order_statistic_bound(n, p, confidence)
        out.append(
            {
                "p": p,
                "estimate": float(x[max(math.ceil(n * p), 1) - 1]),
                "upper_bound": None if r is None else float(x[r - 1]),
                "upper_bound_rank": r,
                "confidence": confidence,
                "runs_needed": runs_needed(p, confidence),
            }
        )
    return out
