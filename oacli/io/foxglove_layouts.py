"""Foxglove layouts for oacli's MCAP files (issue 33 item 4), shipped as ``docs/foxglove/<name>.json``.

One layout per stage kind (``plan``, ``smooth``, ``excite``, ``track``, ``track-tube``, ``estimate``) and one for the
mission-level MCAP (``mission``, :mod:`oacli.mission.foxglove`, which also writes the files): a 3D panel following the
world frame with ``/scene`` and ``/robot/pose``, Plot panels on the stage's message paths, a Raw Messages panel and
a Log panel. In Foxglove: *Layouts* → *Import from file…*, then open the MCAP. The JSON follows Foxglove's layout format
(``configById``, ``layout`` as a split tree, ``globalVariables``, ``userNodes``, ``playbackConfig``).

:data:`LAYOUT_FILES` names the MCAP each layout is for (a stage of the default mission); ``tests/
test_foxglove_layouts.py`` checks that every topic and message path a shipped layout names exists in that file.
Regenerate the shipped files with ``python -m oacli.mission.foxglove docs/foxglove``.
"""

from __future__ import annotations

from typing import Any

#: The world frame of the presets (``configs/mission_iss.yaml``: ``iss``; ``configs/doerr2021.yaml``:
#: ``assembly_bay``); the 3D panels follow ``iss`` (change *Display frame* for the Doerr presets).
FRAME = "iss"

#: Layout name -> the mission stage whose MCAP it is written for (``mission``: the mission-level ``mission.mcap``).
LAYOUT_FILES: dict[str, str] = {
    "plan": "segment-1/plan",
    "smooth": "segment-1/smooth",
    "excite": "segment-2/excite",
    "track": "segment-1/track",
    "track-tube": "segment-2/track",
    "estimate": "segment-2/estimate",
    "mission": "mission",
}

_XYZ = ("x", "y", "z")


def plot_panel(title: str, paths: list[tuple[str, str]], x_path: str | None = None) -> dict[str, Any]:
    """A Plot panel: ``paths`` (message path, legend label); against ``x_path`` (a message path) instead of time."""
    config: dict[str, Any] = {
        "title": title,
        "paths": [{"value": p, "enabled": True, "timestampMethod": "receiveTime", "label": label}
                  for p, label in paths],
        "showXAxisLabels": True, "showYAxisLabels": True, "showLegend": True, "legendDisplay": "floating",
        "showPlotValuesInLegend": False, "isSynced": True, "xAxisVal": "timestamp", "sidebarDimension": 240,
    }
    if x_path is not None:
        config["xAxisVal"] = "custom"
        config["xAxisPath"] = {"value": x_path, "enabled": True}
    return config


def three_d_panel(scene_topics: list[str], pose_topics: list[str]) -> dict[str, Any]:
    topics: dict[str, dict[str, Any]] = {t: {"visible": True} for t in scene_topics}
    topics.update({t: {"visible": True, "type": "arrow", "axisScale": 1} for t in pose_topics})
    return {"followTf": FRAME, "followMode": "follow-position", "scene": {"enableStats": False},
            "cameraState": {"distance": 4.0, "perspective": True, "phi": 55.0, "thetaOffset": 45.0,
                            "targetOffset": [0, 0, 0], "target": [0, 0, 0], "targetOrientation": [0, 0, 0, 1],
                            "fovy": 45, "near": 0.01, "far": 500},
            "transforms": {}, "topics": topics, "layers": {}, "publish": {"type": "point"}, "imageMode": {}}


def _xyz(topic: str, field: str, label: str) -> list[tuple[str, str]]:
    return [(f"{topic}.{field}[{i}]", f"{label} {axis}") for i, axis in enumerate(_XYZ)]


def split(first: Any, second: Any, direction: str, percent: float) -> dict[str, Any]:
    return {"first": first, "second": second, "direction": direction, "splitPercentage": percent}


def layout_file(panels: dict[str, dict[str, Any]], tree: Any) -> dict[str, Any]:
    return {"configById": panels, "globalVariables": {}, "userNodes": {}, "linkedGlobalVariables": [],
            "playbackConfig": {"speed": 1, "messageOrder": "receiveTime"}, "layout": tree}


def _stage_layout(plots: list[dict[str, Any]], raw_topic: str, prefix: str = "") -> dict[str, Any]:
    """3D (left), the plots stacked (right), Raw Messages and Log (bottom)."""
    panels: dict[str, dict[str, Any]] = {
        "3D!oacli": three_d_panel([f"{prefix}/scene"], [f"{prefix}/robot/pose"]),
        "RawMessages!oacli": {"topicPath": raw_topic, "diffEnabled": False, "diffMethod": "custom",
                              "diffTopicPath": "", "showFullMessageForDiff": False},
        "RosOut!oacli": {"searchTerms": [], "minLogLevel": 1, "topicToRender": f"{prefix}/log"},
    }
    ids = []
    for k, plot in enumerate(plots):
        ids.append(f"Plot!oacli{k}")
        panels[ids[-1]] = plot
    right: Any = ids[-1]
    for k in range(len(ids) - 2, -1, -1):
        right = split(ids[k], right, "column", round(100.0 / (len(ids) - k), 1))
    top = split("3D!oacli", right, "row", 50)
    bottom = split("RawMessages!oacli", "RosOut!oacli", "row", 50)
    return layout_file(panels, split(top, bottom, "column", 72))


def stage_layouts() -> dict[str, dict[str, Any]]:
    """The stage layouts, by name (:data:`LAYOUT_FILES`; the mission's: :func:`oacli.mission.foxglove.mission_layout`).
    """
    track_plots = [
        plot_panel("position [m]: true (solid) and reference", _xyz("/state/true", "position", "true")
              + _xyz("/reference", "position", "ref")),
        plot_panel("applied force [N] (world)", _xyz("/control/applied", "force", "f")),
        plot_panel("solver time per step [ms]", [("/solver/stats.solve_time_ms", "solve"),
                                            ("/solver/stats.step_time_ms", "step")]),
    ]
    tube_plots = [
        track_plots[0],
        plot_panel("nominal force v [N]", _xyz("/control/nominal", "force", "v")),
        plot_panel("ancillary force K(x − z) [N]", _xyz("/control/ancillary", "force", "K(x−z)")),
        plot_panel("tube margin (≥ 0: w inside W)", [("/tube/disturbance.margin", "margin")]),
        plot_panel("disturbance w, position [m]", _xyz("/tube/disturbance", "w_position_m", "w")
              + _xyz("/tube/disturbance", "w_half_position_m", "W half-width")),
    ]
    out = {
        "plan": _stage_layout([
            plot_panel("best cost against iteration", [("/plan/solutions.cost", "best cost")],
                  "/plan/solutions.iteration"),
            plot_panel("plan position [m]", _xyz("/trajectory", "position", "r")),
            plot_panel("plan force [N]", _xyz("/trajectory", "force", "f")),
        ], "/plan/solutions"),
        "smooth": _stage_layout([
            plot_panel("shortcut tries: cost after each try", [("/smooth/shortcuts.new_cost", "cost")],
                  "/smooth/shortcuts.try"),
            plot_panel("polish: path length [m] per iteration", [("/smooth/polish.length_m", "length")],
                  "/smooth/polish.iteration"),
            plot_panel("smoothed position [m]", _xyz("/trajectory", "position", "r")),
        ], "/smooth/polish"),
        "excite": _stage_layout([
            plot_panel("SCP criterion per iteration", [("/excitation/iterations.criterion", "criterion")],
                  "/excitation/iterations.iteration"),
            plot_panel("excitation force [N]", _xyz("/trajectory", "force", "f")),
            plot_panel("excitation torque [N·m]", _xyz("/trajectory", "torque", "τ")),
        ], "/excitation/iterations"),
        "track": _stage_layout(track_plots, "/solver/stats"),
        "track-tube": _stage_layout(tube_plots, "/tube/design"),
        "estimate": _stage_layout([
            plot_panel("mass estimate [kg]", [("/estimate/params.mass_kg", "mass")]),
            plot_panel("inertia estimates [kg·m²]", [(f"/estimate/params.inertia_kgm2[{i}]", f"I{a}{a}")
                                                for i, a in enumerate(_XYZ)]),
            plot_panel("normalised residual² against the χ² gate", [("/estimate/samples.d2", "d²"),
                                                               ("/estimate/samples.gate", "gate")]),
        ], "/estimate/params"),
    }
    return out
