"""The tracking stages' speed pass changed no number: each rewritten step equals, value for value (not to a
tolerance), the form it replaced — kept here as the reference — so the closed loop stays bit-identical
(``benchmarks/bench_track.py --check-fingerprint`` checks the whole mission's track stages)."""

from __future__ import annotations

import cvxpy as cp
import numpy as np
import pytest

import oacli.control.tube_design as td
from oacli.control.compiled_qp import CompiledQP
from oacli.control.disturbance import DisturbanceSpec
from oacli.control.reference_sampler import ReferenceSampler, attitude_errors
from oacli.control.tube_design import AncillaryWeights, design_translation_tube
from oacli.control.workspace import WorkspaceRows
from oacli.geometry.halfspaces import best_piece
from oacli.geometry.shapes import Box, Scene
from oacli.model import quaternion as quat
from oacli.reference import waypoint_reference
from oacli.types import InertialParams, Trajectory
from tests.model_helpers import mass_model

PARAMS = InertialParams(9.5, np.array([0.153, 0.143, 0.162]))


def _old_states(sampler: ReferenceSampler, times: np.ndarray) -> np.ndarray:
    """ReferenceSampler.states before the speed pass (per-array gathers, np.linalg.norm, np.where always)."""
    t = sampler.t
    out = np.empty((times.size, 13))
    idx = np.clip(np.searchsorted(t, times, side="right") - 1, 0, t.size - 2)
    s = np.clip((times - t[idx]) / sampler._dt[idx], 0.0, 1.0)
    x0 = sampler.x[idx]
    out[:] = x0 + s[:, None] * sampler._dx[idx]
    phi = s[:, None] * sampler._delta[idx]
    angle = np.linalg.norm(phi, axis=-1, keepdims=True)
    half = 0.5 * angle
    small = angle < 1e-6
    safe = np.where(small, 1.0, angle)
    k = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / safe)
    ev = k * phi
    ew = np.cos(half)
    pv, pw = x0[:, 6:9], x0[:, 9:10]
    q = np.empty((times.size, 4))
    q[:, 0:3] = pw * ev + ew * pv + np.cross(pv, ev)
    q[:, 3:4] = pw * ew - np.sum(pv * ev, axis=-1, keepdims=True)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    out[:, 6:10] = np.where(q[:, 3:4] < 0.0, -q, q)
    after = times > t[-1]
    out[after, 3:6] = 0.0
    out[after, 10:13] = 0.0
    return out


def _old_attitude_errors(q_ref: np.ndarray, q: np.ndarray) -> np.ndarray:
    """attitude_errors before the speed pass."""
    pv, pw = -q_ref[..., :3], q_ref[..., 3:4]
    qv, qw = q[..., :3], q[..., 3:4]
    r = np.empty(np.broadcast_shapes(q_ref.shape, q.shape))
    r[..., :3] = pw * qv + qw * pv + np.cross(pv, qv)
    r[..., 3:4] = pw * qw - np.sum(pv * qv, axis=-1, keepdims=True)
    r = r / np.linalg.norm(r, axis=-1, keepdims=True)
    r = np.where(r[..., 3:4] < 0.0, -r, r)
    v, w = r[..., :3], r[..., 3:4]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, w)
    small = s < 1e-9
    return np.where(small, 2.0 / np.where(small, w, 1.0), angle / np.where(small, 1.0, s)) * v


def _reference() -> Trajectory:
    angles = [0.0, 1.2, -2.5, -2.5]  # the last segment does not turn: small-angle slerp
    quats = np.array([[0.0, 0.0, np.sin(a / 2), np.cos(a / 2)] for a in angles])
    return waypoint_reference(np.array([[0.0, 0.0, 0.0], [0.5, 0.2, -0.1], [0.6, -0.3, 0.2], [0.9, -0.3, 0.2]]),
                              quats, PARAMS, speed_mps=0.1, accel_mps2=0.02, rate_radps=0.1, ang_accel_radps2=0.05,
                              hold_s=1.0)


def test_sampler_states_are_the_previous_values_exactly(rng):
    ref = _reference()
    sampler = ReferenceSampler(ref)
    for _ in range(200):  # controller-like requests: a start time and the horizon's offsets
        times = rng.uniform(-2.0, ref.t[-1] + 3.0) + 0.2 * np.arange(11)
        np.testing.assert_array_equal(sampler.states(times), _old_states(sampler, times))
    knots = np.concatenate([ref.t, ref.t[:-1] + 1e-9])
    np.testing.assert_array_equal(sampler.states(knots), _old_states(sampler, knots))


def test_attitude_errors_are_the_previous_values_and_row_independent(rng):
    for _ in range(200):
        anchor = quat.normalize(rng.normal(size=4))
        q = quat.normalize(rng.normal(size=(12, 4)))
        q[0] = anchor  # zero error: the small-angle branch
        q[1] = -anchor
        batch = attitude_errors(anchor, q)
        np.testing.assert_array_equal(batch, _old_attitude_errors(anchor, q))
        big = q[2:]  # no small angle: the branch without np.where
        np.testing.assert_array_equal(attitude_errors(anchor, big), _old_attitude_errors(anchor, big))
        for i in range(q.shape[0]):  # the controllers chart the measured attitude with the references
            np.testing.assert_array_equal(attitude_errors(anchor, q[i]), batch[i])


def _old_parameter_vector(compiled: CompiledQP, values: dict) -> np.ndarray:
    theta = np.zeros(compiled._n_params + 1)
    for _param, col, size, pid in compiled._param_slices:
        theta[col : col + size] = np.asarray(values[pid], dtype=float).ravel(order="F")
    theta[compiled._const_col] = 1.0
    return theta


def test_compiled_qp_data_are_the_previous_products(rng):
    """θ through column-major views and one stacked product give the bytes of the per-matrix products; the
    solution still matches cvxpy's."""
    x = cp.Variable((4, 3))
    y = cp.Variable(3)
    ref = cp.Parameter((4, 3))
    lim = cp.Parameter(3)
    normal = cp.Parameter((4, 3))
    scale = cp.Parameter()
    problem = cp.Problem(cp.Minimize(cp.sum_squares(x) + cp.sum_squares(y) - 2 * cp.sum(cp.multiply(ref, x))
                                     + scale * cp.sum(y)),
                         [x[0] <= lim, cp.sum(cp.multiply(normal, x), axis=1) >= -1.0, y >= -lim])
    compiled = CompiledQP(problem)
    for _ in range(20):
        values = {ref.id: rng.normal(size=(4, 3)), lim.id: rng.uniform(0.1, 1.0, 3),
                  normal.id: rng.normal(size=(4, 3)), scale.id: np.asarray(rng.normal())}
        theta = compiled.parameter_vector(values)
        np.testing.assert_array_equal(theta, _old_parameter_vector(compiled, values))
        stacked = compiled._t_all @ theta
        want = np.concatenate([compiled._t_q @ theta, compiled._t_b @ theta, compiled._t_a @ theta])
        np.testing.assert_array_equal(stacked, want)
        info = compiled.solve(values)
        for param in (ref, lim, normal, scale):
            param.value = values[param.id]
        problem.solve(solver=cp.CLARABEL)
        assert info.success
        assert info.objective == pytest.approx(problem.value, rel=1e-6, abs=1e-8)
        # Clarabel equilibrated A once, at set-up (CompiledQP): the iterates differ, the optimum within tolerance.
        np.testing.assert_allclose(compiled.value(x), x.value, atol=1e-4)
        np.testing.assert_allclose(compiled.value(y), y.value, atol=1e-4)
    flat = {ref.id: values[ref.id].ravel(order="F")[:, None], lim.id: values[lim.id], normal.id: values[normal.id],
            scale.id: values[scale.id]}  # another shape of the same size: the column-major flattening
    np.testing.assert_array_equal(compiled.parameter_vector(flat), theta)


def test_segment_pieces_are_best_piece(rng):
    scene = Scene(keep_in=(Box(np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0])),
                           Box(np.array([0.5, -0.5, -0.5]), np.array([3.0, 0.5, 0.5]))))
    rows = WorkspaceRows(scene, keep_in_margin_m=0.05, extent_m=np.array([[0.01, 0.02]] * 3), clearance_m=0.01)
    margin = 0.5 * (rows._shrink_lower + rows._shrink_upper)
    for _ in range(300):
        ref = rng.uniform(-1.5, 3.5, size=(11, 3))
        lin = ref + rng.normal(scale=0.2, size=ref.shape)
        want = best_piece(rows._lower, rows._upper, ref[:-1], ref[1:], lin[:-1], lin[1:], margin=margin)
        np.testing.assert_array_equal(rows._best_segment_pieces(ref, lin), want)


def _isotropic_design():
    spec = DisturbanceSpec(force_N=np.full(3, 0.002))
    return design_translation_tube(model=mass_model(9.5, 0.1), dt_s=0.2, force_limit_N=np.full(3, 0.15),
                                   velocity_limit_mps=np.full(3, 0.2), weights=AncillaryWeights(5.0, 10.0, 2.0),
                                   spec=spec, epsilon=0.05)


@pytest.mark.parametrize("axis", [1, 2])
def test_an_isotropic_robot_designs_its_axis_once(axis):
    """The y and z tubes of an isotropic robot are the x design under their own names, equal in every figure to a
    design of that axis computed alone (memo cleared)."""
    td._AXIS_CACHE.clear()
    design = _isotropic_design()
    assert [ax.name for ax in design.axes] == ["x", "y", "z"]
    shared = design.axes[axis]
    assert shared.rpi is design.axes[0].rpi  # not recomputed
    summary = design.summary()
    td._AXIS_CACHE.clear()
    alone = td._design_axis_from_parts(
        shared.name, shared.a, shared.b, shared.gain, shared.disturbance, force_limit_N=shared.force_limit_N,
        velocity_limit_mps=shared.velocity_limit_mps, epsilon=shared.epsilon, epsilon_mode=shared.epsilon_mode,
        max_terms=1000, facet_growth=td.DEFAULT_FACET_GROWTH)
    np.testing.assert_array_equal(alone.z.a, shared.z.a)
    np.testing.assert_array_equal(alone.z.b, shared.z.b)
    assert alone.force_bounds_N == shared.force_bounds_N
    assert alone.velocity_bounds_mps == shared.velocity_bounds_mps
    assert alone.minimal_support == shared.minimal_support
    td._AXIS_CACHE.clear()
    assert _isotropic_design().summary() == summary


# -- the tube MPC step's speed pass ---------------------------------------------------------------


def _old_rows(rows: WorkspaceRows, ref: np.ndarray, lin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """WorkspaceRows.rows' keep-in bounds before the speed pass (vstack of the segment pieces' intersections)."""
    idx = best_piece(rows._lower, rows._upper, ref[:-1], ref[1:], lin[:-1], lin[1:],
                     margin=0.5 * (rows._shrink_lower + rows._shrink_upper))
    seg_lo, seg_hi = rows._lower[idx], rows._upper[idx]
    lower = np.vstack([seg_lo[:1], np.maximum(seg_lo[:-1], seg_lo[1:]), seg_lo[-1:]])
    upper = np.vstack([seg_hi[:1], np.minimum(seg_hi[:-1], seg_hi[1:]), seg_hi[-1:]])
    return lower + rows._shrink_lower, upper - rows._shrink_upper


def test_keep_in_rows_are_the_previous_values_exactly(rng):
    scene = Scene(keep_in=(Box(np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0])),
                           Box(np.array([0.5, -0.5, -0.5]), np.array([3.0, 0.5, 0.5]))))
    rows = WorkspaceRows(scene, keep_in_margin_m=0.05, extent_m=np.array([[0.01, 0.02]] * 3), clearance_m=0.01)
    for k in (2, 3, 11, 41):
        for _ in range(50):
            ref = rng.uniform(-1.5, 3.5, size=(k, 3))
            lin = ref + rng.normal(scale=0.2, size=ref.shape)
            got = rows.rows(ref, lin)
            lower, upper = _old_rows(rows, ref, lin)
            np.testing.assert_array_equal(got.lower, lower)
            np.testing.assert_array_equal(got.upper, upper)
            origin = rng.normal(size=3)
            shifted = got.shifted(origin)
            np.testing.assert_array_equal(shifted.lower, lower - origin)
            np.testing.assert_array_equal(shifted.offsets, got.offsets - got.normals @ origin)


def _tube_qp_with_rows(fast: bool = True):
    """A tube block with keep-in, braking and one keep-out zone (a Parameter in A) and a standard block."""
    from oacli.control.tube_qp import LinearConstraint, NominalQP, PositionRowsSpec, QPBlock
    from oacli.model.double_integrator import double_integrator

    a1, b1 = double_integrator(1.0, 1 / 9.5)
    a = np.kron(a1, np.eye(3))
    b = np.kron(b1, np.eye(3))
    box = LinearConstraint.box(np.r_[np.full(3, np.inf), np.full(3, 0.2)])
    lasso = LinearConstraint.box(np.r_[np.full(3, 0.01), np.full(3, 0.005)])
    spec = PositionRowsSpec(keep_in=True, keep_out_zones=1, braking_mps2=np.full(3, 0.01),
                            braking_speed_mps=np.full(3, 0.2))
    trans = QPBlock("translation", a, b, np.r_[np.full(3, 50.0), np.full(3, 5.0)], np.full(3, 0.1),
                    np.diag(np.r_[np.full(3, 100.0), np.full(3, 10.0)]), state=box,
                    input=LinearConstraint.box(np.full(3, 0.14)), lasso=lasso, positions=spec)
    rot = QPBlock("attitude", a, b, np.r_[np.full(3, 10.0), np.ones(3)], np.full(3, 100.0), np.eye(6),
                  state=LinearConstraint.box(np.r_[np.full(3, np.inf), np.full(3, 0.17)]),
                  input=LinearConstraint.box(np.full(3, 0.02)))
    return NominalQP([trans, rot], 5, fast=fast)


def _random_instance(qp, rng):
    from oacli.control.workspace import PositionRows

    n = qp.horizon
    for name in ("translation", "attitude"):
        qp.set_parameters(name, rng.normal(size=6) * 0.01, np.cumsum(rng.normal(size=(n + 1, 6)) * 0.02, axis=0),
                          rng.normal(size=(n, 3)) * 0.01)
    normal = rng.normal(size=(n + 1, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    active = rng.random() < 0.5  # inactive rows (zero normals) as the workspace gives far from a zone
    rows = PositionRows(np.full((n + 1, 3), -1.0), np.full((n + 1, 3), 1.0),
                        (normal if active else np.zeros_like(normal))[None],
                        np.full((1, n + 1), -0.3 if active else -1.0))
    qp.set_rows("translation", rows)


def test_nominal_qp_solution_is_the_previous_path_exactly(rng):
    """θ written in place and the solution gathered from x at once give the bytes (and layouts) of the previous
    path: θ from the values dict, CompiledQP.solve, cvxpy-shaped values stacked and copied, np.sum."""
    qp = _tube_qp_with_rows()
    compiled = qp.compiled
    for _ in range(20):
        _random_instance(qp, rng)
        theta = compiled.parameter_vector(qp._values)
        np.testing.assert_array_equal(qp._theta, theta)
        new = qp.solve()
        assert new.info.success
        old = compiled.solve(qp._values)  # the same data: Clarabel repeats its iterates
        constant = 0.0
        for name, bv in qp._vars.items():
            q_w, r_w, p_n = qp._weights[name]
            x_ref, u_ref = qp._values[bv.x_ref.id], qp._values[bv.u_ref.id]
            constant += float(np.sum(q_w * x_ref[:-1] ** 2) + np.sum(r_w * u_ref**2) + x_ref[-1] @ p_n @ x_ref[-1])
            z = np.vstack([compiled.value(bv.z), compiled.value(bv.z_n)[None, :]])
            v = np.array(compiled.value(bv.v))
            got = new.blocks[name]
            for mine, want in ((got.z, z), (got.v, v)):
                np.testing.assert_array_equal(mine, want)
                assert (mine.flags.c_contiguous, mine.flags.f_contiguous) == (want.flags.c_contiguous,
                                                                              want.flags.f_contiguous)
            slack = 0.0 if bv.slack is None else float(np.max(compiled.value(bv.slack), initial=0.0))
            assert got.max_slack == max(slack, 0.0)
        assert new.info.objective == old.objective + constant
        assert new.info.iterations == old.iterations


def test_a_parameter_that_is_not_finite_is_refused_by_name(rng):
    for fast in (True, False):
        qp = _tube_qp_with_rows(fast=fast)
        _random_instance(qp, rng)
        x = np.zeros(6)
        x[2] = np.nan
        qp.set_parameters("attitude", x, np.zeros((6, 6)), np.zeros((5, 3)))
        with pytest.raises(ValueError, match="attitude_x: expected finite values"):
            qp.solve()
        with pytest.raises(ValueError, match="translation_x: expected finite values of shape"):
            qp.set_parameters("translation", np.zeros(5), np.zeros((6, 6)), np.zeros((5, 3)))
