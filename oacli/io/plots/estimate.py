"""The ``estimate`` stage's PNG plots.

* ``convergence.png`` -- mass and the three principal inertias over time with ± 2σ bands, the Cramér-Rao bound's
  2σ around the final estimate (dotted) and the truth (dashed) when the telemetry's config knows it;
* ``innovation.png`` -- the normalised residual (batch) or innovation (sequential) squared d² of every record
  (blue), the χ² gate (black, dashed) and the records the gate rejected (red crosses): three colours, three things.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from oacli.io.plots.common import (
    RunFiles,
    guarded_plots,
    legend_outside,
    log_scale,
    save_png,
    spans_decades,
    subplots,
)
from oacli.types import ParameterEstimate

PARAMETERS = (("mass", "kg"), ("Ixx", "kg·m²"), ("Iyy", "kg·m²"), ("Izz", "kg·m²"))


def plot_convergence(path: Path, estimates: Sequence[ParameterEstimate], truth: np.ndarray | None,
                     crb_std: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Draw ``convergence.png`` (module docstring).

    Parameters
    ----------
    path : Path
        Output PNG.
    estimates : sequence of ParameterEstimate
        The estimates over time.
    truth : ndarray, shape (4,), optional
    crb_std : ndarray, shape (4,), optional
        Cramér-Rao standard deviation at the end.

    Returns
    -------
    tuple of ndarray
        Times (k,), θ (k, 4) and σ (k, 4) drawn.
    """
    t = np.array([e.t for e in estimates], dtype=float)
    theta = np.array([e.theta for e in estimates], dtype=float).reshape(-1, 4)
    std = np.array([e.std for e in estimates], dtype=float).reshape(-1, 4)
    fig, axes = subplots(4, 1, figsize=(11, 10), sharex=True)
    for i, (name, unit) in enumerate(PARAMETERS):
        ax = axes[i]
        two = 2.0 * std[:, i]
        ax.plot(t, theta[:, i], color="tab:blue", lw=1.5, marker="o" if len(t) < 20 else None, ms=3,
                label="estimate")
        ax.fill_between(t, theta[:, i] - two, theta[:, i] + two, color="tab:blue", alpha=0.2, lw=0, label="± 2σ")
        shown = [theta[len(t) // 2:, i] - two[len(t) // 2:], theta[len(t) // 2:, i] + two[len(t) // 2:]]
        if crb_std is not None and np.isfinite(crb_std[i]):
            for sign in (-1.0, 1.0):
                ax.axhline(theta[-1, i] + sign * 2.0 * crb_std[i], color="tab:green", ls=":", lw=1.0,
                           label="final ± 2σ Cramér-Rao" if sign > 0 else None)
        if truth is not None:
            ax.axhline(truth[i], color="k", ls="--", lw=1.0, label="truth")
            shown.append(np.array([truth[i]]))
        values = np.concatenate(shown)
        values = values[np.isfinite(values)]
        if values.size:  # y range: the converged half (the prior-sized first bands would hide it)
            lo, hi = float(values.min()), float(values.max())
            pad = 0.1 * (hi - lo) if hi > lo else 0.05 * max(abs(hi), 1e-9)
            ax.set_ylim(lo - pad, hi + pad)
        ax.set_ylabel(f"{name} [{unit}]")
        ax.grid(True, alpha=0.3)
        legend_outside(ax)
    axes[0].set_title("Inertial parameter estimates ± 2σ (y range: converged half)", loc="left", fontsize="medium")
    axes[-1].set_xlabel("time [s]")
    save_png(fig, path)
    return t, theta, std


#: Colours of ``innovation.png``: d², the gate, the rejected records (distinct: the gate is not a rejection).
INNOVATION_COLORS = {"d2": "tab:blue", "gate": "black", "rejected": "tab:red"}


def plot_innovation(path: Path, t_s: np.ndarray, d2: np.ndarray, gate: float, rejected: np.ndarray) -> None:
    """Draw ``innovation.png`` (module docstring).

    Parameters
    ----------
    path : Path
        Output PNG.
    t_s : ndarray, shape (K,)
        Record times [s].
    d2 : ndarray, shape (K,)
        Normalised residual or innovation squared (NaN where not computed).
    gate : float
        χ² threshold (``inf`` or NaN: no gate).
    rejected : ndarray of bool, shape (K,)
        Records the gate rejected.
    """
    t, d2 = np.asarray(t_s, dtype=float), np.asarray(d2, dtype=float)
    bad = np.asarray(rejected, dtype=bool) & np.isfinite(d2)
    fig, ax = subplots(figsize=(11, 4.5))
    ax.plot(t, d2, ".-", color=INNOVATION_COLORS["d2"], lw=0.8, ms=3, label="d² per record")
    if np.isfinite(gate):
        ax.axhline(gate, color=INNOVATION_COLORS["gate"], ls="--", lw=1.2, label=f"χ² gate {gate:.3g}")
    if np.any(bad):
        ax.plot(t[bad], d2[bad], "x", color=INNOVATION_COLORS["rejected"], ms=7, mew=1.5,
                label=f"rejected by the gate ({int(bad.sum())})")
    shown = d2[np.isfinite(d2)]
    if spans_decades(np.append(shown, gate if np.isfinite(gate) else np.nan), 2.0):
        log_scale(ax)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("normalised residual² d² [-]")
    ax.grid(True, alpha=0.3, which="both")
    ax.set_title("Normalised residual (innovation) squared against the χ² gate", loc="left", fontsize="medium")
    legend_outside(ax)
    save_png(fig, path)


def estimate_figures(*, estimates: Sequence[ParameterEstimate], truth: np.ndarray | None,
                     crb_std: np.ndarray | None = None,
                     innovation: tuple[np.ndarray, np.ndarray, float, np.ndarray] | None = None,
                     ) -> dict[str, Callable[[Path], object]]:
    """The ``estimate`` stage's figures, name -> function drawing it to a path (shared by the stage and by
    ``oacli plots``, :mod:`oacli.stages.replot`); parameters as :func:`write_estimate_plots`.

    Returns
    -------
    dict of str to callable
    """
    figures: dict[str, Callable[[Path], object]] = {
        "convergence": lambda p: plot_convergence(p, estimates, truth, crb_std)}
    if innovation is not None:
        figures["innovation"] = lambda p: plot_innovation(p, *innovation)
    return figures


def write_estimate_plots(run: RunFiles, summary: dict[str, Any], *, estimates: Sequence[ParameterEstimate],
                         truth: np.ndarray | None, crb_std: np.ndarray | None = None,
                         innovation: tuple[np.ndarray, np.ndarray, float, np.ndarray] | None = None) -> None:
    """Write ``convergence.png`` (and ``innovation.png``) into the run folder and register them (failure: a summary
    warning).

    Parameters
    ----------
    run : RunFolder
    summary : dict
    estimates : sequence of ParameterEstimate
    truth : ndarray, shape (4,), optional
    crb_std : ndarray, shape (4,), optional
    innovation : tuple, optional
        ``(t [s], d², gate, rejected)`` per record (:func:`plot_innovation`).
    """
    guarded_plots(run, summary, estimate_figures(estimates=estimates, truth=truth, crb_std=crb_std,
                                                 innovation=innovation))
