"""Shared helpers of the stages' PNG plots (matplotlib, Agg backend forced: no display needed).

Figures are rendered to memory and written atomically (:func:`oacli.io.atomic.atomic_path`), so a run folder never
holds a half-written PNG. :func:`guarded_plots` runs each figure of a stage so that a plotting failure never loses
the run: the failure becomes a warning in the summary and the status is kept.
"""

from __future__ import annotations

import io
import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol

import matplotlib

matplotlib.use("Agg", force=True)

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse, Rectangle

from oacli.geometry import Scene
from oacli.io.atomic import atomic_path

_LOG = logging.getLogger(__name__)
DPI = 110
#: Axis names of the world frame.
AXES = ("x", "y", "z")


class RunFiles(Protocol):
    """What :func:`guarded_plots` needs of a run folder (:class:`oacli.io.runfolder.RunFolder`)."""

    run_dir: Path

    def file(self, role: str, name: str) -> Path: ...


def spans_decades(values: np.ndarray, decades: float = 2.0) -> bool:
    """True when the positive finite values span more than ``decades`` powers of ten."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v) & (v > 0)]
    return v.size > 1 and float(np.log10(v.max() / v.min())) > decades


def save_png(fig: Figure, path: Path) -> Path:
    """Render ``fig`` to PNG in memory, close it and write the bytes to ``path`` atomically."""
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight")
    finally:
        plt.close(fig)
    with atomic_path(Path(path)) as tmp:
        tmp.write_bytes(buf.getvalue())
    return Path(path)


def legend_outside(ax: Axes) -> None:
    """A legend right of the axes (it never covers the data)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize="small")


def ellipse_projection(center: np.ndarray, shape: np.ndarray, axes: tuple[int, int] = (0, 1),
                       grow_m: float = 0.0) -> tuple[float, float, float, float, float]:
    """The shadow of ``(p − c)ᵀ P (p − c) <= 1`` on the plane of world ``axes``: centre (2), width, height [m] and
    angle [deg]; semi-axes grown by ``grow_m`` (the robot radius: the zone the robot's centre keeps out of)."""
    i, j = axes
    cov = np.linalg.inv(np.asarray(shape, dtype=float))[np.ix_([i, j], [i, j])]  # the shadow is the ellipse of P⁻¹
    eig, vec = np.linalg.eigh(cov)
    semi = np.sqrt(np.maximum(eig, 0.0)) + grow_m
    angle = float(np.degrees(np.arctan2(vec[1, 1], vec[0, 1])))
    return float(center[i]), float(center[j]), 2.0 * float(semi[1]), 2.0 * float(semi[0]), angle


def draw_scene(ax: Axes, scene: Scene | None, robot_radius_m: float, axes: tuple[int, int] = (0, 1)) -> None:
    """Keep-in boxes (green) and keep-out ellipsoids (red; dashed: grown by the robot radius) projected on ``axes``."""
    if scene is None:
        return
    i, j = axes
    for k, box in enumerate(scene.keep_in):
        lo, hi = np.asarray(box.lower, dtype=float), np.asarray(box.upper, dtype=float)
        ax.add_patch(Rectangle((lo[i], lo[j]), hi[i] - lo[i], hi[j] - lo[j], fc=(0.3, 0.8, 0.45, 0.08),
                               ec="tab:green", lw=1.2, label="keep-in" if k == 0 else None))
    for k, zone in enumerate(scene.keep_out):
        x, y, w, h, a = ellipse_projection(zone.center, zone.shape, axes)
        ax.add_patch(Ellipse((x, y), w, h, angle=a, fc=(0.9, 0.25, 0.25, 0.35), ec="tab:red", lw=1.0,
                             label="keep-out (safety factor incl.)" if k == 0 else None))
        if robot_radius_m > 0:
            x, y, w, h, a = ellipse_projection(zone.center, zone.shape, axes, robot_radius_m)
            ax.add_patch(Ellipse((x, y), w, h, angle=a, fill=False, ec="tab:red", ls="--", lw=0.8,
                                 label=f"keep-out + robot radius {robot_radius_m:g} m" if k == 0 else None))


def finish_view(ax: Axes, axes: tuple[int, int], title: str) -> None:
    """Equal aspect, labels, grid, title and an outside legend of a top / side view."""
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel(f"{AXES[axes[0]]} [m]")
    ax.set_ylabel(f"{AXES[axes[1]]} [m]")
    ax.grid(True, alpha=0.3)
    ax.set_title(title, loc="left", fontsize="medium")
    legend_outside(ax)


def plot_inputs(path: Path, t_s: np.ndarray, u: np.ndarray, force_limit_N: np.ndarray, torque_limit_Nm: np.ndarray,
                title: str, limit_label: str = "limit",
                actuator: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Force and torque per axis (steps, held from each sample) against ± their limits (dashed).

    Parameters
    ----------
    path : Path
        Output PNG.
    t_s : ndarray, shape (K,)
        Sample times [s].
    u : ndarray, shape (K, 6)
        ``[f (N, world), τ (N·m, body)]``.
    force_limit_N, torque_limit_Nm : ndarray, shape (3,)
        Per-axis limits.
    title : str
        Figure title.
    limit_label : str
        Legend label of the limit lines.
    actuator : tuple of ndarray, optional
        The actuators' force [N] and torque [N·m] limits, drawn dotted when they differ from the limits above.

    Returns
    -------
    tuple of ndarray
        The plotted times and inputs.
    """
    t = np.asarray(t_s, dtype=float)
    u = np.asarray(u, dtype=float).reshape(len(t), 6)
    fig, axes = plt.subplots(2, 3, figsize=(13, 6), constrained_layout=True, sharex=True)
    for k in range(6):
        ax = axes[k // 3, k % 3]
        lim = float((force_limit_N if k < 3 else torque_limit_Nm)[k % 3])
        ax.step(t, u[:, k], where="post", lw=1.2, color="tab:blue", label="input")
        ax.axhline(lim, color="tab:red", ls="--", lw=1.0, label=f"± {limit_label}")
        ax.axhline(-lim, color="tab:red", ls="--", lw=1.0)
        top = 1.15 * lim
        if actuator is not None:
            act = float(actuator[0 if k < 3 else 1][k % 3])
            if abs(act - lim) > 1e-12 * lim:
                ax.axhline(act, color="tab:red", ls=":", lw=1.0, label="± actuator limit")
                ax.axhline(-act, color="tab:red", ls=":", lw=1.0)
                top = max(top, 1.15 * act)
        peak = float(np.nanmax(np.abs(u[:, k]))) if len(t) else 0.0
        top = max(top, 1.05 * peak) if np.isfinite(peak) else top
        ax.set_ylim(-top, top)
        unit = "N" if k < 3 else "N·m"
        ax.set_title(f"{'force' if k < 3 else 'torque'} {AXES[k % 3]} [{unit}] (limit ± {lim:.4g})", loc="left",
                     fontsize="medium")
        ax.grid(True, alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    for ax in axes.flat:  # the actuator line may appear on another axis only
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="outside lower center", ncols=len(labels), fontsize="small")
    fig.suptitle(title)
    save_png(fig, path)
    return t, u


def guarded_plots(run: RunFiles, summary: dict[str, Any], figures: Mapping[str, Callable[[Path], object]]) -> None:
    """Draw each figure ``name -> draw(path)`` into ``run.run_dir/<name>.png`` and register it as ``png_<name>``.

    A figure that fails is skipped: a warning naming it goes to the log and to ``summary["warnings"]``; the
    summary's status is kept (the run's results do not depend on its pictures).

    Parameters
    ----------
    run : RunFolder
        The open run folder.
    summary : dict
        The stage's summary (before :meth:`RunFolder.finish`).
    figures : mapping of str to callable
        Figure name -> function drawing it to the path given.
    """
    for name, draw in figures.items():
        path = Path(run.run_dir) / f"{name}.png"
        try:
            draw(path)
        except Exception as exc:  # a picture must never lose the run
            message = f"plot {name}.png not written: {type(exc).__name__}: {exc}"
            _LOG.warning(message)
            summary.setdefault("warnings", []).append(message)
            plt.close("all")
            continue
        run.file(f"png_{name}", f"{name}.png")
