"""The controllers' reference sampler gives the samples of oacli.trajectory.sample_states (before, inside and after
the reference, on and between its knots, a single-sample reference); its attitude chart and feed-forward are those
of oacli.model.quaternion.error_vector and oacli.trajectory.feedforward_inputs."""

from __future__ import annotations

import numpy as np

from oacli.control.reference_sampler import ReferenceSampler, attitude_errors, feedforward
from oacli.model import quaternion as quat
from oacli.reference import waypoint_reference
from oacli.trajectory import feedforward_inputs, sample_states
from oacli.types import InertialParams, Trajectory

PARAMS = InertialParams(9.5, np.array([0.153, 0.143, 0.162]))


def turning_reference() -> Trajectory:
    angles = [0.0, 1.2, -2.5]  # yaw turns, one past ±π/2 so the slerp takes a long arc
    quats = np.array([[0.0, 0.0, np.sin(a / 2), np.cos(a / 2)] for a in angles])
    return waypoint_reference(np.array([[0.0, 0.0, 0.0], [0.5, 0.2, -0.1], [0.6, -0.3, 0.2]]), quats, PARAMS,
                              speed_mps=0.1, accel_mps2=0.02, rate_radps=0.1, ang_accel_radps2=0.05, hold_s=1.0)


def test_samples_match_sample_states_everywhere(rng):
    ref = turning_reference()
    times = np.concatenate([rng.uniform(-2.0, ref.t[-1] + 5.0, 500), ref.t, [ref.t[0] - 1.0, ref.t[-1] + 1.0]])
    got = ReferenceSampler(ref).states(times)
    want = sample_states(ref, times)
    np.testing.assert_allclose(got, want, rtol=0.0, atol=1e-15)
    after = times > ref.t[-1]
    assert np.all(got[after][:, 3:6] == 0.0) and np.all(got[after][:, 10:13] == 0.0)
    np.testing.assert_allclose(np.linalg.norm(got[:, 6:10], axis=1), 1.0, atol=1e-15)


def test_single_sample_reference_holds_its_pose():
    ref = turning_reference()
    one = Trajectory(ref.t[:1], ref.x[:1], ref.u[:1], name="one", frame=ref.frame)
    times = np.array([-1.0, 0.0, 2.0])
    np.testing.assert_array_equal(ReferenceSampler(one).states(times), sample_states(one, times))


def test_attitude_errors_and_feedforward_are_the_generic_helpers(rng):
    for _ in range(200):
        anchor = quat.normalize(rng.normal(size=4))
        q = quat.normalize(rng.normal(size=(11, 4)))
        q[0] = anchor  # zero error: the small-angle branch
        np.testing.assert_allclose(attitude_errors(anchor, q), quat.error_vector(anchor, q), rtol=0, atol=1e-15)
        np.testing.assert_allclose(attitude_errors(anchor, q[5]), quat.error_vector(anchor, q[5]), rtol=0,
                                   atol=1e-15)
        x = rng.normal(size=(11, 13))
        np.testing.assert_allclose(feedforward(x, 0.2, PARAMS),
                                   feedforward_inputs(x, 0.2, PARAMS), rtol=0, atol=1e-15)
