"""What every oacli Rerun recording shares: the timeline, the shared entity names, colours, the application id and
the checks of the arrays logged (:mod:`oacli.io.rerun.writer` writes, :mod:`oacli.io.rerun.layout` lays out)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np
import rerun as rr

#: Timeline every oacli recording uses: simulated mission time since the start of the stage [s].
TIMELINE = "mission_time"

# Entity paths shared by the stage recordings (a fixed contract: tests and other stages read them).
WORLD = "world"
KEEP_IN = "world/keep_in"
KEEP_OUT = "world/keep_out"
ROBOT = "world/robot"
LOG = "log"

#: Child entities that :meth:`StageRecording.log_series` adds for ± limits.
LIMIT_UPPER = "limit_upper"
LIMIT_LOWER = "limit_lower"

def application_id(stage: str) -> str:
    """The Rerun application id of a stage's recording, ``oacli-<stage>`` (``oacli-plan``, ``oacli-track`` ...).

    The viewer keeps one blueprint per application id: distinct ids let several stages' recordings be open at
    once, each in its own layout.

    Parameters
    ----------
    stage : str
        Stage name.

    Returns
    -------
    str
    """
    return f"oacli-{stage}"


LogEntry = tuple[float, str, str]
"""A text log line: ``(t [s], level, message)``."""


class AxisLimits(Protocol):
    """Per-axis bounds a recording plots as ± limits (:class:`oacli.model.limits.MotionLimits`)."""

    @property
    def force_N(self) -> np.ndarray:
        """Force bound per world axis [N], shape (3,)."""
        ...

    @property
    def torque_Nm(self) -> np.ndarray:
        """Torque bound per body axis [N·m], shape (3,)."""
        ...

    @property
    def velocity_mps(self) -> np.ndarray:
        """Velocity bound per world axis [m/s], shape (3,)."""
        ...

    @property
    def angular_velocity_radps(self) -> np.ndarray:
        """Angular-rate bound per body axis [rad/s], shape (3,)."""
        ...


#: Astrobee is a 30 cm cube.
ASTROBEE_SIZE_M = 0.30

# RGBA colours (0-255).
KEEP_IN_COLOR = (80, 200, 120, 60)
KEEP_OUT_COLOR = (230, 60, 60, 110)
REFERENCE_COLOR = (90, 150, 255, 255)
ACTUAL_COLOR = (255, 170, 40, 255)
ROBOT_COLOR = (240, 220, 90, 140)
#: Per-axis series colours (x red, y green, z blue).
AXIS_COLORS = ((230, 60, 60, 255), (60, 180, 75, 255), (60, 110, 230, 255))
AXIS_NAMES = ("x", "y", "z")

_TEXT_LEVELS = {"WARNING": "WARN", "FATAL": "CRITICAL", "ERR": "ERROR"}



# ----------------------------------------------------------------------------------------------------------------
# Small helpers
# ----------------------------------------------------------------------------------------------------------------


def time_column(t_s: np.ndarray) -> rr.TimeColumn:
    """The ``mission_time`` column of ``send_columns`` from times [s], rounded to the nearest nanosecond.

    Parameters
    ----------
    t_s : ndarray, shape (N,)
        Mission times [s] (Rerun would truncate floats).

    Returns
    -------
    rerun.TimeColumn
    """
    ns = np.rint(np.asarray(t_s, dtype=float) * 1e9).astype(np.int64)
    return rr.TimeColumn(TIMELINE, duration=ns.astype("timedelta64[ns]"))


def _times(name: str, t: np.ndarray) -> np.ndarray:
    """Check a 1-D array of finite times [s] and return it as float64."""
    arr = np.asarray(t, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f"{name}: expected a 1-D array of times, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: times must be finite")
    return arr


def _points(name: str, p: np.ndarray) -> np.ndarray:
    """Check an (N, 3) array of finite positions [m]."""
    arr = np.asarray(p, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (N, 3), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: positions must be finite")
    return arr


def _rgba(color: Sequence[int] | np.ndarray) -> np.ndarray:
    """An RGB or RGBA colour (0-255) as a uint8 RGBA array of shape (4,)."""
    c = np.asarray(color, dtype=np.uint8).reshape(-1)
    if c.shape == (3,):
        c = np.append(c, np.uint8(255))
    if c.shape != (4,):
        raise ValueError(f"a colour needs 3 or 4 channels, got {c.shape}")
    return c


def _level(level: str) -> str:
    up = str(level).strip().upper()
    return _TEXT_LEVELS.get(up, up)
