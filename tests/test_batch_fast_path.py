"""The fast batch path against the original: structured propagation, block normal equations with a
Schur complement on φ, block-QR covariance; ``estimate_batch(..., reference=True)`` is the original."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from oacli.estimation import parametrization as par
from oacli.estimation.batch import estimate_batch, estimate_batch_windows, extend_states
from oacli.estimation.batch_problem import BatchProblem
from oacli.estimation.manifold import TANGENT_DIM, boxplus
from oacli.estimation.models import Measurement, ProcessNoise
from oacli.estimation.preprocessing import order_by_time
from oacli.estimation.propagation import (
    propagate_intervals,
    propagate_intervals_structured,
    propagate_state_one,
    substep_schedule,
)
from oacli.excitation.information import MeasurementModel as InfoModel
from oacli.sim.faults import inject_localisation_jumps
from oacli.sim.sensors import SensorNoise
from tests.conftest import random_state, require_shared
from tests.estimation_helpers import (
    PLANT_PERIOD_S,
    RATTLE_PRIOR,
    THETA_TRUE,
    records,
    settings,
    simulate_open_loop,
)

ROOT = Path(__file__).resolve().parents[1]


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def test_structured_propagation_equals_the_general_rk4(rng):
    """Closed-form translation + 7×10 rotational Jacobians give propagate_intervals' states and Jacobians, on
    uneven intervals (zero-padded sub-step rows), large rates and a non-physical-looking but valid θ."""
    k = 40
    x = np.array([random_state(rng, spin_radps=1.5) for _ in range(k)])
    x[::3, 9] *= -1.0  # quaternions with w < 0: the normalisation flips their sign
    u = rng.normal(0, 0.5, (k, 6))
    t0 = np.cumsum(rng.uniform(0.05, 0.4, k))
    t1 = t0 + rng.uniform(0.01, 0.45, k)
    sched = substep_schedule(t0, t1, PLANT_PERIOD_S)
    assert np.any(sched == 0.0)  # rows of different lengths
    theta = np.array([9.3, 0.21, 0.13, 0.27])
    ref = propagate_intervals(x, u, theta, sched)
    new = propagate_intervals_structured(x, u, theta, sched)
    for got, want in zip(new, ref, strict=True):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * max(1.0, np.max(np.abs(want))))
    states_only, a_none, c_none = propagate_intervals_structured(x, u, theta, sched, jacobians=False)
    np.testing.assert_allclose(states_only, ref[0], rtol=0, atol=1e-12 * np.max(np.abs(ref[0])))
    assert a_none is None and c_none is None


def _small_problem(rng, model):
    tel = simulate_open_loop(7, sensors=SensorNoise(0.01, 0.002, 0.005, 0.01), seed=5)
    acc = rng.normal(0, 0.01, (7, 3))
    recs = records(tel, linear_acceleration_mps2=acc, angular_acceleration_radps2=acc[::-1])
    recs[4] = Measurement(recs[4].t, recs[4].x_measured, recs[4].u_applied, recs[4].linear_acceleration_mps2,
                          recs[4].angular_acceleration_radps2, starts_segment=True)  # a gap: two segments
    problem = BatchProblem(recs, settings(measurement=model, process=ProcessNoise(0.01, 0.001)), RATTLE_PRIOR,
                       THETA_TRUE)
    x = boxplus(problem.y, rng.normal(0, 0.05, (7, 12)))
    phi = par.phi_from_theta(np.array([12.0, 0.12, 0.15, 0.17]))
    inliers = np.array([True, True, False, True, True, True, True])
    return problem, x, phi, inliers


def _dense(normal, k):
    """AᵀA and Aᵀb assembled from the blocks."""
    nt, n = TANGENT_DIM, TANGENT_DIM * k
    h = np.zeros((n + 4, n + 4))
    for i in range(k):
        h[nt * i:nt * (i + 1), nt * i:nt * (i + 1)] = normal.hd[i]
        h[nt * i:nt * (i + 1), n:] = normal.hxp[i]
        h[n:, nt * i:nt * (i + 1)] = normal.hxp[i].T
        if i < k - 1:
            h[nt * i:nt * (i + 1), nt * (i + 1):nt * (i + 2)] = normal.ho[i]
            h[nt * (i + 1):nt * (i + 2), nt * i:nt * (i + 1)] = normal.ho[i].T
    h[n:, n:] = normal.hpp
    return h, np.concatenate([normal.gx.ravel(), normal.gp])


MODELS = [
    InfoModel(0.01, 0.002, 0.005, 0.01, linear_acceleration_std_mps2=0.003, angular_acceleration_std_radps2=0.01),
    InfoModel(None, 0.002, None, 0.01),  # velocities only: gauge rows on each segment's first state
]


@pytest.mark.parametrize("model", MODELS, ids=["pose+velocity+accelerations", "velocities-only"])
def test_block_normal_equations_solve_and_covariance_equal_the_sparse_system(rng, model):
    """Blocks of AᵀA, Aᵀb equal the sparse A of the original; the Schur-complement step equals a dense solve of
    the damped system; the block-QR covariance of [x_K, φ] equals the last block of (AᵀA)⁻¹."""
    problem, x, phi, inliers = _small_problem(rng, model)
    b_ref, a_mat = problem.evaluate(x, phi, inliers, jacobian=True)
    a_dense = a_mat.toarray()
    h_ref, g_ref = a_dense.T @ a_dense, a_dense.T @ b_ref
    b, normal = problem.normal_equations(x, phi, inliers)
    np.testing.assert_allclose(b, b_ref, rtol=0, atol=1e-10 * np.max(np.abs(b_ref)))
    h, g = _dense(normal, problem.k)
    assert _relative(h, h_ref) < 1e-12 and _relative(g, g_ref) < 1e-12
    np.testing.assert_allclose(normal.diagonal(), np.diag(h_ref), rtol=1e-12)

    damping = 1e-3 * np.diag(h_ref) * rng.uniform(0.5, 2.0, h_ref.shape[0])
    step = normal.solve(damping)
    want = np.linalg.solve(h_ref + np.diag(damping), -g_ref)
    assert _relative(step, want) < 1e-9

    m = TANGENT_DIM + par.N_PARAMS
    r_inv = np.linalg.inv(np.linalg.qr(a_dense, mode="r")[-m:, -m:])  # last block of (AᵀA)⁻¹ = R⁻¹R⁻ᵀ
    cov_want = r_inv @ r_inv.T
    assert _relative(problem.last_covariance_qr(x, phi, inliers), cov_want) < 1e-10
    assert _relative(cov_want, np.linalg.inv(h_ref)[-m:, -m:]) < 1e-4  # the normal equations lose digits


def test_fast_path_equals_the_original_on_a_run_with_outliers_and_a_gap():
    """A simulated 20 s run with 5 % localisation jumps (several gating rounds) and a lost control step: the
    same iterations, inliers, θ̂ to 1e-6 relative (to rounding in fact) and the same covariance."""
    tel = simulate_open_loop(100, seed=11)
    x_jumped, _ = inject_localisation_jumps(tel.x_measured, 0.05, np.random.default_rng(3))
    recs = [Measurement(r.t, xj, r.u_applied, starts_segment=(i == 60))
            for i, (r, xj) in enumerate(zip(records(tel), x_jumped, strict=True))]
    new = estimate_batch(recs, settings(), RATTLE_PRIOR)
    old = estimate_batch(recs, settings(), RATTLE_PRIOR, reference=True)
    assert new.gating_rounds == old.gating_rounds >= 2 and new.segments == old.segments == 2
    assert new.iterations == old.iterations
    assert np.array_equal(new.inliers, old.inliers) and (~new.inliers).sum() >= 3
    assert np.max(np.abs(new.estimate.theta / old.estimate.theta - 1)) < 1e-6
    assert np.max(np.abs(new.states - old.states)) < 1e-8
    assert _relative(new.estimate.covariance, old.estimate.covariance) < 1e-6
    assert _relative(new.last_covariance, old.last_covariance) < 1e-6
    assert new.chi2_dof == old.chi2_dof and abs(new.chi2 / old.chi2 - 1) < 1e-8


@pytest.mark.slow
def test_fast_path_equals_the_original_on_the_iss_excitation_run(tmp_path):
    """The 60 s ISS excitation run (track stage, 325 records, configs/iss_reswarm.yaml with a payload): θ̂ and the
    covariance equal to the reference path's to 1e-6 relative, and to a dense QR of the same A; a
    sparse LU of AᵀA (cond ≈ 7e12, what the reference used to solve) is itself off by more than 1e-6."""
    from oacli.config import load_config
    from oacli.estimation.alignment import align_records
    from oacli.io.reference_files import load_reference
    from oacli.io.telemetry_streams import read_telemetry_streams
    from oacli.stages.settings import estimation_prior, estimator_settings
    from oacli.stages.track import run_track

    csv = require_shared(ROOT.parent / "shared" / "data" / "rattle-iros-2022" / "info-trajectories"
                         / "excitation_iss_11.csv")
    base = load_config(ROOT / "configs" / "iss_reswarm.yaml")
    cfg = base.model_copy(update={"truth": base.truth.model_copy(
        update={"mass_kg": 15.0, "inertia_kgm2": (0.1464, 0.1376, 0.1604)})})
    run_track(cfg, reference=load_reference(csv, sample_period_s=0.5, frame="iss"), out=tmp_path / "track")
    s = read_telemetry_streams(tmp_path / "track" / "track.mcap")
    use_loc = s.t_localisation is not None and s.t_localisation.size > 0
    t_meas, x_meas = (s.t_localisation, s.x_localisation) if use_loc else (s.t_measured, s.x_measured)
    recs, _ = align_records(t_meas, x_meas, s.t_applied, s.u_applied, reorder_window=cfg.estimation.reorder_window,
                            t_command=s.t_command, u_command=s.u_command,
                            input_limits=np.r_[cfg.robot.force_limit_N, cfg.robot.torque_limit_Nm])
    assert len(recs) > 300
    sets, prior = estimator_settings(cfg), estimation_prior(cfg)
    new = estimate_batch(recs, sets, prior)
    old = estimate_batch(recs, sets, prior, reference=True)
    assert new.iterations == old.iterations and np.array_equal(new.inliers, old.inliers)
    assert np.max(np.abs(new.estimate.theta / old.estimate.theta - 1)) < 1e-6
    problem = BatchProblem(order_by_time(recs).records, sets, prior, prior.theta)
    _, a_mat = problem.evaluate(new.states, new.phi, new.inliers, jacobian=True)
    m = TANGENT_DIM + par.N_PARAMS
    r_last = np.linalg.qr(a_mat.toarray(), mode="r")[-m:, -m:]
    r_inv = np.linalg.inv(r_last)
    assert _relative(new.last_covariance, r_inv @ r_inv.T) < 1e-6
    assert _relative(old.last_covariance, r_inv @ r_inv.T) < 1e-6
    assert _relative(new.last_covariance, old.last_covariance) < 1e-6
    assert _relative(new.estimate.covariance, old.estimate.covariance) < 1e-6
    n = problem.n_var
    rhs = np.zeros((n, m))
    rhs[n - m:] = np.eye(m)
    normal_lu = spla.splu((a_mat.T @ a_mat).tocsc()).solve(rhs)[n - m:]
    assert _relative(normal_lu, r_inv @ r_inv.T) > 1e-6  # why the reference solves the augmented system


def test_warm_started_windows_equal_cold_solves_of_the_same_records():
    """estimate_batch_windows warm-starts each window (no continuation, little damping): every window's
    θ̂, covariance and inliers equal a cold estimate_batch (continuation from the prior) of the same records, on a
    20 s run with 5 % localisation jumps (several gating rounds) and a gap in the inputs. (With this nearly rigid
    process model and windows that double, the warm start saves no iterations; on the default mission it saves
    two thirds: benchmarks/bench_batch_estimation.py --windows.)"""
    tel = simulate_open_loop(100, seed=11)
    x_jumped, _ = inject_localisation_jumps(tel.x_measured, 0.05, np.random.default_rng(3))
    recs = [Measurement(r.t, xj, r.u_applied, starts_segment=(i == 60))
            for i, (r, xj) in enumerate(zip(records(tel), x_jumped, strict=True))]
    ends = [5.0, 10.0, 15.0, recs[-1].t]
    windows = estimate_batch_windows(recs, settings(), RATTLE_PRIOR, ends)
    assert len(windows) == len(ends)
    for end, win in zip(ends, windows, strict=True):
        n = sum(r.t <= end + 1e-9 for r in recs)
        cold = estimate_batch(recs[:n], settings(), RATTLE_PRIOR)
        assert np.array_equal(win.inliers, cold.inliers) and win.segments == cold.segments
        assert np.max(np.abs(win.estimate.theta / cold.estimate.theta - 1)) < 1e-6
        assert _relative(win.estimate.covariance, cold.estimate.covariance) < 1e-6
        assert win.converged
    assert windows[-1].segments == 2 and windows[-1].gating_rounds >= 2


def test_state_only_propagation_equals_the_general_rk4(rng):
    """propagate_state_one (Python floats) and the states-only structured path give propagate_intervals' states;
    extend_states chains them record by record and restarts at a segment start."""
    k = 12
    x = np.array([random_state(rng, spin_radps=1.5) for _ in range(k)])
    u = rng.normal(0, 0.5, (k, 6))
    t0 = np.cumsum(rng.uniform(0.05, 0.4, k))
    t1 = t0 + rng.uniform(0.01, 0.45, k)
    sched = substep_schedule(t0, t1, PLANT_PERIOD_S)
    theta = np.array([9.3, 0.21, 0.13, 0.27])
    want = propagate_intervals(x, u, theta, sched)[0]
    for i in range(k):
        np.testing.assert_allclose(propagate_state_one(x[i], u[i], theta, sched[i]), want[i], rtol=0, atol=1e-12)
    got = propagate_intervals_structured(x, u, theta, sched, jacobians=False)[0]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)

    tel = simulate_open_loop(8, seed=2)
    recs = records(tel)
    recs[6] = Measurement(recs[6].t, recs[6].x_measured, recs[6].u_applied, starts_segment=True)
    out = extend_states(tel.x_measured[:3], recs, theta, PLANT_PERIOD_S)
    np.testing.assert_array_equal(out[:3], tel.x_measured[:3])
    np.testing.assert_array_equal(out[6], recs[6].x_measured)  # a segment starts from its measurement
    for i in (3, 4, 5, 7):
        step = substep_schedule(np.array([recs[i - 1].t]), np.array([recs[i].t]), PLANT_PERIOD_S)
        expected = propagate_intervals(out[i - 1][None], recs[i - 1].u_applied[None], theta, step)[0][0]
        np.testing.assert_allclose(out[i], expected, rtol=0, atol=1e-12)
