"""The ``excite`` stage's PNG plots.

* ``information.png`` -- the diagonal of the cumulative Fisher information per parameter over time (log scale when
  it spans decades), for the offline design ([Doerr2021]-style A/D-optimal design) or as gathered by RATTLE's
  estimator (posterior information minus the prior's);
* ``inputs.png`` -- force and torque per axis against the design limits (RATTLE: also the actuators').
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from oacli.io.plots.common import (
    RunFiles,
    decimate,
    guarded_plots,
    legend_outside,
    log_scale,
    plot_inputs,
    save_png,
    spans_decades,
    subplots,
)
from oacli.types import ParameterEstimate

PARAMETERS = (("mass", "1/kg²"), ("Ixx", "1/(kg·m²)²"), ("Iyy", "1/(kg·m²)²"), ("Izz", "1/(kg·m²)²"))


def plot_information(path: Path, t_s: np.ndarray, information: np.ndarray, title: str) -> np.ndarray:
    """Draw ``information.png``: ``F_ii`` over time, one panel per parameter.

    Parameters
    ----------
    path : Path
        Output PNG.
    t_s : ndarray, shape (N,)
        Times [s].
    information : ndarray, shape (N, 4, 4)
        Cumulative Fisher information.
    title : str

    Returns
    -------
    ndarray, shape (N, 4)
        The diagonals drawn.
    """
    t = np.asarray(t_s, dtype=float)
    diag = np.diagonal(np.asarray(information, dtype=float), axis1=1, axis2=2)
    fig, axes = subplots(4, 1, figsize=(11, 9), sharex=True)
    for i, (name, unit) in enumerate(PARAMETERS):
        ax = axes[i]
        ax.plot(*decimate(t, diag[:, i]), color="tab:blue", lw=1.5, label=f"F[{name}, {name}]")
        if spans_decades(diag[:, i]):
            log_scale(ax)
        ax.set_ylabel(f"{name} [{unit}]")
        ax.grid(True, alpha=0.3, which="both")
        legend_outside(ax)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title)
    save_png(fig, path)
    return diag


def gathered_information(estimates: Sequence[ParameterEstimate], prior_covariance: np.ndarray,
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Information gathered by an estimator: ``Σ_k⁻¹ − Σ_0⁻¹`` at each estimate (zero at t = 0).

    Parameters
    ----------
    estimates : sequence of ParameterEstimate
    prior_covariance : ndarray, shape (4, 4)

    Returns
    -------
    tuple of ndarray
        Times (k+1,) and information (k+1, 4, 4).
    """
    prior_info = np.linalg.inv(np.asarray(prior_covariance, dtype=float))
    t = np.array([0.0] + [e.t for e in estimates])
    info = np.array([np.zeros((4, 4))] + [np.linalg.inv(e.covariance) - prior_info for e in estimates])
    return t, 0.5 * (info + np.transpose(info, (0, 2, 1)))


def excite_figures(*, method: str, t_info_s: np.ndarray, information: np.ndarray, t_input_s: np.ndarray,
                   u: np.ndarray, force_limit_N: np.ndarray, torque_limit_Nm: np.ndarray,
                   actuator: tuple[np.ndarray, np.ndarray] | None = None) -> dict[str, Callable[[Path], object]]:
    """The ``excite`` stage's figures, name -> function drawing it to a path (shared by the stage and by
    ``oacli plots``, :mod:`oacli.stages.replot`); parameters as :func:`write_excite_plots` (``method`` names the
    titles).

    Returns
    -------
    dict of str to callable
    """
    return {
        "information": lambda p: plot_information(
            p, t_info_s, information, f"Fisher information per parameter ({method} excitation)"),
        "inputs": lambda p: plot_inputs(p, t_input_s, u, force_limit_N, torque_limit_Nm,
                                        f"Inputs against the design limits ({method} excitation)",
                                        "design limit", actuator),
    }


def write_excite_plots(run: RunFiles, summary: dict[str, Any], *, t_info_s: np.ndarray, information: np.ndarray,
                       t_input_s: np.ndarray, u: np.ndarray, force_limit_N: np.ndarray, torque_limit_Nm: np.ndarray,
                       actuator: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """Write ``information.png`` and ``inputs.png`` into the run folder and register them (failures: a summary
    warning).

    Parameters
    ----------
    run : RunFolder
    summary : dict
        The stage's summary (its ``method`` names the titles).
    t_info_s, information : ndarray
        Times (N,) and cumulative Fisher information (N, 4, 4).
    t_input_s, u : ndarray
        Times (K,) and inputs (K, 6).
    force_limit_N, torque_limit_Nm : ndarray, shape (3,)
        Design limits.
    actuator : tuple of ndarray, optional
        Actuator force and torque limits.
    """
    guarded_plots(run, summary, excite_figures(
        method=str(summary.get("method", "")), t_info_s=t_info_s, information=information, t_input_s=t_input_s,
        u=u, force_limit_N=force_limit_N, torque_limit_Nm=torque_limit_Nm, actuator=actuator))
