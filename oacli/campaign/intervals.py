"""Confidence intervals of a campaign's per-cell figures, without assumptions on their distribution.

* Medians: ``[x_(l), x_(n+1-l)]`` (ranks from 1) covers the median with probability ``1 − 2 P(B ≤ l − 1)``,
  ``B ~ Binomial(n, 1/2)``; ``l`` is the largest rank for which that is at least the level (W. J. Conover,
  *Practical Nonparametric Statistics*, 3rd ed., 1999, §3.2; as ``benchmarks/bench_estimation.py``). At 95 % it
  needs n ≥ 6; with fewer runs the interval is ``None``, not the sample's extremes passed off as one.
* Proportions (runs with a violation, runs that never arrive): the Clopper-Pearson exact interval
  (:meth:`scipy.stats.binomtest` ``proportion_ci(method="exact")``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.stats import binom, binomtest

LEVEL = 0.95


def median_interval(values: Any, level: float = LEVEL) -> dict[str, Any]:
    """Median of ``values`` with its distribution-free interval (module docstring).

    Values may be ``None`` (dropped) or ``inf`` (kept: e.g. a run that never arrives ranks above every arrival).

    Parameters
    ----------
    values : sequence of float or None
    level : float
        Confidence level.

    Returns
    -------
    dict
        ``median``, ``low``, ``high`` (None when ``n`` is too small for ``level``), ``n``, ``level``,
        ``coverage`` (the interval's exact coverage).
    """
    x = np.sort(np.asarray([v for v in values if v is not None and not math.isnan(float(v))], dtype=float))
    n = int(x.size)
    out: dict[str, Any] = {"median": None, "low": None, "high": None, "n": n, "level": level, "coverage": None}
    if n == 0:
        return out
    out["median"] = float(np.median(x)) if np.all(np.isfinite(x[[n // 2, (n - 1) // 2]])) else float(x[n // 2])
    ranks = np.arange(1, n // 2 + 1)
    coverage = 1.0 - 2.0 * binom.cdf(ranks - 1, n, 0.5)
    ok = coverage >= level
    if np.any(ok):
        rank = int(ranks[ok][-1])
        out.update(low=float(x[rank - 1]), high=float(x[n - rank]), coverage=float(coverage[ok][-1]))
    return out


def proportion_interval(successes: int, n: int, level: float = LEVEL) -> dict[str, Any]:
    """A fraction with its Clopper-Pearson interval (module docstring).

    Parameters
    ----------
    successes, n : int
    level : float

    Returns
    -------
    dict
        ``fraction``, ``low``, ``high``, ``count``, ``n``, ``level`` (None figures when ``n`` is 0).
    """
    if n <= 0:
        return {"fraction": None, "low": None, "high": None, "count": 0, "n": 0, "level": level}
    ci = binomtest(int(successes), int(n)).proportion_ci(confidence_level=level, method="exact")
    return {"fraction": successes / n, "low": float(ci.low), "high": float(ci.high), "count": int(successes),
            "n": int(n), "level": level}


__all__ = ["LEVEL", "median_interval", "proportion_interval"]
