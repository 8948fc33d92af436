"""Telemetry by time, not by position: estimator records from separately logged, imperfect streams.

Flight telemetry is not clean ([ReSWARM2023] §5.4.2-§5.4.3, §6.2.1): localisation messages arrive late and out of
order, some are lost, whole controller cycles can be missing from the log, and a message can be logged twice. The
localisation (measured state) and the inputs (applied wrench; the commanded one as a fallback) are logged on separate
topics, so records are built by **time stamp**, never by position in the file:

* measurements go, in arrival order, through a :class:`~oacli.estimation.preprocessing.ReorderBuffer` of
  ``reorder_window`` messages: those displaced by less than the window are put back in time order (counted as
  ``reordered``), later ones cannot be used without rewinding and are set aside (``late``), a repeated time stamp
  is dropped (``duplicates``);
* each control instant with a known input but no measurement becomes an *input-only* record
  (``Measurement.state_measured = False``): the estimators propagate through it, so a lost localisation message is
  simply absent instead of merging two control periods under one held input (``input_only``);
* a measurement stamped between two control instants (a localisation faster than, or not synchronised with, the
  controller) gets the input held since the last control instant, when that instant's input is known and the next
  instant has not come yet (``held``);
* an input missing from the applied record is taken from the logged command history when it has that stamp, clipped
  to the actuator limits when they are given (``bridged``);
* when the input over an interval is unknown -- a control instant with neither an applied nor a commanded input, or
  a gap in the stamps longer than 1.5 control periods -- the record after it starts a new segment
  (``Measurement.starts_segment``: the input over the interval before it is unknown; ``gaps``, ``segments``). A gap
  in the stamps after a known input gets an input-only record at the first lost control instant (``lost_instants``;
  its own input is unknown, a zero placeholder), so the last known input is held for exactly its control period;
  after a single lost instant the unknown interval spans one control period, over which the controller held one
  (unknown) wrench. The batch estimator predicts that wrench from its neighbours, with the prediction's error
  measured on the run (or takes its force from the accelerometer when ``/imu`` survived), as process noise over
  the gap (:func:`oacli.estimation.lost_inputs.lost_input_model`,
  :func:`~oacli.estimation.lost_inputs.segment_link_weights`). The sequential filter bridges a single lost instant the
  same way (the neighbours' mean, the error's covariance as process noise; ``gaps_bridged``) and re-initialises the
  robot state only where the batch cuts (``segment_restarts``). An input is never held silently across a gap.

The control period is the median spacing of the input stamps (robust to dropped records).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from oacli.estimation.models import Measurement
from oacli.estimation.preprocessing import ReorderBuffer

__all__ = ["AlignmentReport", "align_records"]

_STAMP_RESOLUTION_S = 1e-6
_GAP_FACTOR = 1.5


def _key(t: float) -> int:
    return round(float(t) / _STAMP_RESOLUTION_S)


@dataclass(frozen=True)
class AlignmentReport:
    """What :func:`align_records` did with the streams (counts of messages or control instants).

    Attributes
    ----------
    measurements_received : int
        Localisation messages in the file.
    reordered : int
        Measurements that arrived after one with a later stamp and were put back in order by the reorder window.
    late : int
        Measurements that arrived too late for the reorder window (set aside, not used).
    duplicates : int
        Measurements whose stamp repeats an earlier one (the first arrival is kept).
    input_duplicates : int
        Applied-input messages whose stamp repeats an earlier one.
    input_only : int
        Control instants with a known input but no usable measurement (propagated through).
    bridged : int
        Control instants whose applied input is missing and was taken from the command history.
    gaps : int
        Intervals over which the input is unknown (each starts a new segment).
    unusable : int
        Control instants dropped for lack of both a measurement and a usable input link.
    segments : int
        Segments of records linked by the process model.
    held : int
        Measurements between control instants given the input held since the last one (reported only when not 0,
        so telemetry on the control grid keeps its summary).
    lost_instants : int
        Gaps after a known input whose first lost control instant got an input-only record with an unknown input
        (reported only when not 0).
    control_period_s : float
        Median spacing of the input stamps [s] (NaN with fewer than two).
    """

    measurements_received: int
    reordered: int
    late: int
    duplicates: int
    input_duplicates: int
    input_only: int
    bridged: int
    gaps: int
    unusable: int
    segments: int
    control_period_s: float
    held: int = 0
    lost_instants: int = 0

    def as_dict(self) -> dict[str, float | int]:
        """The counts as a plain dict (for ``summary.json``).

        Returns
        -------
        dict
        """
        out = asdict(self)
        for key in ("held", "lost_instants"):
            if not out[key]:
                del out[key]
        return out


def _first_by_stamp(t: np.ndarray, values: np.ndarray) -> tuple[dict[int, np.ndarray], int]:
    """Values keyed by stamp (first arrival kept) and the number of repeated stamps."""
    out: dict[int, np.ndarray] = {}
    repeats = 0
    for ti, v in zip(np.asarray(t, dtype=float), np.asarray(values, dtype=float), strict=True):
        k = _key(ti)
        if k in out:
            repeats += 1
        else:
            out[k] = v
    return out, repeats


def align_records(
    t_measured: np.ndarray,
    x_measured: np.ndarray,
    t_applied: np.ndarray,
    u_applied: np.ndarray,
    *,
    reorder_window: int,
    t_command: np.ndarray | None = None,
    u_command: np.ndarray | None = None,
    input_limits: np.ndarray | None = None,
) -> tuple[list[Measurement], AlignmentReport]:
    """Estimator records from the measured-state and input streams, aligned by time stamp (module docstring).

    Parameters
    ----------
    t_measured, x_measured : ndarray, shape (M,), (M, 13)
        Localisation messages in **arrival** (file) order: stamps [s] and measured states.
    t_applied, u_applied : ndarray, shape (N,), (N, 6)
        Applied inputs (held from their stamp to the next control instant) [N, N·m].
    reorder_window : int
        Messages the reorder buffer holds back, >= 0.
    t_command, u_command : ndarray, shape (P,), (P, 6), optional
        The command history, to bridge inputs missing from the applied record.
    input_limits : ndarray, shape (6,), optional
        Actuator limits [N, N·m] a bridged command is clipped to (the actuators saturate it).

    Returns
    -------
    records : list of Measurement
        Strictly increasing stamps; the first record has a measured state and starts a segment.
    report : AlignmentReport
    """
    t_measured = np.asarray(t_measured, dtype=float).reshape(-1)
    x_measured = np.asarray(x_measured, dtype=float).reshape(-1, 13)
    applied, input_duplicates = _first_by_stamp(t_applied, np.reshape(u_applied, (-1, 6)))
    command: dict[int, np.ndarray] = {}
    if t_command is not None and u_command is not None:
        command, _ = _first_by_stamp(t_command, np.reshape(u_command, (-1, 6)))

    # Measurements through the reorder window, in arrival order.
    buffer = ReorderBuffer(reorder_window)
    states: dict[int, tuple[float, np.ndarray]] = {}
    seen: set[int] = set()
    late = duplicates = reordered = 0
    newest = -np.inf
    zero_u = np.zeros(6)

    def take(released: list[Measurement], dropped: list[Measurement]) -> None:
        nonlocal late, duplicates
        for rec in released:
            states[_key(rec.t)] = (rec.t, np.array(rec.x_measured))
        for rec in dropped:
            if _key(rec.t) in seen:
                duplicates += 1
            else:
                late += 1

    for t, x in zip(t_measured, x_measured, strict=True):
        k = _key(t)
        if k in seen:
            duplicates += 1
            continue
        if t < newest:
            reordered += 1
        newest = max(newest, t)
        released, dropped = buffer.push(Measurement(t, x, zero_u))
        take(released, dropped)
        seen.add(k)
    take(*buffer.flush())
    reordered -= late  # a message too late for the window was not put back in order

    input_keys = sorted(set(applied) | set(command))
    stamps = sorted(set(states) | set(input_keys))
    period = float(np.median(np.diff(np.array(input_keys) * _STAMP_RESOLUTION_S))) if len(input_keys) > 1 else np.nan
    limits = None if input_limits is None else np.asarray(input_limits, dtype=float)

    records: list[Measurement] = []
    bridged = input_only = gaps = unusable = segments = held = lost = 0
    last_input: tuple[float, np.ndarray] | None = None  # the last control instant with a known input
    prev_t: float | None = None
    prev_input_known = False
    prev_x: np.ndarray | None = None
    for key in stamps:
        t = key * _STAMP_RESOLUTION_S if key not in states else states[key][0]
        if key in applied:
            u, known = applied[key], True
        elif key in command:
            u = command[key] if limits is None else np.clip(command[key], -limits, limits)
            known = True
            bridged += 1
        elif (last_input is not None and np.isfinite(period) and key in states
              and t - last_input[0] < period - _STAMP_RESOLUTION_S):
            u, known = last_input[1], True  # between control instants: the input is still held
            held += 1
        else:
            u, known = zero_u, False
        if known and (key in applied or key in command):
            last_input = (t, u)
        elif key in input_keys:
            last_input = None
        linked = prev_t is not None and prev_input_known and (
            not np.isfinite(period) or t - prev_t <= _GAP_FACTOR * period)
        if prev_t is not None and not linked:
            gaps += 1
            if prev_input_known and prev_x is not None and np.isfinite(period) and t - prev_t > 1.5 * period:
                # The first control instant lost in the gap: an input-only record with an unknown input, so the last
                # known input is held for its control period only (module docstring). Later lost instants would
                # only add unconstrained states: the interval after this record is unknown either way.
                t_v = prev_t + period
                x_v = prev_x.copy()  # a seed for the solver only
                x_v[0:3] += x_v[3:6] * period
                records.append(Measurement(t_v, x_v, zero_u, state_measured=False))
                lost += 1
        if key in states:
            x = states[key][1]
            measured = True
        else:
            if not linked or prev_x is None:
                unusable += 1  # an input with neither a state nor a link to one
                prev_t, prev_input_known = None, False
                continue
            x = prev_x.copy()  # a seed for the solver only: the previous state moved on at its velocity
            x[0:3] += x[3:6] * (t - prev_t)  # type: ignore[operator]
            measured = False
            input_only += 1
        if not linked:
            segments += 1
        records.append(Measurement(t, x, u, state_measured=measured, starts_segment=bool(records) and not linked))
        prev_t, prev_input_known, prev_x = t, known, x
    report = AlignmentReport(
        measurements_received=int(t_measured.size), reordered=max(reordered, 0), late=late, duplicates=duplicates,
        input_duplicates=input_duplicates, input_only=input_only, bridged=bridged, gaps=gaps, unusable=unusable,
        segments=segments, control_period_s=period, held=held, lost_instants=lost,
    )
    return records, report
