"""The estimation benchmark's median verdict: ``bound-limited`` if and only if the bound implies a median above the
flight figure (``benchmarks/bench_estimation.py``, module docstring)."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_estimation import FLIGHT_ERROR_PCT, median_interval, median_verdict
from scipy.stats import binom


def test_verdict_met_when_every_median_is_within_its_flight_figure() -> None:
    assert median_verdict(0.99 * FLIGHT_ERROR_PCT, 10 * FLIGHT_ERROR_PCT) == "met"


def test_bound_limited_only_where_the_bound_implied_median_exceeds_the_flight_figure() -> None:
    # The gapped row of 80 seeds: mass median 0.536 % against 0.39 %, median bound 0.916 % (0.674 × = 0.617 %).
    med = np.array([0.536, 0.567, 0.430, 0.563])
    crb = np.array([0.916, 0.799, 0.897, 0.938])
    assert median_verdict(med, crb) == "bound-limited m"
    # Just below the limit (0.674 × 0.578 = 0.3896 < 0.39): missed, not bound-limited.
    assert median_verdict(med, np.array([0.578, 0.799, 0.897, 0.938])) == "missed m"
    # A parameter of each kind.
    assert median_verdict(np.array([0.5, 1.0, 0.4, 0.5]), np.array([0.9, 0.5, 0.9, 0.9])) == (
        "bound-limited m; missed Ixx")


def test_a_miss_within_the_median_interval_is_marked() -> None:
    # The gapped+IMU row of 160 seeds: mass median 0.403 % against 0.39 %, 0.674 × its bound 0.374 % (not limited).
    med = np.array([0.403, 0.251, 0.294, 0.267])
    crb = np.array([0.554, 0.395, 0.396, 0.441])
    assert median_verdict(med, crb) == "missed m"
    assert median_verdict(med, crb, np.array([0.35, 0.22, 0.26, 0.23])) == "missed m (interval reaches it)"
    assert median_verdict(med, crb, np.array([0.395, 0.22, 0.26, 0.23])) == "missed m"
    two = np.array([0.403, 0.95, 0.294, 0.267])
    assert median_verdict(two, crb, np.array([0.35, 0.93, 0.26, 0.23])) == "missed m,Ixx (interval reaches it: m)"


def test_median_interval_ranks_are_the_binomial_ones() -> None:
    # n = 160: ranks 68 and 93 (1 − 2 P(B ≤ 67) = 0.9522 ≥ 0.95; rank 69 would give 0.9313), B ~ Binomial(160, 1/2).
    assert 1 - 2 * binom.cdf(67, 160, 0.5) >= 0.95 > 1 - 2 * binom.cdf(68, 160, 0.5)
    values = np.arange(1.0, 161.0)[::-1].reshape(-1, 1)  # unsorted on purpose
    low, high = median_interval(values)
    assert (low[0], high[0]) == (68.0, 93.0)
    # n = 20: ranks 6 and 15 (0.9586; rank 7: 0.8847); with 4 samples no ranks reach the level: the extremes.
    low, high = median_interval(np.arange(1.0, 21.0).reshape(-1, 1))
    assert (low[0], high[0]) == (6.0, 15.0)
    low, high = median_interval(np.arange(1.0, 5.0).reshape(-1, 1))
    assert (low[0], high[0]) == (1.0, 4.0)


def test_median_interval_covers_the_median_at_its_level() -> None:
    # Heavy-tailed |errors| (|t₃|) with a known median: coverage over 4000 draws of 160 samples.
    rng = np.random.default_rng(7)
    true_median = 0.7648923284  # median of |t_3| = t_3's 75th percentile (scipy.stats.t.ppf(0.75, 3))
    draws = np.abs(rng.standard_t(3, size=(160, 4000)))
    low, high = median_interval(draws)
    coverage = np.mean((low <= true_median) & (true_median <= high))
    assert 0.940 <= coverage <= 0.964  # exact coverage 0.9522, ±3.5 binomial standard errors (0.0034) of 4000 draws
