"""One mission stage run through the function its command uses (``run_plan``, ``run_smooth``, ``run_excite``,
``run_track``, ``run_estimate``), for :mod:`oacli.mission.run` and its background process
(:mod:`oacli.mission.background`)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from oacli.config import OacliConfig
from oacli.io.runfolder import StageResult
from oacli.mission.configs import Handoff
from oacli.mission.layout import MissionStage


def run_stage(stage: MissionStage, stage_cfg: OacliConfig, handoff: Handoff, folder: Path,
              progress: Callable[[float], None] | None) -> StageResult:
    """Run one stage into ``folder`` through the function its command uses.

    Parameters
    ----------
    stage : MissionStage
        The stage.
    stage_cfg : OacliConfig
        Its config (:func:`oacli.mission.configs.stage_config`).
    handoff : Handoff
        Its inputs.
    folder : Path
        Its run folder (must not exist).
    progress : callable or None
        Progress callback.

    Returns
    -------
    StageResult
    """
    if stage.command == "plan":
        from oacli.stages.plan import run_plan
        return run_plan(stage_cfg, out=folder, progress=progress)
    if stage.command == "smooth":
        from oacli.stages.smooth import run_smooth
        assert handoff.plan is not None
        return run_smooth(stage_cfg, input_path=handoff.plan, out=folder, progress=progress)
    if stage.command == "excite":
        from oacli.stages.excite import run_excite
        return run_excite(stage_cfg, out=folder, progress=progress)
    if stage.command == "track":
        from oacli.stages.track import run_track
        return run_track(stage_cfg, out=folder, progress=progress)
    from oacli.stages.estimate import run_estimate
    assert handoff.telemetry is not None
    # The method is the stage config's (stage_config sets it per stage), so its config.yaml reruns the same one.
    return run_estimate(stage_cfg, telemetry=handoff.telemetry, out=folder, progress=progress)


__all__ = ["run_stage"]
