"""The convex subproblem of the offline excitation design's SCP (:mod:`oacli.excitation.design`), built once
with cvxpy Parameters (DPP) and solved with Clarabel.

Around the current rollout it finds the step ``δu`` that minimises the exact convex criterion of the linearised
Fisher information ([Doerr2021] Eq. 30) plus the ℓ1 penalty of the slacks, subject to the linearised
dynamics (translation exact, rotation by the RK4 Jacobians), the input bounds, the trust region and the softened
velocity, rate, keep-in, keep-out and terminal constraints (see the module docstring of
:mod:`oacli.excitation.design`).
"""

from __future__ import annotations

import clarabel
import cvxpy as cp
import numpy as np

from oacli.control.compiled_qp import CompiledQP
from oacli.excitation.convex import RotationDynamics
from oacli.excitation.design_types import ExcitationProblem
from oacli.excitation.fim_gradient import SYMMETRIC_PAIRS
from oacli.excitation.information import N_PARAMS
from oacli.excitation.merit import Evaluation, ScpMerit
from oacli.excitation.problem import LENGTH_UNIT_M, attitude_error, keep_in_sample_bounds, segment_halfspaces
from oacli.geometry.halfspaces import keep_out_zone
from oacli.solver import solve_clarabel, solver_error_status

_MASS_INDEX = SYMMETRIC_PAIRS.index((0, 0))
_INERTIA_PAIRS = tuple((a, b) for a, b in SYMMETRIC_PAIRS if a > 0)
_SCATTER = np.zeros((N_PARAMS * N_PARAMS, 1 + len(_INERTIA_PAIRS)))
"""Row-major vec of the 4×4 change of F from ``[ΔF_mm, ΔF_II (a ≤ b)]`` (symmetric; F_mI unchanged)."""
_SCATTER[0, 0] = 1.0
for _col, (_a, _b) in enumerate(_INERTIA_PAIRS, start=1):
    _SCATTER[_a * N_PARAMS + _b, _col] = _SCATTER[_b * N_PARAMS + _a, _col] = 1.0


def _two_sided(expr: cp.Expression, bound: cp.Expression) -> list[cp.Constraint]:
    """``|expr| ≤ bound`` as two linear rows per entry (``cp.abs`` adds an epigraph variable and a third row)."""
    return [expr <= bound, -bound <= expr]


class ConvexSubproblem:
    """The convexified design problem around an iterate; cvxpy problem built once with Parameters.

    Parameters
    ----------
    problem : ExcitationProblem
    merit : ScpMerit
        The merit whose margins and reference the subproblem mirrors.
    penalty : float
        Exact-penalty weight μ on the slacks.
    linearisation_margin : float, optional
        κ: constraints the model predicts only to first order (final attitude and rate) aim at κ × their bound,
        never tighter than the current value.
    rate_margin_fraction : float, optional
        The rate limits aim at ``1 − (1 − κ) × rate_margin_fraction`` of the limit, likewise.
    compiled : bool, optional
        Solve through :class:`oacli.control.compiled_qp.CompiledQP` (the DPP problem canonicalised once at the
        first solve, then only its data updated in one Clarabel solver) instead of ``problem.solve()`` (which
        re-canonicalises every time); the same problem and solver, so the same solution to solver tolerance.
    """

    def __init__(
        self, problem: ExcitationProblem, merit: ScpMerit, penalty: float, linearisation_margin: float = 0.5,
        rate_margin_fraction: float = 0.05, compiled: bool = False,
    ) -> None:
        p = problem
        self.compiled = compiled
        self._compiled_qp: CompiledQP | None = None
        self._values: dict[int, np.ndarray] = {}
        self.linearisation_margin = linearisation_margin
        self.rate_margin_fraction = rate_margin_fraction
        n = p.steps
        dt = p.dt
        m = p.theta[0]
        lim = p.limits
        self.p = p
        self.n = n
        self.du = cp.Variable((n, 6), name="du")
        dr = cp.Variable((n + 1, 3), name="dr")
        dv = cp.Variable((n + 1, 3), name="dv")
        drot = cp.Variable((n + 1, 7), name="drot")  # [δq (4), δω (3)]
        du = self.du

        self.v_bar = cp.Parameter((n + 1, 3), name="v_bar")
        self.w_bar = cp.Parameter((n + 1, 3), name="w_bar")
        self.delta = np.zeros(6)
        """Trust region of the last :meth:`set_iterate` per channel [N, N·m]."""

        self.rotation = RotationDynamics(drot, du[:, 3:6])
        cons = [dr[0] == 0, dv[0] == 0, *self.rotation.constraints]
        cons += [
            dr[1:] == dr[:-1] + dt * dv[:-1] + (dt**2 / (2.0 * m)) * du[:, 0:3],
            dv[1:] == dv[:-1] + (dt / m) * du[:, 0:3],
        ]
        # Input bounds and trust region in one box per entry: max(−u_max − ū, −Δ) ≤ δu ≤ min(u_max − ū, Δ) (two rows
        # per entry; |·| would add an epigraph variable and three rows per entry for the same feasible set).
        self.du_lower = cp.Parameter((n, 6), name="du_lower")
        self.du_upper = cp.Parameter((n, 6), name="du_upper")
        cons += [du >= self.du_lower, du <= self.du_upper]

        slacks = []
        self._slack_cons: list[cp.Constraint] = []
        s_v = self._slack(n, "s_velocity")
        s_w = self._slack(n, "s_rate")
        self.w_bound = cp.Parameter((n, 3), nonneg=True, name="rate_bound")
        v_cap = cp.reshape(1.0 + s_v, (n, 1), order="C") @ lim.velocity_mps[None, :]
        w_cap = self.w_bound + cp.reshape(s_w, (n, 1), order="C") @ lim.angular_velocity_radps[None, :]
        cons += [*_two_sided(self.v_bar[1:] + dv[1:], v_cap), *_two_sided(self.w_bar[1:] + drot[1:, 4:7], w_cap)]
        slacks += [s_v, s_w]
        self._rotational = [False, True]  # per slack (the terminal one, last, is split by hand)

        self.has_keep_in = bool(p.scene.keep_in)
        if self.has_keep_in:
            # Bounds on dr relative to the iterate, per sample: the intersection of the boxes of its two segments
            # (:func:`oacli.excitation.problem.keep_in_sample_bounds`), one slack per sample.
            self.in_lo = cp.Parameter((n + 1, 3), name="in_lo")
            self.in_hi = cp.Parameter((n + 1, 3), name="in_hi")
            s_in = self._slack(n + 1, "s_keep_in")
            ls = cp.reshape(LENGTH_UNIT_M * s_in, (n + 1, 1), order="C") @ np.ones((1, 3))
            cons += [dr >= self.in_lo - ls, dr <= self.in_hi + ls]
            slacks.append(s_in)
            self._rotational.append(False)
        self.out_n: list[cp.Parameter] = []
        self.out_c0: list[cp.Parameter] = []
        self.out_c1: list[cp.Parameter] = []
        for e in range(len(p.scene.keep_out)):
            n_hat = cp.Parameter((n, 3), name=f"out_n{e}")
            c0 = cp.Parameter(n, name=f"out_c0_{e}")
            c1 = cp.Parameter(n, name=f"out_c1_{e}")
            s_out = self._slack(n, f"s_keep_out{e}")
            cons += [
                cp.sum(cp.multiply(n_hat, dr[:-1]), axis=1) >= c0 - LENGTH_UNIT_M * s_out,
                cp.sum(cp.multiply(n_hat, dr[1:]), axis=1) >= c1 - LENGTH_UNIT_M * s_out,
            ]
            self.out_n.append(n_hat)
            self.out_c0.append(c0)
            self.out_c1.append(c1)
            slacks.append(s_out)
            self._rotational.append(False)

        tol = p.terminal
        self.r_end = cp.Parameter(3, name="r_end_minus_goal")
        self.att_err = cp.Parameter(3, name="attitude_error_end")
        self.att_jac = cp.Parameter((3, 4), name="attitude_error_jacobian")
        self.att_bound = cp.Parameter(3, nonneg=True, name="attitude_bound")
        self.w_end_bound = cp.Parameter(3, nonneg=True, name="rate_end_bound")
        s_t = self._slack(4, "s_terminal")
        cons += [
            *_two_sided(self.r_end + dr[n], tol.position_m * (1.0 + s_t[0])),
            *_two_sided(self.v_bar[n] + dv[n], tol.velocity_mps * (1.0 + s_t[1])),
            *_two_sided(self.att_err + self.att_jac @ drot[n, 0:4], self.att_bound + tol.attitude_rad * s_t[2]),
            *_two_sided(self.w_bar[n] + drot[n, 4:7], self.w_end_bound + tol.angular_velocity_radps * s_t[3]),
        ]
        slacks.append(s_t)
        self._rotational.append(True)
        self.slacks = slacks
        self.last_objective = float("nan")
        """Objective value of the last solve (NaN when it failed)."""
        self._last_translation_slack = float("nan")
        self.translation_slack = float("nan")
        """Slacks of the last (compiled) solve on translational constraints (velocity, keep-in, keep-out, terminal
        position and velocity): the model's violation of a force-only step."""

        crit_expr = self._information_model(du, cons, n)
        cons += self._slack_cons
        penalty_expr = sum(cp.sum(s) for s in slacks)
        self.problem = cp.Problem(cp.Minimize(crit_expr + penalty * penalty_expr), cons)
        self.merit = merit

    def _information_model(self, du: cp.Variable, cons: list[cp.Constraint], n: int) -> cp.Expression:
        """The criterion of the affine model of the (scaled) FIM in the step ``du``; its constraints appended to
        ``cons`` (overridden for the full rigid body, :mod:`oacli.excitation.design_full`)."""
        p = self.p
        # Affine model of the (scaled) FIM: F̃(δu) = F̃0 + Σ_ab E_ab ⟨∇F̃_ab, δu⟩. Translation and rotation are
        # decoupled (F_mI ≡ 0 for every input, :mod:`oacli.excitation.split_information`): F_mm moves with the
        # forces only, the six entries of F_II with the torques only, F_mI not at all. So the gradient has 7 rows
        # of N·3 (not 16 of N·6, four times the dense entries in the solver's KKT system), kept in a variable
        # ``dfim`` (7) so that the 4×4 matrix refers to each of them by one entry.
        self.f0 = cp.Parameter((N_PARAMS, N_PARAMS), name="fim0")
        self.g_force = cp.Parameter((1, 3 * n), name="fim_gradient_force")
        self.g_torque = cp.Parameter((len(_INERTIA_PAIRS), 3 * n), name="fim_gradient_torque")
        dfim = cp.Variable(1 + len(_INERTIA_PAIRS), name="fim_change")
        cons += [
            dfim[0:1] == self.g_force @ cp.vec(du[:, 0:3], order="C"),
            dfim[1:] == self.g_torque @ cp.vec(du[:, 3:6], order="C"),
        ]
        fim_var = cp.Variable((N_PARAMS, N_PARAMS), symmetric=True, name="fim")
        cons.append(fim_var == self.f0 + cp.reshape(_SCATTER @ dfim, (N_PARAMS, N_PARAMS), order="C"))
        self.crit_param = cp.Parameter((N_PARAMS, N_PARAMS), name="criterion_weight")
        if p.criterion == "A":
            z = cp.Variable((2 * N_PARAMS, 2 * N_PARAMS), PSD=True, name="schur")
            cons += [z[:N_PARAMS, :N_PARAMS] == fim_var, z[:N_PARAMS, N_PARAMS:] == self.crit_param]
            crit_expr = cp.trace(z[N_PARAMS:, N_PARAMS:])
        elif p.criterion == "D":
            crit_expr = -cp.log_det(fim_var) / N_PARAMS
        else:
            t_min = cp.Variable(name="lambda_min")
            z = cp.Variable((N_PARAMS, N_PARAMS), PSD=True, name="lmi")
            cons.append(z == fim_var - t_min * self.crit_param)
            crit_expr = -t_min
        return crit_expr

    def _slack(self, size: int, name: str) -> cp.Variable:
        """A non-negative slack: a ``nonneg`` Variable, or (compiled) a plain one with ``s >= 0`` (cvxpy replaces
        variables with attributes in its reduction chain, and the compiled path reads the original ones)."""
        if not self.compiled:
            return cp.Variable(size, nonneg=True, name=name)
        var = cp.Variable(size, name=name)
        self._slack_cons.append(var >= 0)
        return var

    def set_iterate(self, ev: Evaluation, lin, delta_force: float, delta_torque: float) -> None:
        """Linearise around an iterate: set every Parameter of the subproblem.

        Parameters
        ----------
        ev : Evaluation
            The current iterate.
        lin : FimGradient
            Its rotational RK4 Jacobians and FIM gradients (:func:`oacli.excitation.fim_gradient.fim_gradients`).
        delta_force, delta_torque : float
            Trust regions Δ as fractions of the force and torque limits.
        """
        p = self.p
        n = self.n
        # After the compiled problem's first solve its data come straight from these values (no cvxpy validation of
        # each Parameter assignment); before it, and on the reference path, the Parameters get them.
        direct = self._compiled_qp is not None
        values = self._values

        def put(param: cp.Parameter, value: np.ndarray) -> None:
            if direct:
                values[param.id] = value
            else:
                param.value = value

        x = ev.x
        u_max = p.limits.input
        self.delta = np.concatenate([delta_force * p.limits.force_N, delta_torque * p.limits.torque_Nm])
        put(self.du_lower, np.maximum(-u_max - ev.u, -self.delta))
        put(self.du_upper, np.minimum(u_max - ev.u, self.delta))
        put(self.v_bar, x[:, 3:6])
        put(self.w_bar, x[:, 10:13])
        for j, param in enumerate(self.rotation.a_cols):
            put(param, lin.a[:, 6:13, 6 + j])
        for j, param in enumerate(self.rotation.b_cols):
            put(param, lin.b[:, 6:13, 3 + j])
        pos = x[:, 0:3]
        margin = self.merit.margin
        if self.has_keep_in:
            lo, hi = keep_in_sample_bounds(p.scene, pos, margin)
            put(self.in_lo, lo - pos)
            put(self.in_hi, hi - pos)
        for e, ell in enumerate(p.scene.keep_out):
            n_hat, beta = segment_halfspaces(keep_out_zone(ell), pos[:-1], pos[1:], lateral_inside=True)
            bound = beta + self.merit.keep_out_margin
            put(self.out_n[e], n_hat)
            put(self.out_c0[e], bound - np.einsum("ki,ki->k", n_hat, pos[:-1]))
            put(self.out_c1[e], bound - np.einsum("ki,ki->k", n_hat, pos[1:]))
        put(self.r_end, pos[n] - p.goal[0:3])
        err, jac = attitude_error(p.goal[6:10], x[n, 6:10])
        put(self.att_err, err)
        put(self.att_jac, jac)
        # Constraints the linear model predicts only to first order (rotation) are aimed at a tightened bound
        # (κ × the true one) but never tighter than the current value, so the slacks at zero step still equal the
        # true violations: linearisation errors of a step then stay inside the true bound (no Maratos effect).
        kappa = self.linearisation_margin
        tol = p.terminal
        put(self.att_bound, np.minimum(tol.attitude_rad, np.maximum(kappa * tol.attitude_rad, np.abs(err))))
        w_end = np.abs(x[n, 10:13])
        put(self.w_end_bound, np.minimum(tol.angular_velocity_radps,
                                         np.maximum(kappa * tol.angular_velocity_radps, w_end)))
        w_max = p.limits.angular_velocity_radps[None, :]
        rate_kappa = 1.0 - (1.0 - kappa) * self.rate_margin_fraction
        put(self.w_bound, np.minimum(w_max, np.maximum(rate_kappa * w_max, np.abs(x[1:, 10:13]))))

        self._set_information(ev, lin, put)

    def _set_information(self, ev: Evaluation, lin, put) -> None:
        """Set the FIM model's Parameters around the iterate (see :meth:`_information_model`)."""
        p = self.p
        # Scaled FIM model: F̃ = Dθ F Dθ / c with c = tr(Dθ F Dθ)/4 (O(1) numbers for the conic solver).
        d_theta = np.abs(p.theta)
        f_rel = d_theta[:, None] * ev.fim * d_theta[None, :]
        c = float(np.trace(f_rel)) / N_PARAMS
        put(self.f0, f_rel / c)
        grads = lin.gradients
        put(self.g_force, (grads[_MASS_INDEX, :, 0:3].reshape(1, -1) * (d_theta[0] ** 2 / c)))
        put(self.g_torque, np.stack([grads[SYMMETRIC_PAIRS.index((a, b)), :, 3:6].reshape(-1)
                                     * (d_theta[a] * d_theta[b] / c) for a, b in _INERTIA_PAIRS]))
        # Criterion on F_s = D_s F D_s = c T F̃ T with T = D_s Dθ⁻¹ (see the module docstring of fim_gradient).
        t_diag = np.diag(self.merit.d) / d_theta
        ref = self.merit.reference
        assert ref is not None
        if p.criterion == "A":
            put(self.crit_param, np.diag(1.0 / t_diag) / np.sqrt(c * ref))
        elif p.criterion == "E":
            put(self.crit_param, np.diag(1.0 / t_diag**2) * abs(ref) / c)
        else:
            put(self.crit_param, np.eye(N_PARAMS))

    def solve(self) -> tuple[str, np.ndarray | None, float]:
        """Solve with Clarabel.

        Returns
        -------
        status : str
            cvxpy's status, or ``solver_error: ...`` when the solver raised (:func:`oacli.solver.solve_clarabel`).
        du : ndarray, shape (N, 6) or None
            The step (None when the solve failed).
        slack : float
            Sum of the slacks (NaN when the solve failed).
        """
        if self.compiled:
            if self._compiled_qp is None:
                # Built at the first solve, so that Clarabel equilibrates the data of a real iterate.
                # Iterative refinement off: the solution still meets Clarabel's tolerances (its status says so) and
                # every step is judged by the merit test on the nonlinear rollout; about 40 % less time per solve.
                # Presolve and chordal decomposition (the latter picks the D-criterion's log-det cone) would
                # forbid data updates: off, which leaves the problem as cvxpy states it.
                settings = clarabel.DefaultSettings()
                settings.iterative_refinement_enable = False
                settings.presolve_enable = False
                settings.chordal_decomposition_enable = False
                self._compiled_qp = CompiledQP(self.problem, settings)
            failure = ""
            try:
                info = self._compiled_qp.solve(self._values or None)
            except Exception as exc:  # the solver raised: reported in the status, as solve_clarabel does
                info = None
                failure = solver_error_status(exc)
            if info is None or not info.success:
                # Fall back to cvxpy's solve of the same problem (with Clarabel's defaults) for this iterate.
                if info is not None:
                    failure = info.status
                for param in self.problem.parameters():  # the values the compiled solve took directly
                    if param.id in self._values:
                        param.value = self._values[param.id]
                status, du, slack = self._solve_cvxpy()
                self.translation_slack = self._last_translation_slack
                return f"{status} (compiled: {failure})", du, slack
            qp = self._compiled_qp
            self.last_objective = info.objective
            values = [np.maximum(qp.value(s), 0.0) for s in self.slacks]
            self.translation_slack = float(sum(np.sum(v) for v, rot in zip(values, self._rotational, strict=True)
                                               if not rot) + np.sum(values[-1][0:2]))
            slack = float(sum(np.sum(v) for v in values))
            return info.status, np.array(qp.value(self.du)), slack
        return self._solve_cvxpy()

    def _solve_cvxpy(self) -> tuple[str, np.ndarray | None, float]:
        # An inaccurate solve is reported in the status (and judged by the merit test), not as a warning.
        out = solve_clarabel(self.problem, quiet=True)
        status = out.status
        self.last_objective = out.objective
        self._last_translation_slack = float("nan")
        if not out.success or self.du.value is None:
            return status, None, float("nan")
        values = [np.maximum(np.asarray(s.value), 0.0) for s in self.slacks]
        self._last_translation_slack = float(sum(np.sum(v) for v, rot in zip(values, self._rotational, strict=True)
                                                 if not rot) + np.sum(values[-1][0:2]))
        slack = float(sum(np.sum(v) for v in values))
        return status, np.array(self.du.value), slack


__all__ = ["ConvexSubproblem"]
