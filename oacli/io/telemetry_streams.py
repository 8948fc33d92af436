"""A tracking run's controller-rate topics as logged, for the estimators' own alignment (unordered, unaligned).

:func:`read_telemetry_streams` reads ``/state/measured``, ``/control/applied``, ``/control/command`` and, where
present, ``/localisation`` and ``/imu`` of a ``track``-like MCAP in file (arrival) order, up to the last intact
record of a cut file; :func:`oacli.estimation.alignment.align_records` aligns them by stamp. The scan itself is
:mod:`oacli.io.mcap_read`'s.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from oacli.io import mcap_schema as ms
from oacli.io.mcap_read import _json_messages, _Scan, _scan
from oacli.types import INPUT_DIM, STATE_DIM

__all__ = ["TelemetryStreams", "read_telemetry_streams"]


@dataclass(frozen=True)
class TelemetryStreams:
    """A tracking run's controller-rate topics as logged: every message in file (arrival) order, unaligned.

    What :func:`oacli.estimation.alignment.align_records` needs; unlike :func:`read_telemetry` nothing is required
    to be in time order or of equal length (flight telemetry is not).

    Attributes
    ----------
    path : Path
    t_measured, x_measured : ndarray, shape (M,), (M, 13)
        ``/state/measured`` stamps (the messages' own ``t``) and states.
    t_applied, u_applied : ndarray, shape (N,), (N, 6)
        ``/control/applied``.
    t_command, u_command : ndarray, shape (P,), (P, 6), optional
        ``/control/command`` (None when the topic is absent).
    config_yaml : str or None
        The attached resolved configuration.
    truncated : bool
        The file was cut (no footer); the streams hold what the intact records before the cut carry.
    bytes_read, bytes_total : int
        End of the intact part and size of the file [bytes].
    t_localisation, x_localisation : ndarray, shape (L,), (L, 13), optional
        ``/localisation`` message stamps (their ``stamp``, not their arrival time) and states, in arrival order
        (None when the topic is absent).
    t_imu, imu : ndarray, shape (N,), (N, 6), optional
        ``/imu`` stamps and readings ``[specific force m/s² (3), angular rate rad/s (3)]``, body frame.
    """

    path: Path
    t_measured: np.ndarray
    x_measured: np.ndarray
    t_applied: np.ndarray
    u_applied: np.ndarray
    t_command: np.ndarray | None
    u_command: np.ndarray | None
    config_yaml: str | None
    truncated: bool
    bytes_read: int
    bytes_total: int
    t_localisation: np.ndarray | None = None
    x_localisation: np.ndarray | None = None
    t_imu: np.ndarray | None = None
    imu: np.ndarray | None = None


def _as_list(value: Any) -> list:
    return value if isinstance(value, list) else [value]


def _raw_series(scan: _Scan, topic: str, keys: tuple[str, ...], width: int) -> tuple[np.ndarray, np.ndarray] | None:
    """``(t, values)`` of a JSON topic in file order, values the concatenation of ``keys`` (numbers or lists of
    numbers; None when the topic is absent)."""
    if topic not in scan.messages:
        return None
    records = _json_messages(scan, topic)
    try:
        arr = np.array([[r["t"], *(v for key in keys for v in _as_list(r[key]))] for r in records], dtype=float)
    except (KeyError, TypeError, ValueError) as exc:
        raise scan.fail(f"{topic}: malformed record ({exc!r})") from None
    arr = arr.reshape(-1, 1 + width)
    if not np.all(np.isfinite(arr)):
        raise scan.fail(f"{topic}: a record contains NaN or infinite values")
    return arr[:, 0], arr[:, 1:]


def read_telemetry_streams(path: Path) -> TelemetryStreams:
    """Read ``/state/measured``, ``/control/applied``, ``/control/command`` (and ``/localisation``, ``/imu`` when
    present) of a ``track``-like MCAP as logged.

    A cut file is read up to its last intact record (``truncated``); CRCs are checked.

    Parameters
    ----------
    path : Path

    Returns
    -------
    TelemetryStreams

    Raises
    ------
    InputError
        Unreadable or corrupt file, or ``/state/measured`` or ``/control/applied`` absent (the message lists the
        topics the file has and says when the file was cut).
    """
    wanted = (ms.TOPIC_STATE_MEASURED, ms.TOPIC_CONTROL_APPLIED, ms.TOPIC_CONTROL_COMMAND, ms.TOPIC_LOCALISATION,
              ms.TOPIC_IMU)
    scan = _scan(Path(path), True, frozenset(wanted))
    state_keys = ("position", "velocity", "quaternion", "angular_velocity")
    measured = _raw_series(scan, ms.TOPIC_STATE_MEASURED, state_keys, STATE_DIM)
    applied = _raw_series(scan, ms.TOPIC_CONTROL_APPLIED, ("force", "torque"), INPUT_DIM)
    command = _raw_series(scan, ms.TOPIC_CONTROL_COMMAND, ("force", "torque"), INPUT_DIM)
    localisation = _raw_series(scan, ms.TOPIC_LOCALISATION, ("stamp", *state_keys), 1 + STATE_DIM)
    imu = _raw_series(scan, ms.TOPIC_IMU, ("linear_acceleration", "angular_velocity"), 6)
    for topic, series in ((ms.TOPIC_STATE_MEASURED, measured), (ms.TOPIC_CONTROL_APPLIED, applied)):
        if series is None or series[0].size == 0:
            listed = ", ".join(f"{t} ({n})" for t, n in sorted(scan.counts.items())) or "none"
            cut = (f" (the file is cut at byte {scan.bytes_read} of {scan.bytes_total}: the topic may have been "
                   "written after the cut)") if scan.truncated else ""
            raise scan.fail(f"no {topic} messages{cut}; topics in the file: {listed}")
    data = scan.attachments.get(ms.CONFIG_ATTACHMENT)
    return TelemetryStreams(
        path=Path(path),
        t_measured=measured[0], x_measured=measured[1],  # type: ignore[index]
        t_applied=applied[0], u_applied=applied[1],  # type: ignore[index]
        t_command=None if command is None else command[0], u_command=None if command is None else command[1],
        config_yaml=None if data is None else data.decode("utf-8"),
        truncated=scan.truncated, bytes_read=scan.bytes_read, bytes_total=scan.bytes_total,
        t_localisation=None if localisation is None else localisation[1][:, 0],
        x_localisation=None if localisation is None else localisation[1][:, 1:],
        t_imu=None if imu is None else imu[0], imu=None if imu is None else imu[1],
    )
