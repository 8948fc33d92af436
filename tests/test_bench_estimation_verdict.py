"""The estimation benchmark's median verdict: ``bound-limited`` if and only if the bound implies a median above the
flight figure (``benchmarks/bench_estimation.py``, module docstring)."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_estimation import FLIGHT_ERROR_PCT, median_verdict


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
