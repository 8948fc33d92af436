"""Where a mission keeps its files: one run folder, one sub-folder per segment and stage.

A mission run folder ``runs/mission-<name>-<UTC stamp>/`` holds::

    config.yaml                       the mission config as given (resolved, defaults filled)
    segment-1/plan/                   A -> B, model known: LQR-RRT* (or kino-RRT)
    segment-1/smooth/                 LQR shortcutting + polish of segment-1/plan/plan.mcap
    segment-1/track/                  standard MPC tracking segment-1/smooth/smooth.mcap
    segment-1/calibrate-manoeuvre/    optional: a rotation-rich flight of the known robot at B for the calibration
    segment-1/calibrate/              actuator calibration from segment-1/track/track.mcap (known robot; optional),
    segment-1/calibrate-on-manoeuvre/ optional: calibration from the manoeuvre, fitted from segment-1/calibrate's
    segment-2/excite/                 B -> C, payload grasped: A-optimal excitation (or RATTLE)
    segment-2/track/                  tube MPC tracking segment-2/excite/excite.mcap, W from the prior (Eq. 28)
    segment-2/estimate-sequential/    sequential estimate from segment-2/track/track.mcap (during the segment)
    segment-2/estimate/               batch estimate from segment-2/track/track.mcap (at C)
    segment-3/plan/                   C -> A with the learned model
    segment-3/smooth/
    segment-3/track/                  tube MPC, W from the estimate's 2σ bounds ([Doerr2021] Eq. 28)
    segment-3/baseline-mpc-prior/     the same reference, standard MPC, prior model (Fig. 3(d), cyan)
    segment-3/baseline-tube-prior/    the same reference, tube MPC, prior model and W (Fig. 3(d), magenta)
    segment-3/baseline-mpc-unconstrained-prior/   only with mission.unconstrained_baseline: standard MPC on the
                                      prior without workspace constraints (the paper's standard MPC)
    mission.rrd                       one recording on the ``mission_time`` timeline
    plots/*.png                       tracking error per segment with baselines, estimate convergence, top view
    summary.json                      written last

Every stage sub-folder is exactly what that stage command writes (``config.yaml``, ``<stage>.mcap``,
``<stage>.rrd``, ``summary.json``); a baseline or ``estimate-sequential`` folder is a ``track`` or ``estimate``
folder under another name. :data:`MISSION_STAGES` lists them in the order they run.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class MissionStage:
    """One stage of the mission.

    Attributes
    ----------
    segment : str
        ``segment-1``, ``segment-2`` or ``segment-3``.
    name : str
        The sub-folder's name (``plan``, ``track``, ``baseline-mpc-prior`` ...).
    command : str
        The stage command that writes such a folder (``plan``, ``smooth``, ``excite``, ``track``, ``estimate``).
    """

    segment: str
    name: str
    command: str

    @property
    def key(self) -> str:
        """``segment/name``, e.g. ``segment-3/track`` (what ``--from`` takes)."""
        return f"{self.segment}/{self.name}"

    def folder(self, mission_dir: Path) -> Path:
        """This stage's run folder inside ``mission_dir``.

        Parameters
        ----------
        mission_dir : Path
            The mission run folder.

        Returns
        -------
        Path
        """
        return Path(mission_dir) / self.segment / self.name

    def mcap(self, mission_dir: Path) -> Path:
        """The stage's MCAP (``<command>.mcap``) inside its folder.

        Parameters
        ----------
        mission_dir : Path
            The mission run folder.

        Returns
        -------
        Path
        """
        return self.folder(mission_dir) / f"{self.command}.mcap"


MISSION_STAGES: tuple[MissionStage, ...] = (
    MissionStage("segment-1", "plan", "plan"),
    MissionStage("segment-1", "smooth", "smooth"),
    MissionStage("segment-1", "track", "track"),
    MissionStage("segment-1", "calibrate", "estimate"),
    MissionStage("segment-2", "excite", "excite"),
    MissionStage("segment-2", "track", "track"),
    MissionStage("segment-2", "estimate-sequential", "estimate"),
    MissionStage("segment-2", "estimate", "estimate"),
    MissionStage("segment-3", "plan", "plan"),
    MissionStage("segment-3", "smooth", "smooth"),
    MissionStage("segment-3", "track", "track"),
    MissionStage("segment-3", "baseline-mpc-prior", "track"),
    MissionStage("segment-3", "baseline-tube-prior", "track"),
)
"""Every stage of a default mission, in the order they run."""

OPTIONAL_STAGES: tuple[MissionStage, ...] = (
    MissionStage("segment-3", "baseline-mpc-unconstrained-prior", "track"),
    MissionStage("segment-1", "calibrate-manoeuvre", "track"),
    MissionStage("segment-1", "calibrate-on-manoeuvre", "estimate"),
)
"""Stages a mission flies only when asked, after :data:`MISSION_STAGES` in this table's order
(:func:`oacli.mission.run.mission_stages` places them): ``mission.unconstrained_baseline`` flies
``segment-3/baseline-mpc-unconstrained-prior``, which then appears in ``mission.mcap``, ``mission.rrd``, the mission's
plots and its report beside the other baselines; ``mission.calibration_manoeuvre`` flies
``segment-1/calibrate-manoeuvre`` after ``segment-1/track`` and fits it in ``segment-1/calibrate-on-manoeuvre`` after
``segment-1/calibrate`` (ordinary ``track`` and ``estimate`` folders, not in the mission's combined recording)."""

ALL_STAGES: tuple[MissionStage, ...] = MISSION_STAGES + OPTIONAL_STAGES
"""Every stage a mission may run, in order (a stage's seed is drawn from its index here)."""

SEGMENTS: tuple[str, ...] = ("segment-1", "segment-2", "segment-3")
"""The three segments: A → B (model known), B → C (payload uncertain), C → A (model learned)."""

BASELINES: dict[str, str] = {
    "segment-3/track": "tube MPC, estimate",
    "segment-3/baseline-mpc-prior": "standard MPC, prior",
    "segment-3/baseline-tube-prior": "tube MPC, prior",
}
"""The three ways segment 3 is flown ([Doerr2021] Fig. 3(d): green, cyan, magenta)."""

UNCONSTRAINED_BASELINE = "segment-3/baseline-mpc-unconstrained-prior"
"""The optional fourth segment-3 flight (``mission.unconstrained_baseline``): standard MPC on the prior without
``controller.position_constraints``, as [Doerr2021]'s standard MPC ("can lead to collisions"); a study flies it
beside the constrained one in the same mission instead of doubling its missions. Drawn and recorded with the other
segment-3 flights when flown (olive)."""

FLIGHT_LABELS: dict[str, str] = {**BASELINES, UNCONSTRAINED_BASELINE: "standard MPC, prior, no workspace constraints"}
"""Labels of every segment-3 flight a mission may fly, in the order they fly (:data:`BASELINES`, then the optional
unconstrained one)."""


def stage_by_key(key: str) -> MissionStage:
    """The stage named ``segment/name``.

    Parameters
    ----------
    key : str
        E.g. ``segment-3/track``.

    Returns
    -------
    MissionStage

    Raises
    ------
    KeyError
        Unknown key (the message lists the known ones).
    """
    for stage in ALL_STAGES:
        if stage.key == key.strip("/"):
            return stage
    raise KeyError(f"{key!r}: not a mission stage; one of " + ", ".join(s.key for s in ALL_STAGES))

RECORDED_STAGES: tuple[MissionStage, ...] = MISSION_STAGES + tuple(s for s in OPTIONAL_STAGES
                                                                   if s.key == UNCONSTRAINED_BASELINE)
"""The stages whose records the mission's combined files (``mission.mcap``, the mission log) carry, when flown: the
default stages and the unconstrained baseline (it flies from segment 3's start like the other baselines). The
calibration manoeuvre's two stages are left out: their clocks start after ``segment-1/track`` ends, which the
segment's offset does not say; their own folders hold their records."""
