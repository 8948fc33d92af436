"""PNG plots that read consistently: the innovation plot's gate and rejected records have their own
colours, coinciding waypoints get one label (no B printed over C), and error panels of one figure share one kind of
axis. Each read back from the drawn figure before it is saved."""

from __future__ import annotations

import json
import warnings

import matplotlib.colors as mcolors
import numpy as np
import pytest

from oacli.io.plots import estimate as estimate_plots
from oacli.io.plots import track as track_plots
from oacli.io.plots.common import lay_out
from oacli.mission import plots as mission_plots
from oacli.mission.records import load_mission_records
from oacli.types import Telemetry, Trajectory


def _capture(monkeypatch, module):
    figures = []

    def capture(fig, path):
        lay_out(fig)
        fig.canvas.draw()
        figures.append(fig)
        return path

    monkeypatch.setattr(module, "save_png", capture)
    return figures


def test_innovation_gate_and_rejected_records_have_distinct_colours(monkeypatch, tmp_path):
    figures = _capture(monkeypatch, estimate_plots)
    t = np.arange(50) * 0.2
    d2 = np.abs(np.sin(t)) * 20 + 1.0
    d2[[7, 31]] = [40.0, 55.0]
    rejected = d2 > 26.2
    estimate_plots.plot_innovation(tmp_path / "innovation.png", t, d2, 26.2, rejected)
    (fig,) = figures
    (ax,) = fig.axes
    handles, labels = ax.get_legend_handles_labels()
    colours = {label.split(" ")[0]: mcolors.to_rgba(h.get_color()) for h, label in zip(handles, labels, strict=True)}
    assert set(colours) == {"d²", "χ²", "rejected"}
    assert len(set(colours.values())) == 3  # the gate is not drawn in the rejected records' colour
    (marks,) = [line for line in ax.lines if line.get_label().startswith("rejected")]
    np.testing.assert_array_equal(marks.get_ydata(), [40.0, 55.0])
    (gate,) = [line for line in ax.lines if line.get_label().startswith("χ²")]
    assert set(gate.get_ydata()) == {26.2}


def test_waypoints_closer_than_the_merge_distance_share_one_label():
    waypoints = {"A": np.array([10.8, -9.6, 4.8]), "B": np.array([10.8, -7.75, 5.2]),
                 "C": np.array([10.8, -7.75, 4.3])}
    top = mission_plots.waypoint_labels(waypoints, (0, 1), 0.1)
    assert [names for names, _ in top] == [["A"], ["B", "C"]]
    side = mission_plots.waypoint_labels(waypoints, (1, 2), 0.1)
    assert [names for names, _ in side] == [["A"], ["B"], ["C"]]


@pytest.fixture(scope="module")
def records(mission_run):
    mission_dir = mission_run[0]
    summary = json.loads((mission_dir / "summary.json").read_text())
    return load_mission_records(mission_dir, summary)


def test_paths_png_prints_no_label_over_another(monkeypatch, tmp_path, records):
    figures = _capture(monkeypatch, mission_plots)
    mission_plots.plot_paths(records, tmp_path / "paths.png")
    (fig,) = figures
    renderer = fig.canvas.get_renderer()
    texts = []
    for ax in fig.axes:
        boxes = [(t.get_text(), t.get_window_extent(renderer)) for t in ax.texts]
        texts += [name for name, _ in boxes]
        for i, (a, box_a) in enumerate(boxes):
            for b, box_b in boxes[i + 1:]:
                assert not box_a.overlaps(box_b), f"labels {a!r} and {b!r} overlap"
    assert sorted(", ".join(texts).replace(" ", "").split(",")) == sorted(list("ABC") * 2)  # each named in each view


def test_mission_error_panels_share_one_axis_kind_and_range(monkeypatch, tmp_path, records):
    figures = _capture(monkeypatch, mission_plots)
    mission_plots.plot_tracking_error(records, tmp_path / "tracking_error.png")
    (fig,) = figures
    scales = {ax.get_yscale() for ax in fig.axes}
    limits = {tuple(np.round(ax.get_ylim(), 12)) for ax in fig.axes}
    assert len(scales) == 1 and len(limits) == 1, (scales, limits)
    errors = np.concatenate([f.position_error_m for f in records.flights.values()])
    _, hi = next(iter(limits))
    assert hi >= errors.max()  # every flight's largest error in range


def test_stage_error_panels_share_one_axis_kind(monkeypatch, tmp_path):
    figures = _capture(monkeypatch, track_plots)
    t = np.linspace(0.0, 10.0, 501)
    x_ref = np.zeros((501, 13))
    x_ref[:, 9] = 1.0
    x_ref[:, 0] = 0.01 * t
    x_true = x_ref.copy()
    x_true[:, 0] += 1e-6 + 0.02 * (t / 10.0) ** 4  # the error grows over four decades
    angle = 0.001 + 0.01 * t / 10.0
    x_true[:, 6], x_true[:, 9] = np.sin(angle / 2), np.cos(angle / 2)
    u = np.zeros((501, 6))
    reference = Trajectory(t=t, x=x_ref, u=u)
    k = np.arange(0, 501, 25)
    telemetry = Telemetry(t_true=t, x_true=x_true, t_ctrl=t[k], x_measured=x_true[k], x_reference=x_ref[k],
                          u_command=u[k], u_applied=u[k], solve_info=(), disturbance=u[k])
    track_plots.plot_tracking_error(tmp_path / "e.png", telemetry, reference)
    (fig,) = figures
    assert [ax.get_yscale() for ax in fig.axes] == ["log", "log"]
    assert all(ax.get_ylabel().endswith(", log") for ax in fig.axes)
    # an attitude error of exactly zero has nothing to show on a log axis: linear, and said so (no "log" label)
    x_true = x_true.copy()
    x_true[:, 6], x_true[:, 9] = 0.0, 1.0
    telemetry = Telemetry(t_true=t, x_true=x_true, t_ctrl=t[k], x_measured=x_true[k], x_reference=x_ref[k],
                          u_command=u[k], u_applied=u[k], solve_info=(), disturbance=u[k])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        track_plots.plot_tracking_error(tmp_path / "e0.png", telemetry, reference)
    assert [ax.get_yscale() for ax in figures[-1].axes] == ["log", "linear"]
    assert not figures[-1].axes[1].get_ylabel().endswith(", log")
