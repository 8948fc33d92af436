"""The track recording's error plot compares the true state and the reference at equal times.

The plant runs at 62.5 Hz and the controller at 5 Hz: every other control instant falls between two plant samples,
8 ms before the next one. The errors plotted at the control instants take the true state at exactly those times.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from oacli.cli import app
from oacli.config import load_config
from oacli.io.mcap_io import read_telemetry
from oacli.io.rerun.read import read_recording_scalars
from oacli.metrics import true_states_at
from oacli.model import quaternion as quat
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.sim.simulator import simulate
from oacli.stages.track import reference_from_config
from oacli.trajectory import sample_states
from tests.conftest import REPO
from tests.test_simulator import LIMITS, TRUTH, PiecewiseForce, at_rest, closed_form_position

DOERR = REPO / "configs" / "doerr2021.yaml"


def run_cli(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_true_state_at_control_instants_is_exact_between_plant_samples():
    base = np.array([0.01, -0.02, 0.005])
    tel = simulate(PiecewiseForce(base), at_rest(), TRUTH, duration_s=3.0, control_period_s=0.2,
                   plant_period_s=0.016, input_limits=LIMITS, sensors=SensorNoise(),
                   disturbance=Disturbance.none(), rng=np.random.default_rng(0))
    off_grid = np.abs(tel.t_ctrl / 0.016 - np.round(tel.t_ctrl / 0.016)) > 1e-6
    assert off_grid.sum() == 7  # 0.2, 0.6, 1.0 ... s lie 8 ms before a plant sample
    x = true_states_at(tel, tel.t_ctrl)
    for k, t in enumerate(tel.t_ctrl):
        np.testing.assert_allclose(x[k, 0:3], closed_form_position(base, tel.t_ctrl, 0.2, TRUTH.mass_kg, t),
                                   atol=1e-13)
    # The next plant sample is 8 ms later and off by about v·8 ms: the error the old plot showed.
    nxt = tel.x_true[np.searchsorted(tel.t_true, tel.t_ctrl[off_grid])]
    assert np.min(np.linalg.norm(nxt[:, 0:3] - x[off_grid, 0:3], axis=1)) > 1e-6
    # On-grid times are the samples themselves; quaternions stay unit.
    np.testing.assert_array_equal(x[~off_grid], tel.x_true[np.searchsorted(tel.t_true, tel.t_ctrl[~off_grid] - 1e-9)])
    np.testing.assert_allclose(np.linalg.norm(x[:, 6:10], axis=1), 1.0, atol=1e-12)


@pytest.fixture(scope="module")
def doerr_track(tmp_path_factory):
    out = tmp_path_factory.mktemp("track") / "run"
    result = run_cli("track", DOERR, "--out", out, "--quiet", "--seed", "3")
    assert result.exit_code == 0, result.output
    return out


def test_plotted_position_error_matches_the_summary(doerr_track):
    summary = json.loads((doerr_track / "summary.json").read_text())
    tel = read_telemetry(doerr_track / "track.mcap")
    # The reference the run followed (the MCAP's /reference holds it at the control instants only).
    reference = reference_from_config(load_config(doerr_track / "config.yaml"))
    t, plotted = read_recording_scalars(doerr_track / "track.rrd")["metrics/position_error_m"]
    _, plotted_att = read_recording_scalars(doerr_track / "track.rrd")["metrics/attitude_error_rad"]
    np.testing.assert_allclose(t, tel.t_ctrl, atol=1e-9)
    # The summary's errors, over the plant samples.
    ref_true = sample_states(reference, tel.t_true)
    err_true = np.linalg.norm(tel.x_true[:, 0:3] - ref_true[:, 0:3], axis=1)
    assert err_true.max() == pytest.approx(summary["max_position_error_m"], rel=1e-12)
    # Where a control instant is a plant sample, the plot holds the summary's value for that sample.
    idx = np.searchsorted(tel.t_true, tel.t_ctrl - 1e-9)
    on_grid = np.abs(tel.t_true[idx] - tel.t_ctrl) < 1e-9
    assert on_grid.sum() >= len(t) // 2 - 1
    np.testing.assert_allclose(plotted[on_grid], err_true[idx[on_grid]], rtol=1e-12, atol=1e-15)
    # Everywhere, the plot is the error at that very time, so never above the summary's maximum (the old plot,
    # comparing with the plant sample 8 ms later, peaked at 15x the summary's maximum).
    x_at = true_states_at(tel, tel.t_ctrl)
    ref_at = sample_states(reference, tel.t_ctrl)
    np.testing.assert_allclose(plotted, np.linalg.norm(x_at[:, 0:3] - ref_at[:, 0:3], axis=1), rtol=1e-12,
                               atol=1e-15)
    assert plotted.max() <= summary["max_position_error_m"] * (1 + 1e-9)
    assert plotted.max() >= 0.5 * summary["max_position_error_m"]
    np.testing.assert_allclose(plotted_att, quat.angle_between(ref_at[:, 6:10], x_at[:, 6:10]), atol=1e-12)
    assert plotted_att.max() <= summary["max_attitude_error_rad"] * (1 + 1e-6) + 1e-12
