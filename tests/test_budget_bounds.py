"""Order-statistic quantile bounds and Clopper–Pearson, against first principles."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rwlab.campaign.quantiles import (
    clopper_pearson_lower,
    order_statistic_bound,
    quantile_table,
    runs_needed,
)


def _binom_cdf(k: int, n: int, p: float) -> float:
    """P(Bin(n, p) ≤ k) summed term by term (independent of scipy)."""
    return sum(math.comb(n, i) * p**i * (1 - p) ** (n - i) for i in range(k + 1))


def test_runs_needed_for_the_99_73_percent_quantile_is_about_1108():
    """ln 0.05 / ln 0.9973 = 1108.03: the 1109th run is the first that suffices."""
    n = next(n for n in range(1, 5000) if 1 - 0.9973**n >= 0.95)  # brute force
    assert runs_needed(0.9973) == n == 1109
    assert runs_needed(0.5) == 5  # 1 − 0.5⁵ = 0.969 ≥ 0.95 > 1 − 0.5⁴


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 120), p=st.sampled_from([0.5, 0.9, 0.99, 0.9973]))
def test_the_bounding_rank_is_the_smallest_with_enough_binomial_mass(n, p):
    r = order_statistic_bound(n, p, 0.95)
    if r is None:
        assert _binom_cdf(n - 1, n, p) < 0.95
    else:
        assert _binom_cdf(r - 1, n, p) >= 0.95 - 1e-12
        assert r == 1 or _binom_cdf(r - 2, n, p) < 0.95 + 1e-12


def test_forty_runs_bound_the_median_and_90_percent_but_not_the_tails():
    values = np.arange(1.0, 41.0)
    table = {row["p"]: row for row in quantile_table(values)}
    assert table[0.9973]["upper_bound"] is None and table[0.9973]["runs_needed"] == 1109
    assert table[0.99]["upper_bound"] is None
    r = table[0.5]["upper_bound_rank"]
    assert table[0.5]["upper_bound"] == values[r - 1]
    assert table[0.9]["upper_bound"] is None or table[0.9]["upper_bound"] >= table[0.9]["estimate"]


def test_the_bound_covers_the_true_quantile_at_its_confidence():
    """Empirical coverage on exponential draws (true ξ_p = −ln(1 − p))."""
    rng = np.random.default_rng(0)
    p, n, hits, trials = 0.9, 60, 0, 2000
    r = order_statistic_bound(n, p)
    xi = -math.log(1 - p)
    for _ in range(trials):
        hits += np.sort(rng.exponential(size=n))[r - 1] >= xi
    assert hits / trials == pytest.approx(_binom_cdf(r - 1, n, p), abs=0.02)
    assert hits / trials >= 0.93


def test_clopper_pearson_lower_bound_solves_the_binomial_tail():
    for k, n in ((40, 40), (35, 40), (1, 10)):
        lb = clopper_pearson_lower(k, n)
        # P(X ≥ k | p = lb) = 0.05 (the exact one-sided bound)
        assert 1 - _binom_cdf(k - 1, n, lb) == pytest.approx(0.05, abs=1e-6)
    assert clopper_pearson_lower(40, 40) == pytest.approx(0.05 ** (1 / 40))
    assert clopper_pearson_lower(0, 5) == 0.0
