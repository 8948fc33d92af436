"""The mission's status: the worst of its own stages, a stop on an ``unsafe`` stage, a failure reported beside it.

Rules (docs/mission.md, "Status"):

* the mission's status is the worst of its own stages (the baselines are counterfactual flights: their statuses are
  reported, not the mission's): ``unsafe`` > ``degraded`` > ``ok``;
* an ``unsafe`` stage stops the mission: no later stage flies (the robot holds where that stage's flight ended);
  a ``no_solution`` stage stops it too (nothing to fly);
* a later failure (an error in a stage or while writing the outputs, an interruption) is reported beside the
  worst status (``error``, ``failed_stage``), never in its place: a mission with an ``unsafe`` stage stays
  ``unsafe`` (exit 4) whatever happens after;
* the mission's last flight (segment 3, back to A) must arrive: a flight whose true position never stays within
  :data:`oacli.mission.compare.ARRIVAL_TOLERANCE_M` of its goal ends the mission ``failed`` with reason
  ``not_arrived`` (exit 1), not ``degraded``.

No I/O here: :mod:`oacli.mission.run` hands in the stages' summaries.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from oacli.errors import OacliError
from oacli.status import DEGRADED, EXIT_CODES, FAILED, INTERRUPTED, NO_SOLUTION, OK, UNSAFE

STOP_STATUSES = (UNSAFE, NO_SOLUTION)
"""Statuses of a mission stage after which no later stage runs."""

_RANK = {OK: 0, DEGRADED: 1, INTERRUPTED: 2, FAILED: 3, NO_SOLUTION: 4, UNSAFE: 5}
"""Which status wins: a safety finding over any failure after it, a failure over a weakened promise."""


@dataclass
class MissionVerdict:
    """The findings of a mission's own stages and what ended it.

    Attributes
    ----------
    reasons : list of dict
        ``{level, kind, message}`` per finding (the stages' ``status_reasons`` prefixed with the stage's key, plus
        the mission's own: ``not_arrived``, ``stopped``, ``failed``).
    """

    reasons: list[dict[str, str]] = field(default_factory=list)

    def add(self, level: str, kind: str, message: str) -> None:
        """Record one finding (``level`` one of ok-ranked statuses: degraded, unsafe, no_solution, failed ...)."""
        self.reasons.append({"level": level, "kind": kind, "message": message})

    def add_stage(self, key: str, summary: Mapping[str, Any]) -> None:
        """Record the findings of one mission stage's summary (nothing for an ``ok`` stage)."""
        status = summary.get("status")
        if status == OK:
            return
        if summary.get("handled"):  # a failure the mission worked around (an estimate not handed on)
            self.add(DEGRADED, f"{summary.get('stage', 'stage')}_failed", f"{key}: {summary.get('error')}")
            return
        reasons = summary.get("status_reasons") or [
            {"level": status, "kind": "stage", "message": str(summary.get("error") or f"ended {status}")}]
        for r in reasons:
            level = r.get("level") if r.get("level") in _RANK else DEGRADED
            self.add(str(level), str(r.get("kind", "stage")), f"{key}: {r.get('message', '?')}")

    @property
    def status(self) -> str:
        """The worst level recorded (``ok`` without findings)."""
        return max((r["level"] for r in self.reasons), key=_RANK.__getitem__, default=OK)

    def apply(self, summary: dict[str, Any]) -> dict[str, Any]:
        """Set ``status`` and ``status_reasons`` (worst first) of ``summary``; returns it."""
        summary["status"] = self.status
        summary["status_reasons"] = sorted(self.reasons, key=lambda r: -_RANK[r["level"]])
        return summary


def stage_verdict(results: Mapping[str, Mapping[str, Any]], own_keys: Iterable[str]) -> MissionVerdict:
    """The findings of the mission's own stages (``own_keys``, in order; the baselines left out by the caller).

    Parameters
    ----------
    results : mapping
        Each stage's summary by key.
    own_keys : iterable of str
        The keys of the mission's own stages that ran.

    Returns
    -------
    MissionVerdict
    """
    verdict = MissionVerdict()
    for key in own_keys:
        if key in results:
            verdict.add_stage(key, results[key])
    return verdict


def stop_reason(key: str, summary: Mapping[str, Any]) -> str | None:
    """Why the mission stops after stage ``key`` (None: it goes on).

    Parameters
    ----------
    key : str
        The stage's key.
    summary : mapping
        Its summary.

    Returns
    -------
    str or None
    """
    status = summary.get("status")
    if status == UNSAFE:
        return (f"{key} ended unsafe: the mission stops there (the robot holds where that flight ended; no later "
                f"stage flies)")
    if status == NO_SOLUTION:
        return f"{key} found no solution: the mission stops there (nothing to fly)"
    return None


class MissionStageError(OacliError):
    """A mission stopped by an error in one of its stages; the exit code is the mission's status's.

    A stage's own error code (2 for a config it refused) would read as bad input to the mission; the mission's
    config was valid (it was checked before anything ran), so the mission's status decides: ``failed`` exits 1,
    ``unsafe`` (an earlier stage) 4.
    """

    def __init__(self, problems: list[str] | str, status: str) -> None:
        super().__init__(problems)
        self.exit_code = EXIT_CODES.get(status, 1)


__all__ = ["STOP_STATUSES", "MissionStageError", "MissionVerdict", "stage_verdict", "stop_reason"]


def plan_above_nominal(reference: Mapping[str, Any] | None, track: Mapping[str, Any] | None,
                       tolerance_N: float = 1e-6) -> str | None:
    """Segment 3's flown reference asks more force than the nominal MPC of its tube may command, or None.

    The plan's force cap follows the tube's tightened bound ``Ū = U ⊖ K Z`` ([Doerr2021] Eq. 27) only down to
    :data:`oacli.mission.configs.NOMINAL_FLOOR_SHARE` of its share (a heavy payload's Ū left the planner without a
    path): where that floor binds, the nominal MPC lags the part of the plan above Ū. The tube's promise holds (its
    own status says so); the flight just cannot follow the plan as planned, which the mission reports as
    ``degraded`` (``plan_above_nominal``).

    Parameters
    ----------
    reference : mapping or None
        The summary of the stage whose trajectory the flight tracks (``segment-3/smooth``): its
        ``max_force_per_axis_N`` [N], world axes.
    track : mapping or None
        The tube flight's summary: its ``tightened_force_N`` ``[[lower, upper]] × 3`` [N] (absent for standard MPC).

    Returns
    -------
    str or None
        The finding's message, naming the axes and forces.
    """
    if not reference or not track:
        return None
    asked, bounds = reference.get("max_force_per_axis_N"), track.get("tightened_force_N")
    if asked is None or bounds is None:
        return None
    nominal = [min(-float(lo), float(hi)) for lo, hi in bounds]
    over = [(axis, float(f), u) for axis, f, u in zip("xyz", asked, nominal, strict=True) if float(f) > u + tolerance_N]
    if not over:
        return None
    parts = ", ".join(f"{axis} {f:.3g} N > Ū {u:.3g} N" for axis, f, u in over)
    return (f"segment-3: the reference asks more force than the tube's nominal MPC may command ({parts}); the flight "
            f"lags that part of the plan (the plan's force cap stops at a floor so that a path exists)")
