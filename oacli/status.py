"""Run statuses: what ``summary.json`` says about how a stage's run went, and the exit code it maps to.

``status`` is one of

* ``ok`` — the run did what was asked, with no finding below;
* ``degraded`` — it finished, but a promise was weakened: the tube assumption was violated (a disturbance beyond
  W, the state outside the promised tube), solves failed and fallbacks or the safe hold drove the robot, an
  estimate or an SCP did not converge, a commanded input exceeded an actuator limit (saturated);
* ``unsafe`` — the *true* state left a keep-in zone, entered a keep-out zone or broke a hard limit (velocity,
  angular rate), or a stage's output trajectory does;
* ``no_solution`` — the stage finished without a result (no plan within the budget);
* ``failed`` — an error stopped the stage (the run folder is incomplete);
* ``interrupted`` — the user stopped it (Ctrl-C; the run folder is incomplete).

Findings have a precedence: ``unsafe`` > ``degraded`` > ``ok``; the summary lists every reason
(``status_reasons``: ``{level, kind, message}``). ``degraded`` exits 0 with a warning, ``unsafe`` exits 4,
``no_solution`` 3, ``failed`` 1 (or the error's own code), ``interrupted`` 130.

No I/O here: the stages build a :class:`StatusReport`, the CLI prints :func:`warning_line` and exits with
:func:`exit_code`.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

OK = "ok"
DEGRADED = "degraded"
UNSAFE = "unsafe"
NO_SOLUTION = "no_solution"
FAILED = "failed"
INTERRUPTED = "interrupted"
STATUSES = (OK, DEGRADED, UNSAFE, NO_SOLUTION, FAILED, INTERRUPTED)

#: Statuses of a run that ran to its end and wrote every file (see :mod:`oacli.io.runfolder`).
COMPLETE_STATUSES = frozenset({OK, DEGRADED, UNSAFE, NO_SOLUTION})

#: Process exit code per status.
EXIT_CODES = {OK: 0, DEGRADED: 0, UNSAFE: 4, NO_SOLUTION: 3, FAILED: 1, INTERRUPTED: 130}

_RANK = {OK: 0, DEGRADED: 1, UNSAFE: 2}

#: Mode words a controller step's ``SolveInfo.status`` starts with when no fresh solve drove it.
FALLBACK_MODES = ("fallback", "lqr", "hold")
SAFE_HOLD_MODE = "hold"

#: Violation kinds of the safety block that make a run unsafe; ``input`` (a saturated command) degrades it.
UNSAFE_KINDS = ("keep_in", "keep_out", "velocity", "angular_velocity")


@dataclass(frozen=True)
class Reason:
    """One finding: its level (``degraded`` or ``unsafe``), a short machine key and a sentence for people."""

    level: str
    kind: str
    message: str

    def as_dict(self) -> dict[str, str]:
        return {"level": self.level, "kind": self.kind, "message": self.message}


class StatusReport:
    """Collects the findings of a run and decides its status by precedence.

    Parameters
    ----------
    base : str
        ``ok`` (findings decide) or a terminal status (``no_solution``) that findings do not override.
    """

    def __init__(self, base: str = OK) -> None:
        if base not in STATUSES:
            raise ValueError(f"unknown status {base!r}")
        self.base = base
        self.reasons: list[Reason] = []

    def unsafe(self, kind: str, message: str) -> None:
        """Record a finding that makes the run unsafe."""
        self.reasons.append(Reason(UNSAFE, kind, message))

    def degraded(self, kind: str, message: str) -> None:
        """Record a finding that degrades the run."""
        self.reasons.append(Reason(DEGRADED, kind, message))

    @property
    def status(self) -> str:
        """``base`` unless it is ``ok``; then the most severe finding's level (``ok`` without findings)."""
        if self.base != OK:
            return self.base
        return max((r.level for r in self.reasons), key=_RANK.__getitem__, default=OK)

    def apply(self, summary: dict[str, Any]) -> dict[str, Any]:
        """Set ``summary["status"]`` and ``summary["status_reasons"]`` (most severe first); returns ``summary``."""
        summary["status"] = self.status
        ordered = sorted(self.reasons, key=lambda r: -_RANK[r.level])
        summary["status_reasons"] = [r.as_dict() for r in ordered]
        return summary


def _when(first_time_s: float | None) -> str:
    return "" if first_time_s is None else f"first at t = {first_time_s:.2f} s, "


def describe_violation(kind: str, entry: Mapping[str, Any], samples: str = "plant samples") -> str:
    """A sentence for one entry of a safety block (``count``, ``first_time_s``, ``worst_depth``, ``unit``)."""
    n, depth, unit = entry["count"], entry["worst_depth"], entry["unit"]
    when = _when(entry.get("first_time_s"))
    if kind == "keep_in":
        return f"the true state left the keep-in on {n} {samples} ({when}up to {depth:.3g} {unit} outside)"
    if kind == "keep_out":
        return f"the robot entered a keep-out zone on {n} {samples} ({when}up to {depth:.3g} {unit} deep)"
    if kind == "velocity":
        return f"the velocity limit was exceeded on {n} {samples} ({when}by up to {depth:.3g} {unit})"
    if kind == "angular_velocity":
        return f"the angular-rate limit was exceeded on {n} {samples} ({when}by up to {depth:.3g} {unit})"
    if kind == "input":
        return (f"the commanded input exceeded an actuator limit on {n} control steps ({when}by up to "
                f"{100 * depth:.3g} % of the limit; the actuators saturated it)")
    return f"{kind}: {n} violations ({when}up to {depth:.3g} {unit})"


def add_safety_reasons(report: StatusReport, safety: Mapping[str, Any], samples: str = "plant samples") -> None:
    """Findings of a safety block (:func:`oacli.metrics.safety_block`): keep-in, keep-out and the velocity and
    angular-rate limits make a run unsafe; a command beyond an actuator limit degrades it."""
    for kind in (*UNSAFE_KINDS, "input"):
        entry = safety.get(kind)
        if entry is None or not entry["count"]:
            continue
        message = describe_violation(kind, entry, samples)
        if kind == "input":
            report.degraded(kind, message)
        else:
            report.unsafe(kind, message)


def add_output_trajectory_reasons(report: StatusReport, summary: Mapping[str, Any], what: str) -> None:
    """Findings of a stage's output trajectory (plan, smooth): one that collides or breaks a limit is unsafe.

    Reads ``collision_free`` (exact continuous check), ``dense_check.ok`` (independent re-check) and
    ``within_limits`` (force, torque, velocity, angular rate) where present.
    """
    if summary.get("collision_free") is False:
        first = summary.get("first_collision") or {}
        at = f" at t = {first['t_s']:.2f} s ({first.get('kind')})" if "t_s" in first else ""
        report.unsafe("collision", f"the {what} leaves the free space{at} (exact continuous check)")
    dense = summary.get("dense_check")
    if isinstance(dense, Mapping) and dense.get("ok") is False:
        report.unsafe("dense_check", f"the {what} fails the independent dense re-check (min clearance "
                                     f"{dense.get('min_clearance_m', float('nan')):.3g} m)")
    if summary.get("within_limits") is False:
        report.unsafe("limits", f"the {what} exceeds a force, torque, velocity or angular-rate limit")


def mode_word(status: str) -> str:
    """The leading word of a controller step's status (``"fallback (infeasible)"`` → ``"fallback"``)."""
    m = re.match(r"[A-Za-z]+", status)
    return m.group(0).lower() if m else ""


def controller_mode_counts(statuses: Iterable[str]) -> dict[str, int]:
    """``fallback_steps`` (steps driven by a fallback, an LQR law or the safe hold) and ``safe_hold_steps``,
    counted from the mode word each step's ``SolveInfo.status`` starts with."""
    words = [mode_word(s) for s in statuses]
    return {
        "fallback_steps": sum(w in FALLBACK_MODES for w in words),
        "safe_hold_steps": sum(w == SAFE_HOLD_MODE for w in words),
    }


def warning_line(summary: Mapping[str, Any]) -> str | None:
    """The one line a non-``ok`` run prints on stderr (None for ``ok``), naming what happened."""
    status = summary.get("status", OK)
    if status == OK:
        return None
    stage = summary.get("stage", "run")
    reasons = [r["message"] for r in summary.get("status_reasons", ())]
    if not reasons and summary.get("error"):
        reasons = [str(summary["error"])]
    text = "; ".join(reasons) if reasons else "see summary.json"
    return f"warning: {stage} status {status}: {text}"


def status_log(summary: Mapping[str, Any], t: float = 0.0) -> list[tuple[float, str, str]]:
    """The stage log's lines about the status: one per finding of ``summary["status_reasons"]``.

    Parameters
    ----------
    summary : Mapping
        A stage's summary after :meth:`StatusReport.apply`.
    t : float
        Mission time of the lines [s] (the end of the run).

    Returns
    -------
    list of (float, str, str)
        ``(t, level, "status <level>: <message>")`` with level ``error`` for unsafe findings, ``warning`` else.
    """
    return [(t, "error" if r["level"] == UNSAFE else "warning", f"status {r['level']}: {r['message']}")
            for r in summary.get("status_reasons", ())]


def exit_code(status: str) -> int:
    """The process exit code of a run with ``status``."""
    return EXIT_CODES.get(status, 1)
