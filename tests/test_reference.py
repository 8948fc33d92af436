"""References: minimum-jerk waypoint references, sampling, and the file loaders (DAT, CSV, MCAP)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from oacli.cli import app
from oacli.errors import InputError
from oacli.io.mcap_io import StageMcapWriter, read_telemetry
from oacli.io.reference_files import load_reference
from oacli.model import quaternion as quat
from oacli.model import rigid_body as rb
from oacli.reference import waypoint_reference
from oacli.trajectory import feedforward_inputs, sample_states
from oacli.types import InertialParams, Trajectory
from tests.conftest import INFO_TRAJECTORIES, MIT_ISS, REPO, require_shared

PARAMS = InertialParams(9.583788668, [0.153427995, 0.14271405, 0.162302759])
Q_A = [0.0, 0.0, -0.7071068, 0.7071068]


def make_reference():
    return waypoint_reference(
        [[10.8, -9.6, 4.8], [10.8, -7.75, 5.2], [10.8, -7.75, 4.3]], [Q_A, [0, 0, 0, 1], Q_A], PARAMS,
        speed_mps=0.1, accel_mps2=0.0175, rate_radps=0.0873, ang_accel_radps2=0.05, hold_s=1.0,
    )


def test_waypoint_reference_respects_its_limits_and_is_dynamically_consistent():
    ref = make_reference()
    assert np.max(np.linalg.norm(ref.x[:, 3:6], axis=1)) <= 0.1 + 1e-12
    assert np.max(np.linalg.norm(ref.x[:, 10:13], axis=1)) <= 0.0873 + 1e-12
    assert np.max(np.linalg.norm(ref.u[:, 0:3], axis=1)) / PARAMS.mass_kg <= 0.0175 + 1e-12
    # Rest at every waypoint, in the right pose.
    np.testing.assert_allclose(ref.x[0, 0:3], [10.8, -9.6, 4.8])
    np.testing.assert_allclose(ref.x[-1, 0:3], [10.8, -7.75, 4.3])
    np.testing.assert_allclose(ref.x[-1, 3:6], 0.0, atol=1e-15)
    assert quat.angle_between(ref.x[-1, 6:10], np.array(Q_A)) < 1e-7
    # Velocity is the derivative of position; the inputs reproduce the motion through the model (RK4 over a
    # 0.1 s sample with the input held is close to the analytic minimum-jerk profile).
    dt = np.diff(ref.t)
    np.testing.assert_allclose(np.diff(ref.x[:, 0:3], axis=0), 0.5 * (ref.x[:-1, 3:6] + ref.x[1:, 3:6]) * dt[:, None],
                               atol=2e-5)
    theta = rb.theta_of(PARAMS)
    for k in range(0, len(ref) - 1, 37):
        x_next = rb.propagate(ref.x[k], ref.u[k], theta, dt[k])
        assert np.linalg.norm(x_next[0:3] - ref.x[k + 1, 0:3]) < 1e-4
        assert quat.angle_between(x_next[6:10], ref.x[k + 1, 6:10]) < 1e-4


def test_sampling_interpolates_and_holds_at_rest_after_the_end():
    ref = make_reference()
    mid = 0.5 * (ref.t[10] + ref.t[11])
    x = sample_states(ref, [mid, ref.t[-1] + 10.0, -1.0])
    np.testing.assert_allclose(x[0, 0:3], 0.5 * (ref.x[10, 0:3] + ref.x[11, 0:3]))
    np.testing.assert_allclose(x[1, 0:3], ref.x[-1, 0:3])
    np.testing.assert_allclose(x[1, 3:6], 0.0)
    np.testing.assert_allclose(x[2], ref.x[0])
    u = feedforward_inputs(sample_states(ref, ref.t[:20]), 0.1, PARAMS)
    np.testing.assert_allclose(u[:, 0:3], PARAMS.mass_kg * np.diff(ref.x[:20, 3:6], axis=0) / 0.1)


def test_dat_folder_loader_on_the_mit_iss_release():
    require_shared(MIT_ISS)
    ref = load_reference(MIT_ISS)
    assert len(ref) == 700 and ref.duration_s == pytest.approx(139.8)
    np.testing.assert_allclose(ref.x[0, 0:3], [10.8, -9.6, 4.8])
    np.testing.assert_allclose(ref.x[-1, 0:3], [10.8, -8.4, 4.4])
    np.testing.assert_allclose(np.linalg.norm(ref.x[:, 6:10], axis=1), 1.0, atol=1e-12)


def test_csv_loader_on_a_flown_excitation_file():
    path = require_shared(INFO_TRAJECTORIES / "excitation_iss_11.csv")
    ref = load_reference(path, sample_period_s=0.5)
    assert len(ref) == 121 and ref.duration_s == pytest.approx(60.0)
    np.testing.assert_allclose(ref.x[0, 0:3], [10.8, -7.75, 5.2])
    np.testing.assert_allclose(ref.x[-1, 0:3], [10.8, -7.75, 4.3], atol=1e-9)
    assert np.max(np.abs(ref.u[:, 0:3])) <= 0.25 + 1e-6 and np.max(np.abs(ref.u[:, 3:6])) <= 0.025 + 1e-6


def test_loaders_refuse_bad_files(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_reference(tmp_path / "nope.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("1,2,3\n4,5,6\n")
    with pytest.raises(InputError, match="expected 19 rows"):
        load_reference(bad)
    folder = tmp_path / "dat"
    folder.mkdir()
    (folder / "results_pos_0.dat").write_text("0 1 2 3\n")
    with pytest.raises(InputError, match=r"missing results_vel_0\.dat"):
        load_reference(folder)
    unnormalised = np.zeros((19, 3))
    unnormalised[9] = 2.0
    path = tmp_path / "q.csv"
    np.savetxt(path, unnormalised, delimiter=",")
    with pytest.raises(InputError, match="quaternion norm"):
        load_reference(path)


def test_track_follows_a_previous_stage_mcap(tmp_path):
    """--reference accepts a stage's MCAP: its /trajectory is read back and followed."""
    ref = make_reference()
    ref = Trajectory(ref.t, ref.x, ref.u, name="plan", frame="iss")  # the frame of iss_reswarm.yaml
    plan = tmp_path / "plan.mcap"
    with StageMcapWriter(plan, stage="plan", config_yaml="name: test\n", frame="iss") as writer:
        writer.write_trajectory("/trajectory", ref)
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["track", str(REPO / "configs" / "iss_reswarm.yaml"), "--reference", str(plan),
                                      "--out", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "ok" and summary["sim_time_s"] == pytest.approx(ref.duration_s + 5.0, abs=0.2)
    tel = read_telemetry(out / "track.mcap")
    np.testing.assert_allclose(tel.x_reference, sample_states(ref, tel.t_ctrl), atol=1e-12)
    assert np.linalg.norm(tel.x_true[-1, 0:3] - ref.x[-1, 0:3]) < 0.02
