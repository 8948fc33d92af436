"""Draw a finished run's PNGs afterwards from its files (``oacli plots RUN_DIR``).

A stage folder holds everything its figures show: the MCAP (the record of truth), the resolved ``config.yaml`` and
``summary.json``. :func:`stage_figures` reads them back and hands the data to the same figure functions the stage
uses (:func:`~oacli.io.plots.track.track_figures`, :func:`~oacli.io.plots.plan.path_figures`,
:func:`~oacli.io.plots.excite.excite_figures`, :func:`~oacli.io.plots.estimate.estimate_figures`), so the PNGs are
those the stage would have drawn (pixel for pixel: the MCAP's floats are the run's, written round-trippable):

* ``plan`` -- ``/trajectory``, the config's segment (start, goal), scene and robot radius;
* ``smooth`` -- ``/trajectory`` and ``/trajectory/input`` (the input plan as read);
* ``track`` -- the telemetry and the reference the config names (``reference.file`` or its waypoints); the robot's
  limits;
* ``excite`` -- ``/excitation/information`` and ``/trajectory`` (offline design) or the flown inputs (RATTLE; its
  information is the MCAP's, sampled at the control instants, so its curve steps there rather than at each estimate);
* ``estimate`` -- ``/estimate/params`` (θ and covariance per record), the summary's truth and Cramér-Rao σ.

A file a stage read (the reference, the input plan) is looked for where it was, then at the same place relative to
the run folder (a mission folder that was moved or copied keeps its stage folders side by side). A mission folder
(``summary.json`` with ``"stage": "mission"``) gets every stage's PNGs in its stage folders and the mission's in
``plots/`` (:func:`oacli.mission.plots.write_mission_plots`). Summaries are left as they are (they record the run).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from oacli.config import OacliConfig, load_config
from oacli.errors import InputError
from oacli.io import mcap_schema as ms
from oacli.io.mcap_read import read_stage, read_telemetry, read_trajectory
from oacli.io.plots.estimate import estimate_figures
from oacli.io.plots.excite import excite_figures
from oacli.io.plots.plan import path_figures
from oacli.io.plots.track import track_figures
from oacli.types import ParameterEstimate, Trajectory

Figures = dict[str, Callable[[Path], object]]
#: The stages whose folders :func:`stage_figures` draws, and the MCAP each writes.
STAGE_MCAPS = {"plan": "plan.mcap", "smooth": "smooth.mcap", "excite": "excite.mcap", "track": "track.mcap",
               "estimate": "estimate.mcap"}
PARAM_NAMES = ("mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2")
#: The smooth stage's input plan as it read it.
SMOOTH_INPUT_TOPIC = "/trajectory/input"


def read_summary(folder: Path) -> dict[str, Any]:
    """``folder/summary.json``, or an :class:`~oacli.errors.InputError` naming the folder and the reason."""
    from oacli.io.runfolder import read_summary_file

    path = Path(folder) / "summary.json"
    if not path.exists() and not path.is_symlink():
        raise InputError(f"{folder}: no summary.json: not an oacli run folder")
    summary = read_summary_file(path)  # a FIFO, a device, binary data: exit 2 without blocking
    if not isinstance(summary, dict) or "stage" not in summary:
        raise InputError(f"{path}: no 'stage' entry: not an oacli run summary")
    return summary


def _recorded_file(recorded: str | None, summary: dict[str, Any], folder: Path, what: str) -> Path:
    """A file the stage read: where it was, else at the same place relative to the (moved) run folder."""
    if not recorded:
        raise InputError(f"{folder}: the config names no {what}")
    path = Path(recorded)
    if path.exists():
        return path
    run_dir = summary.get("run_dir")
    if run_dir:
        moved = (Path(folder) / os.path.relpath(path, run_dir)).resolve()
        if moved.exists():
            return moved
    raise InputError(f"{folder}: the {what} {path} it read is gone (nor found beside the run folder)")


def _stage_config(folder: Path) -> OacliConfig:
    path = Path(folder) / "config.yaml"
    if not path.is_file():
        raise InputError(f"{folder}: no config.yaml")
    return load_config(path)


def _plan_figures(folder: Path, summary: dict[str, Any], cfg: OacliConfig) -> Figures:
    from oacli.stages.plan import resolve_segment
    from oacli.stages.settings import robot_model

    seg = resolve_segment(cfg, None)  # the run's config holds the segment it planned
    record = read_stage(folder / "plan.mcap", topics=[ms.TOPIC_TRAJECTORY])
    traj = record.trajectories.get(ms.TOPIC_TRAJECTORY)
    return path_figures(stage="plan", scene=cfg.scene(), robot_radius_m=float(robot_model(cfg).radius_m),
                        paths={} if traj is None else {"plan": traj.x[:, 0:3]}, start_m=seg.start[0:3],
                        goal_m=seg.goal[0:3])


def _smooth_figures(folder: Path, summary: dict[str, Any], cfg: OacliConfig) -> Figures:
    from oacli.stages.settings import robot_model

    record = read_stage(folder / "smooth.mcap", topics=[ms.TOPIC_TRAJECTORY, SMOOTH_INPUT_TOPIC])
    traj_in = record.trajectories.get(SMOOTH_INPUT_TOPIC)  # the input as read
    if traj_in is None:  # a file from before the topic: the input file itself
        source = cfg.inputs.smooth_input or record.metadata.get("oacli.smooth", {}).get("input")
        traj_in = read_trajectory(_recorded_file(source, summary, folder, "input plan"))
    traj_out = record.trajectories[ms.TOPIC_TRAJECTORY]
    return path_figures(stage="smooth", scene=cfg.scene(), robot_radius_m=float(robot_model(cfg).radius_m),
                        paths={"plan (input)": traj_in.x[:, 0:3], "smoothed": traj_out.x[:, 0:3]},
                        start_m=traj_in.x[0, 0:3], goal_m=traj_in.x[-1, 0:3])


def _reference(folder: Path, summary: dict[str, Any], cfg: OacliConfig) -> Trajectory:
    """The reference the track stage followed (:func:`oacli.stages.track.reference_from_config`)."""
    from oacli.io.reference_files import load_reference
    from oacli.stages.track import reference_from_config

    if cfg.reference.source != "file":
        return reference_from_config(cfg)
    path = _recorded_file(cfg.reference.file, summary, folder, "reference file")
    return load_reference(path, sample_period_s=cfg.reference.sample_period_s, frame=cfg.environment.frame)


def _track_figures(folder: Path, summary: dict[str, Any], cfg: OacliConfig) -> Figures:
    from oacli.stages.settings import robot_model

    telemetry, model = read_telemetry(folder / "track.mcap"), robot_model(cfg)
    return track_figures(telemetry=telemetry, reference=_reference(folder, summary, cfg),
                         limits=model.limits, scene=cfg.scene(), robot_radius_m=float(model.radius_m))


def _excite_figures(folder: Path, summary: dict[str, Any], cfg: OacliConfig) -> Figures:
    from oacli.stages.design_limits import excitation_design_limits, to_motion_limits
    from oacli.stages.settings import robot_model

    record = read_stage(folder / "excite.mcap", topics=[ms.TOPIC_TRAJECTORY, ms.TOPIC_EXCITATION_INFORMATION])
    traj = record.trajectories[ms.TOPIC_TRAJECTORY]
    info_records = record.json_records.get(ms.TOPIC_EXCITATION_INFORMATION, ())
    t_info = np.array([float(r["t"]) for r in info_records])
    information = np.array([r["information"] for r in info_records], dtype=float).reshape(-1, 4, 4)
    method = str(summary.get("method", ""))
    if method == "rattle":
        limits = to_motion_limits(excitation_design_limits(cfg, rattle=True))
        robot = robot_model(cfg).limits
        # the flown trajectory is the control instants plus the final state (no input there)
        return excite_figures(method=method, t_info_s=t_info, information=information, t_input_s=traj.t[:-1],
                              u=traj.u[:-1], force_limit_N=limits.force_N, torque_limit_Nm=limits.torque_Nm,
                              actuator=(robot.force_N, robot.torque_Nm))
    limits = to_motion_limits(excitation_design_limits(cfg))
    return excite_figures(method=method, t_info_s=traj.t, information=information, t_input_s=traj.t, u=traj.u,
                          force_limit_N=limits.force_N, torque_limit_Nm=limits.torque_Nm)


def _estimate_figures(folder: Path, summary: dict[str, Any], cfg: OacliConfig) -> Figures:
    record = read_stage(folder / "estimate.mcap", topics=[ms.TOPIC_ESTIMATE_PARAMS, ms.TOPIC_ESTIMATE_SAMPLES])
    params = record.json_records.get(ms.TOPIC_ESTIMATE_PARAMS, ())
    if not params:
        raise InputError(f"{folder / 'estimate.mcap'}: no /estimate/params records")
    estimates = [ParameterEstimate(float(p["t"]), np.array([p["mass_kg"], *p["inertia_kgm2"]], dtype=float),
                                   np.array(p["covariance"], dtype=float), str(p.get("method", "")))
                 for p in params]
    truth = summary.get("truth_theta")
    crb = summary.get("crb_std")
    crb_std = None if not isinstance(crb, dict) else np.array(
        [np.nan if crb.get(n) is None else float(crb[n]) for n in PARAM_NAMES])
    samples = record.json_records.get(ms.TOPIC_ESTIMATE_SAMPLES, ())
    innovation = None if not samples else (
        np.array([float(r["t"]) for r in samples]),
        np.array([np.nan if r["d2"] is None else float(r["d2"]) for r in samples]),
        next((float(r["gate"]) for r in samples if r.get("gate") is not None), float("inf")),
        np.array([r["status"] == "rejected" for r in samples], dtype=bool))
    return estimate_figures(estimates=estimates, truth=None if truth is None else np.asarray(truth, dtype=float),
                            crb_std=crb_std, innovation=innovation)


_READERS: dict[str, Callable[[Path, dict[str, Any], OacliConfig], Figures]] = {
    "plan": _plan_figures, "smooth": _smooth_figures, "excite": _excite_figures, "track": _track_figures,
    "estimate": _estimate_figures,
}


def stage_figures(folder: Path) -> Figures:
    """The figures a stage folder's stage draws (module docstring), name -> function drawing it to a path.

    Parameters
    ----------
    folder : Path
        A complete ``plan``, ``smooth``, ``excite``, ``track`` or ``estimate`` run folder.

    Returns
    -------
    dict of str to callable

    Raises
    ------
    InputError
        Not such a folder, or a file it needs is missing or unreadable.
    """
    folder = Path(folder)
    summary = read_summary(folder)
    stage = str(summary["stage"])
    if stage not in _READERS:
        raise InputError(f"{folder}: stage {stage!r} has no PNGs of its own (stages with PNGs: "
                         f"{', '.join(_READERS)}; a mission folder draws them all)")
    mcap = folder / STAGE_MCAPS[stage]
    if not mcap.is_file():
        raise InputError(f"{folder}: no {mcap.name}: the stage did not finish (status {summary.get('status')})")
    return _READERS[stage](folder, summary, _stage_config(folder))


def draw_stage(folder: Path, out_dir: Path | None = None) -> dict[str, Path]:
    """Draw a stage folder's PNGs into ``out_dir`` (default: the folder itself, where the stage writes them).

    Parameters
    ----------
    folder : Path
        A stage run folder.
    out_dir : Path, optional
        Where the PNGs go (created).

    Returns
    -------
    dict of str to Path
        Figure name -> PNG written.
    """
    figures = stage_figures(folder)
    out = Path(folder) if out_dir is None else Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = {}
    for name, draw in figures.items():
        path = out / f"{name}.png"
        draw(path)
        written[name] = path
    return written


__all__ = ["STAGE_MCAPS", "draw_stage", "read_summary", "stage_figures"]
