"""Load reference trajectories from files: RATTLE/ReSWARM result folders, 19-row CSVs, oacli MCAPs.

Formats (those of the public data of [RattleData], docs/references.md):

* a folder of ``results_{pos,vel,ori,ome}_0.dat`` (optionally ``results_input_0.dat``): whitespace-separated
  columns, first column time [s], then position [m], velocity [m/s], quaternion [x, y, z, w], angular velocity
  [rad/s] (and force [N]);
* a ``.csv`` of 19 rows × N columns: position (3), velocity (3), quaternion (4, x y z w), angular velocity (3),
  force (3), torque (3), one column per sample every ``sample_period_s``; or of N rows × 20 columns with a time
  column first and the same 19 quantities;
* an ``.mcap`` written by an oacli stage: its ``/trajectory`` topic.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from oacli.errors import InputError
from oacli.model import quaternion as quat
from oacli.types import Trajectory

_DAT_PARTS = {"pos": 3, "vel": 3, "ori": 4, "ome": 3}


#: Largest reference table read [bytes] (RATTLE's files are tens of KiB).
MAX_TABLE_BYTES = 64 * 1024 * 1024


def _load_table(path: Path, delimiter: str | None = None) -> np.ndarray:
    import io
    import os

    from oacli.io.regular_files import open_regular

    fd = open_regular(path, "a reference table")  # a FIFO or a device: exit 2 without blocking
    with os.fdopen(fd, "rb") as f:
        raw = f.read(MAX_TABLE_BYTES + 1)
    if len(raw) > MAX_TABLE_BYTES:
        raise InputError(f"{path}: larger than {MAX_TABLE_BYTES} bytes; not a reference table")
    try:
        data = np.loadtxt(io.StringIO(raw.decode("utf-8")), delimiter=delimiter, ndmin=2)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read a numeric table ({exc})") from exc
    if not np.all(np.isfinite(data)):
        raise InputError(f"{path}: contains NaN or infinite values")
    return data


def _build(path: Path, t: np.ndarray, x: np.ndarray, u: np.ndarray, frame: str) -> Trajectory:
    norms = np.linalg.norm(x[:, 6:10], axis=1)
    if np.any(np.abs(norms - 1.0) > 1e-3):
        bad = int(np.argmax(np.abs(norms - 1.0)))
        raise InputError(f"{path}: sample {bad}: quaternion norm {norms[bad]:.6g} is not 1")
    x = x.copy()
    x[:, 6:10] = quat.normalize(x[:, 6:10])
    if np.any(np.diff(t) <= 0):
        raise InputError(f"{path}: time stamps must be strictly increasing")
    t0 = t[0]
    return Trajectory(t - t0, x, u, name=f"reference:{path.name}", frame=frame)


def load_dat_folder(folder: Path, frame: str = "world") -> Trajectory:
    """Load a RATTLE ``results_*_0.dat`` folder (see the module docstring)."""
    columns = []
    t = None
    for part, width in _DAT_PARTS.items():
        path = folder / f"results_{part}_0.dat"
        if not path.is_file():
            raise InputError(f"{folder}: missing {path.name} (a reference folder needs pos, vel, ori and ome files)")
        table = _load_table(path)
        if table.shape[1] != width + 1:
            raise InputError(f"{path}: expected {width + 1} columns (time + {width}), found {table.shape[1]}")
        if t is None:
            t = table[:, 0]
        elif table.shape[0] != t.size or not np.allclose(table[:, 0], t):
            raise InputError(f"{path}: time column differs from results_pos_0.dat")
        columns.append(table[:, 1:])
    assert t is not None
    x = np.hstack(columns)
    u = np.zeros((t.size, 6))
    input_path = folder / "results_input_0.dat"
    if input_path.is_file():
        table = _load_table(input_path)
        if table.shape[0] == t.size and table.shape[1] >= 4:
            u[:, : min(6, table.shape[1] - 1)] = table[:, 1:7]
    return _build(folder, t, x, u, frame)


def load_csv(path: Path, sample_period_s: float, frame: str = "world") -> Trajectory:
    """Load a 19-row (RATTLE excitation) or 20-column (time first) CSV reference."""
    table = _load_table(path, delimiter=",")
    if table.shape[0] == 19 and table.shape[1] != 20:
        data = table.T
        t = sample_period_s * np.arange(data.shape[0])
    elif table.shape[1] == 20:
        t, data = table[:, 0], table[:, 1:]
    else:
        raise InputError(
            f"{path}: expected 19 rows (one column per sample) or 20 columns (time + 19), found {table.shape}"
        )
    return _build(path, t, data[:, :13], data[:, 13:19], frame)


def load_reference(path: Path, *, sample_period_s: float = 0.5, frame: str = "world") -> Trajectory:
    """Load a reference from a DAT folder, a CSV file or an oacli MCAP (``/trajectory`` topic)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: reference not found")
    if path.is_dir():
        return load_dat_folder(path, frame)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return load_csv(path, sample_period_s, frame)
    if suffix == ".mcap":
        from oacli.io.mcap_io import read_trajectory

        return read_trajectory(path, "/trajectory")
    raise InputError(f"{path}: unknown reference format (expected a results_*_0.dat folder, .csv or .mcap)")
