"""From telemetry to measurement records, and back into time-stamp order ([ReSWARM2023] §5.4.3, §6.2.1).

On Astrobee the localisation (EKF) and the applied wrench (inverse FAM) arrive on separate topics whose messages
are often delayed and out of order; RATTLE sorted them by time stamp before the sequential estimator ([ReSWARM2023]
§6.2.1, Fig. 20). Here:

* :func:`order_by_time` sorts a whole batch of records (stable) and sets aside duplicated time stamps;
* :class:`ReorderBuffer` does it online: it holds back the ``window`` most recent records and releases the oldest
  one in time order; a record older than one already released is *late* and reported, never silently used.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from oacli.estimation.models import Measurement
from oacli.estimation.propagation import TIME_TOL_S
from oacli.types import Telemetry


def measurements_from_telemetry(
    tel: Telemetry, *, linear_acceleration_mps2: np.ndarray | None = None,
    angular_acceleration_radps2: np.ndarray | None = None,
) -> list[Measurement]:
    """One :class:`Measurement` per controller step of a tracking run.

    Parameters
    ----------
    tel : Telemetry
        A ``track`` run: ``x_measured`` and ``u_applied`` at ``t_ctrl`` (the truth is not used).
    linear_acceleration_mps2, angular_acceleration_radps2 : ndarray, shape (K, 3), optional
        Accelerations measured at ``t_ctrl`` (world-frame ``f/m``; body-frame ``ω̇``).

    Returns
    -------
    list of Measurement
        In the telemetry's order (time order for a valid track record).
    """
    k = len(tel.t_ctrl)
    for name, acc in (("linear_acceleration_mps2", linear_acceleration_mps2),
                      ("angular_acceleration_radps2", angular_acceleration_radps2)):
        if acc is not None and np.shape(acc) != (k, 3):
            raise ValueError(f"{name}: expected shape ({k}, 3), got {np.shape(acc)}")
    return [
        Measurement(
            t=float(tel.t_ctrl[i]),
            x_measured=tel.x_measured[i],
            u_applied=tel.u_applied[i],
            linear_acceleration_mps2=None if linear_acceleration_mps2 is None else linear_acceleration_mps2[i],
            angular_acceleration_radps2=None if angular_acceleration_radps2 is None else angular_acceleration_radps2[i],
        )
        for i in range(k)
    ]


@dataclass(frozen=True)
class OrderedRecords:
    """Records sorted by time stamp.

    Attributes
    ----------
    records : tuple of Measurement
        Strictly increasing time stamps.
    duplicates : tuple of Measurement
        Records whose time stamp repeats an earlier one (within :data:`TIME_TOL_S`); the first arrival is kept.
    reordered : int
        How many records were not in time order on arrival.
    """

    records: tuple[Measurement, ...]
    duplicates: tuple[Measurement, ...]
    reordered: int


def order_by_time(records: Iterable[Measurement]) -> OrderedRecords:
    """Sort records by time stamp (stable), setting duplicated time stamps aside.

    Parameters
    ----------
    records : iterable of Measurement
        In arrival order.

    Returns
    -------
    OrderedRecords
    """
    arrived = list(records)
    order = sorted(range(len(arrived)), key=lambda i: (arrived[i].t, i))
    kept: list[Measurement] = []
    duplicates: list[Measurement] = []
    for i in order:
        rec = arrived[i]
        if kept and rec.t - kept[-1].t <= TIME_TOL_S:
            duplicates.append(rec)
        else:
            kept.append(rec)
    reordered = sum(1 for pos, i in enumerate(order) if pos != i)
    return OrderedRecords(tuple(kept), tuple(duplicates), reordered)


class ReorderBuffer:
    """Online time-stamp reordering with a fixed look-back (a min-heap of the last ``window`` records).

    Parameters
    ----------
    window : int
        Records held back, >= 0. A record displaced by fewer than ``window`` positions from its place in time
        order is released in order; ``window = 0`` releases every record at once.
    """

    def __init__(self, window: int) -> None:
        if window < 0:
            raise ValueError("window must be >= 0")
        self.window = int(window)
        self._heap: list[tuple[float, int, Measurement]] = []
        self._count = itertools.count()
        self.last_released_t = -np.inf

    def __len__(self) -> int:
        return len(self._heap)

    def push(self, record: Measurement) -> tuple[list[Measurement], list[Measurement]]:
        """Add one record.

        A record is *late* when its time stamp is not after the last released one (it arrived more than ``window``
        records too late, or repeats a time stamp): it cannot be used without rewinding the filter.

        Parameters
        ----------
        record : Measurement

        Returns
        -------
        released : list of Measurement
            In time order.
        late : list of Measurement
        """
        if record.t <= self.last_released_t + TIME_TOL_S:
            return [], [record]
        heapq.heappush(self._heap, (record.t, next(self._count), record))
        released: list[Measurement] = []
        late: list[Measurement] = []
        while len(self._heap) > self.window:
            self._release(released, late)
        return released, late

    def flush(self) -> tuple[list[Measurement], list[Measurement]]:
        """Release every held record in time order.

        Returns
        -------
        released : list of Measurement
        late : list of Measurement
            Duplicated time stamps.
        """
        released: list[Measurement] = []
        late: list[Measurement] = []
        while self._heap:
            self._release(released, late)
        return released, late

    def _release(self, released: list[Measurement], late: list[Measurement]) -> None:
        _, _, rec = heapq.heappop(self._heap)
        if rec.t <= self.last_released_t + TIME_TOL_S:
            late.append(rec)
            return
        self.last_released_t = rec.t
        released.append(rec)


def shuffle_locally(records: Sequence[Measurement], max_displacement: int, rng: np.random.Generator) -> list:
    """Permute records so that each lands fewer than ``max_displacement`` places from its own (arrival jitter).

    Sorting by ``index + uniform(0, max_displacement)`` moves no record by ``max_displacement`` places or more.

    Parameters
    ----------
    records : sequence of Measurement
    max_displacement : int
        Bound on how far a record moves, >= 1.
    rng : numpy.random.Generator

    Returns
    -------
    list of Measurement
    """
    keys = np.arange(len(records)) + rng.uniform(0.0, max_displacement, len(records))
    return [records[i] for i in np.argsort(keys, kind="stable")]
