"""Residuals, Jacobians and covariance of the batch maximum-likelihood problem ([Doerr2021] Eqs. 31-32).

:class:`BatchProblem` holds the data of one solve and evaluates the residuals ``b(ϑ)`` of Eq. 31 (measurement,
acceleration, process, gauge and prior rows), their Jacobian ``A`` (sparse, reference path) or the normal
equations in blocks (:mod:`oacli.estimation.batch_normal`), and the covariance of the last state and φ from a block
QR factorisation of ``A``; :func:`marginal_covariances` maps it to ``cov(θ̂) = [(AᵀA)⁻¹]_θθ``. The design is
described in :mod:`oacli.estimation.batch`'s module docstring.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from oacli.estimation.batch_model import FullModel, LegacyModel
from oacli.estimation.batch_normal import NormalEquations, ResidualGroup, block_coo, process_jacobians, sparse_solve
from oacli.estimation.lost_inputs import (
    bridge_accelerations,
    bridge_angular_accelerations,
    lost_input_model,
    segment_link_weights,
)
from oacli.estimation.manifold import (
    TANGENT_DIM,
    boxminus,
    lift_matrix,
    project_matrix,
    so3_left_jacobian_inverse,
    so3_right_jacobian_inverse,
)
from oacli.estimation.models import EstimatorSettings, Measurement, measured_rows
from oacli.estimation.propagation import substep_schedule
from oacli.types import ParameterEstimate

Propagated = tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray | None, np.ndarray | None]]
"""A cached process-model propagation: (states, φ, (x_next, a, c))."""


class BatchProblem:
    """Residuals ``b(ϑ)`` and the sparse Jacobian ``A`` of the batch problem for fixed data.

    ``model`` chooses θ: the original [m, Ixx, Iyy, Izz] (default) or a part of the full rigid body
    (:mod:`oacli.estimation.batch_model`); φ then has ``model.n`` entries and the border of ``AᵀA`` as many columns.
    """

    def __init__(
        self, records: Sequence[Measurement], settings: EstimatorSettings, prior: ParameterEstimate | None,
        weights_theta: np.ndarray, model: LegacyModel | FullModel | None = None,
    ) -> None:
        self.model: LegacyModel | FullModel = LegacyModel() if model is None else model
        self.n_par = self.model.n
        weights_theta = np.asarray(weights_theta, dtype=float)[:4]
        self.t = np.array([r.t for r in records])
        self.y = np.array([r.x_measured for r in records])
        self.u = np.array([r.u_applied for r in records])
        self.acc = np.array([r.accelerations() for r in records])
        self.k = len(records)
        self.n_var = TANGENT_DIM * self.k + self.n_par
        self.has_state = np.array([r.state_measured for r in records], dtype=bool)
        starts = np.array([r.starts_segment for r in records], dtype=bool)
        starts[0] = True
        self.segment_starts = np.flatnonzero(starts)
        self.links = ~starts[1:]  # process residual k -> k+1 present
        meas = settings.measurement
        self.state_rows, accel_rows = measured_rows(meas)
        # Acceleration rows are used only where every record with a measurement carries them.
        measured_acc = self.acc[self.has_state]
        self.accel_rows = np.array([i for i in accel_rows if np.all(np.isfinite(measured_acc[:, i]))], dtype=int)
        self.w_state = np.sqrt(meas.state_weights[self.state_rows])
        self.w_accel = np.sqrt(meas.acceleration_weights[self.accel_rows])
        self.dof = len(self.state_rows) + len(self.accel_rows)
        self.gauge_rows = np.setdiff1d(np.arange(TANGENT_DIM), self.state_rows)
        self.durations = substep_schedule(self.t[:-1], self.t[1:], settings.substep_s)
        self._w_proc_nominal = settings.process.sqrt_information(np.diff(self.t), weights_theta)
        self.link_rows = TANGENT_DIM * self.links.astype(int)  # informative process residuals per interval
        self.gap_offset = np.zeros((max(self.k - 1, 0), TANGENT_DIM))
        self.has_gaps = self.k > 1 and not np.all(self.links)
        self._u_records = self.u.copy()
        self._w_proc_linked = self._w_proc_nominal
        self._q_proc = settings.process.covariance(np.diff(self.t), weights_theta) if self.has_gaps else None
        self._weights_theta = np.asarray(weights_theta, dtype=float)
        self._bridge = bridge_accelerations(records, meas) if self.has_gaps else (None, None)
        self._gyro = bridge_angular_accelerations(records) if self.has_gaps else None
        self.w_proc = self._w_proc_nominal
        self.set_lost_inputs()
        self._propagation_cache: Propagated | None = None
        self.prior = prior
        if prior is not None:
            if isinstance(self.model, FullModel):
                idx = self.model.prior_index
                self.prior_mean = self.model.prior_mean[idx]
                prior_cov = self.model.prior_cov[np.ix_(idx, idx)]
            else:
                self.prior_mean, prior_cov = prior.theta, prior.covariance
            self.prior_sqrt_info = np.linalg.inv(np.linalg.cholesky(prior_cov))

    def set_lost_inputs(self, noise: np.ndarray | None = None, theta: np.ndarray | None = None) -> None:
        """The model across the gaps of the input record: the unknown wrench predicted from its neighbours (the
        force measured by the accelerometer when the records carry it), or its force profiled out and the rotation
        cut (:func:`lost_input_model`, :func:`segment_link_weights`). ``noise`` (the measurement residuals of a
        first solve) corrects the prediction for the controller's reaction to the neighbours' measurement noise;
        ``theta`` (that solve's θ̂) replaces the prior as the point where the lost wrench's directions and the
        force's ``1/m`` are evaluated (a prior 30 % off in inertia mis-weights the torque's error by as much).

        Does nothing when the records have no gaps. Updates ``u``, ``gap_offset``, ``w_proc`` and ``link_rows`` and
        drops the cached propagation.

        Parameters
        ----------
        noise : ndarray, shape (K, 12), optional
            Measurement residuals ``ỹ_k ⊟ x̂_k`` [m, m/s, rad, rad/s] of a first solve, NaN where a record has none
            (:meth:`measurement_noise`); None: no correction.
        theta : ndarray, shape (4,), optional
            θ̂ = [m kg, Ixx, Iyy, Izz kg·m²] of that solve; None: the prior's θ the problem was built with.
        """
        if not self.has_gaps or self._q_proc is None:
            return
        weights_theta = self._weights_theta if theta is None else np.asarray(theta, dtype=float)
        m_w = float(weights_theta[0])
        acc, var = self._bridge
        self.u, bridged, variance, self.gap_offset = lost_input_model(
            self.t, self._u_records, self.links, weights_theta[:4], bridge_acceleration=acc,
            bridge_acceleration_variance=var, noise=noise, gyro=self._gyro)
        self._w_proc_nominal, self.link_rows = segment_link_weights(
            self._w_proc_linked, self._q_proc, np.diff(self.t), self.links, bridged,
            variance * np.r_[m_w**2, m_w**2, m_w**2, 1.0, 1.0, 1.0], weights_theta)
        self.w_proc = self._w_proc_nominal
        self._propagation_cache = None

    def measurement_noise(self, x: np.ndarray, inliers: np.ndarray) -> np.ndarray:
        """``ỹ_k ⊟ x_k`` (K, 12) on the inlier records, NaN elsewhere (the residuals of a solve).

        Parameters
        ----------
        x : ndarray, shape (K, 13)
            States [r m, v m/s, q (x, y, z, w), ω rad/s].
        inliers : ndarray of bool, shape (K,)
            Records whose measurement is used.

        Returns
        -------
        ndarray, shape (K, 12)
            Unweighted tangent residuals [m, m/s, rad, rad/s]; rows of outliers are NaN.
        """
        out = np.full((self.k, TANGENT_DIM), np.nan)
        out[inliers] = boxminus(self.y[inliers], x[inliers])
        return out

    def set_process_noise_scale(self, factor: float) -> None:
        """Use ``factor`` × the configured process noise standard deviations (continuation, see the module).

        Parameters
        ----------
        factor : float
            Scale (> 0) of the process noise standard deviations: ``W_k`` becomes the nominal ``W_k / factor``;
            1 restores the configured noise.
        """
        self.w_proc = self._w_proc_nominal / float(factor)

    # -- residuals and Jacobian ------------------------------------------------------------------------------------

    def evaluate(
        self, x: np.ndarray, phi: np.ndarray, inliers: np.ndarray, jacobian: bool
    ) -> tuple[np.ndarray, sp.csc_matrix | None]:
        """``b(ϑ)`` and, if asked, ``A = ∂b/∂δϑ`` (right perturbations of the states, φ additive).

        The whitened residuals of [Doerr2021] Eq. 31 and the Jacobian of the linearised problem Eq. 32, in the row
        order measurement, acceleration, process, gauge, prior; the sparse reference path.

        Parameters
        ----------
        x : ndarray, shape (K, 13)
            States [r m, v m/s, q (x, y, z, w), ω rad/s].
        phi : ndarray, shape (4,)
            φ = [log m, log A, log B, log C] (:mod:`oacli.estimation.parametrization`).
        inliers : ndarray of bool, shape (K,)
            Records whose measurement (and acceleration) rows are used.
        jacobian : bool
            Also assemble ``A``.

        Returns
        -------
        b : ndarray, shape (N,)
            Whitened residuals (dimensionless), N rows in total.
        a_mat : scipy.sparse.csc_matrix, shape (N, 12 K + 4), or None
            ``∂b/∂δϑ`` with the variables ``[δx_1 .. δx_K, δφ]``; None when ``jacobian`` is false.
        """
        k = self.k
        theta = self.model.theta(phi)
        dtheta = self.model.jacobian(phi)
        parts: list[np.ndarray] = []
        triplets: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        row = 0
        phi_col = TANGENT_DIM * k

        # Measurement residuals h(x_k) ⊟ ỹ_k on the inlier records.
        idx = np.flatnonzero(inliers)
        if idx.size and self.state_rows.size:
            e = boxminus(x[idx], self.y[idx])
            res = (e[:, self.state_rows] * self.w_state).ravel()
            parts.append(res)
            if jacobian:
                blocks = np.zeros((idx.size, TANGENT_DIM, TANGENT_DIM))
                blocks[:, 0:6, 0:6] = np.eye(6)
                blocks[:, 6:9, 6:9] = so3_right_jacobian_inverse(e[:, 6:9])
                blocks[:, 9:12, 9:12] = np.eye(3)
                blocks = blocks[:, self.state_rows, :] * self.w_state[None, :, None]
                n_r = len(self.state_rows)
                triplets.append(block_coo(blocks, row + n_r * np.arange(idx.size), TANGENT_DIM * idx))
            row += res.size

        # Acceleration residuals (rows of the continuous dynamics at x_k, u_k).
        if idx.size and self.accel_rows.size:
            f, fx_jac, fth_jac = self.model.accelerations(x[idx], self.u[idx], theta, jacobian)
            res = ((f - self.acc[idx])[:, self.accel_rows] * self.w_accel).ravel()
            parts.append(res)
            if jacobian:
                assert fx_jac is not None and fth_jac is not None
                jx = fx_jac[:, self.accel_rows] @ lift_matrix(x[idx]) * self.w_accel[None, :, None]
                jp = fth_jac[:, self.accel_rows] @ dtheta * self.w_accel[None, :, None]
                n_a = len(self.accel_rows)
                r0 = row + n_a * np.arange(idx.size)
                triplets.append(block_coo(jx, r0, TANGENT_DIM * idx))
                triplets.append(block_coo(jp, r0, np.full(idx.size, phi_col)))
            row += res.size

        # Process residuals x_{k+1} ⊟ f(x_k, u_k, θ), whitened by Q_k^-½.
        if k > 1:
            fx, a, c = self.model.propagate(x[:-1], self.u[:-1], theta, self.durations, reference=True)
            assert a is not None and c is not None
            e_raw = boxminus(x[1:], fx)  # the Jacobians are those of ⊟, at its value (the gap offset is constant)
            e = e_raw - self.gap_offset
            res = np.einsum("kij,kj->ki", self.w_proc, e).ravel()
            parts.append(res)
            if jacobian:
                next_blk = np.zeros((k - 1, TANGENT_DIM, TANGENT_DIM))
                next_blk[:, 0:6, 0:6] = np.eye(6)
                next_blk[:, 6:9, 6:9] = so3_right_jacobian_inverse(e_raw[:, 6:9])
                next_blk[:, 9:12, 9:12] = np.eye(3)
                pred_blk = next_blk.copy()
                pred_blk[:, 6:9, 6:9] = so3_left_jacobian_inverse(e_raw[:, 6:9])
                proj = pred_blk @ project_matrix(fx)  # (K-1, 12, 13)
                j_prev = -(self.w_proc @ proj @ a @ lift_matrix(x[:-1]))
                j_next = self.w_proc @ next_blk
                j_phi = -(self.w_proc @ proj @ c @ dtheta)
                r0 = row + TANGENT_DIM * np.arange(k - 1)
                triplets.append(block_coo(j_prev, r0, TANGENT_DIM * np.arange(k - 1)))
                triplets.append(block_coo(j_next, r0, TANGENT_DIM * np.arange(1, k)))
                triplets.append(block_coo(j_phi, r0, np.full(k - 1, phi_col)))
            row += res.size

        # Gauge: tie the unmeasured components of each segment's first state to its record (unit weight).
        for first in self.segment_starts if self.gauge_rows.size else ():
            e = boxminus(x[first], self.y[first])
            parts.append(e[self.gauge_rows])
            if jacobian:
                blk = np.eye(TANGENT_DIM)
                blk[6:9, 6:9] = so3_right_jacobian_inverse(e[6:9])
                triplets.append(block_coo(blk[self.gauge_rows][None], np.array([row]),
                                           np.array([TANGENT_DIM * first])))
            row += self.gauge_rows.size

        # Gaussian prior on θ (in θ, not in φ).
        if self.prior is not None:
            pidx = self.model.prior_index
            parts.append(self.prior_sqrt_info @ (theta[pidx] - self.prior_mean))
            if jacobian:
                blk = (self.prior_sqrt_info @ dtheta[pidx])[None]
                triplets.append(block_coo(blk, np.array([row]), np.array([phi_col])))
            row += self.n_par

        b = np.concatenate(parts) if parts else np.zeros(0)
        if not jacobian:
            return b, None
        rows, cols, vals = (np.concatenate(z) for z in zip(*triplets, strict=True))
        a_mat = sp.csc_matrix((vals, (rows, cols)), shape=(row, self.n_var))
        return b, a_mat

    def _propagate(self, x: np.ndarray, phi: np.ndarray, theta: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Process model over every interval; the last result is reused while (x, φ) are unchanged (the next
        continuation stage and the covariance start where the previous solve stopped)."""
        cached = self._propagation_cache
        if cached is not None and np.array_equal(cached[0], x) and np.array_equal(cached[1], phi):
            return cached[2]
        out = self.model.propagate(x[:-1], self.u[:-1], theta, self.durations)
        self._propagation_cache = (x.copy(), phi.copy(), out)
        return out

    def jacobian_groups(
        self, x: np.ndarray, phi: np.ndarray, inliers: np.ndarray, *, jacobian: bool = True
    ) -> tuple[np.ndarray, list[ResidualGroup]]:
        """``b(ϑ)`` and its Jacobian as groups of per-record blocks (same residuals and Jacobians as
        :meth:`evaluate`, in the same row order); the process model is
        :func:`oacli.estimation.propagation.propagate_intervals_structured`.

        Residuals of [Doerr2021] Eq. 31, Jacobian blocks of Eq. 32.

        Parameters
        ----------
        x : ndarray, shape (K, 13)
            States [r m, v m/s, q (x, y, z, w), ω rad/s].
        phi : ndarray, shape (4,)
            φ = [log m, log A, log B, log C].
        inliers : ndarray of bool, shape (K,)
            Records whose measurement (and acceleration) rows are used.
        jacobian : bool, default True
            Also form the Jacobian blocks; False propagates the end states only (a trial step's cost).

        Returns
        -------
        b : ndarray, shape (N,)
            Whitened residuals (dimensionless), in the row order of :meth:`evaluate`.
        groups : list of ResidualGroup
            One group per residual kind present, with its per-record blocks on the 12-dim state tangents and on φ
            (4 columns); empty when ``jacobian`` is false.
        """
        k = self.k
        theta = self.model.theta(phi)
        dtheta = self.model.jacobian(phi)
        nt = TANGENT_DIM
        parts: list[np.ndarray] = []
        groups: list[ResidualGroup] = []

        idx = np.flatnonzero(inliers)
        if idx.size and self.state_rows.size:
            e = boxminus(x[idx], self.y[idx])
            res = e[:, self.state_rows] * self.w_state
            parts.append(res.ravel())
            if jacobian:
                blocks = np.zeros((idx.size, nt, nt))
                blocks[:, 0:6, 0:6] = np.eye(6)
                blocks[:, 6:9, 6:9] = so3_right_jacobian_inverse(e[:, 6:9])
                blocks[:, 9:12, 9:12] = np.eye(3)
                blocks = blocks[:, self.state_rows, :] * self.w_state[None, :, None]
                groups.append(ResidualGroup(res, idx, blocks))

        if idx.size and self.accel_rows.size:
            f, fx_jac, fth_jac = self.model.accelerations(x[idx], self.u[idx], theta, jacobian)
            res = (f - self.acc[idx])[:, self.accel_rows] * self.w_accel
            parts.append(res.ravel())
            if jacobian:
                assert fx_jac is not None and fth_jac is not None
                jx = fx_jac[:, self.accel_rows] @ lift_matrix(x[idx]) * self.w_accel[None, :, None]
                jp = fth_jac[:, self.accel_rows] @ dtheta * self.w_accel[None, :, None]
                groups.append(ResidualGroup(res, idx, jx, phi=jp))

        if k > 1:
            if jacobian:
                fx, a, c = self._propagate(x, phi, theta)
            else:  # the end states only (a trial step's cost)
                fx = self.model.propagate(x[:-1], self.u[:-1], theta, self.durations, jacobians=False)[0]
            e_raw = boxminus(x[1:], fx)  # the Jacobians are those of ⊟, at its value (the gap offset is constant)
            e = e_raw - self.gap_offset
            res = np.einsum("kij,kj->ki", self.w_proc, e)
            parts.append(res.ravel())
            if jacobian:
                assert a is not None and c is not None  # the Jacobian branch propagated with Jacobians
                j_prev, j_next, j_phi = process_jacobians(self.w_proc, e_raw, fx, a, c, x[:-1], dtheta)
                groups.append(ResidualGroup(res, np.arange(k - 1), j_prev, j_next, j_phi))

        if self.gauge_rows.size:
            first = self.segment_starts
            e = boxminus(x[first], self.y[first])
            res = e[:, self.gauge_rows]
            parts.append(res.ravel())
            if jacobian:
                blk = np.broadcast_to(np.eye(nt), (first.size, nt, nt)).copy()
                blk[:, 6:9, 6:9] = so3_right_jacobian_inverse(e[:, 6:9])
                groups.append(ResidualGroup(res, first, blk[:, self.gauge_rows]))

        if self.prior is not None:
            pidx = self.model.prior_index
            res = self.prior_sqrt_info @ (theta[pidx] - self.prior_mean)
            parts.append(res)
            if jacobian:
                groups.append(ResidualGroup(res[None], np.zeros(0, dtype=int), None,
                                     phi=(self.prior_sqrt_info @ dtheta[pidx])[None]))

        b = np.concatenate(parts) if parts else np.zeros(0)
        return b, groups

    def normal_equations(
        self, x: np.ndarray, phi: np.ndarray, inliers: np.ndarray
    ) -> tuple[np.ndarray, NormalEquations]:
        """``b(ϑ)`` and the blocks of ``AᵀA`` and ``Aᵀb`` (:class:`NormalEquations`).

        ``A`` is never formed: every residual touches one or two consecutive states and φ, so ``AᵀA`` is block
        tridiagonal in the states (12×12 blocks) with a dense 4-column border in φ, accumulated directly from the
        per-record Jacobian blocks of :meth:`jacobian_groups`. These are the normal equations of the
        Gauss-Newton step of [Doerr2021] Eq. 32.

        Parameters
        ----------
        x : ndarray, shape (K, 13)
            States [r m, v m/s, q (x, y, z, w), ω rad/s].
        phi : ndarray, shape (4,)
            φ = [log m, log A, log B, log C].
        inliers : ndarray of bool, shape (K,)
            Records whose measurement (and acceleration) rows are used.

        Returns
        -------
        b : ndarray, shape (N,)
            Whitened residuals (dimensionless).
        normal : NormalEquations
            The blocks ``hd`` (K, 12, 12), ``ho`` (K − 1, 12, 12), ``hxp`` (K, 12, 4), ``hpp`` (4, 4), ``gx``
            (K, 12) and ``gp`` (4,) of ``AᵀA`` and ``Aᵀb``.
        """
        b, groups = self.jacobian_groups(x, phi, inliers)
        k, nt, npar = self.k, TANGENT_DIM, self.n_par
        hd = np.zeros((k, nt, nt))
        ho = np.zeros((max(k - 1, 0), nt, nt))
        hxp = np.zeros((k, nt, npar))
        hpp = np.zeros((npar, npar))
        gx = np.zeros((k, nt))
        gp = np.zeros(npar)
        for grp in groups:
            for offset, blk in ((0, grp.state), (1, grp.next_state)):
                if blk is None:
                    continue
                at = grp.index + offset
                bt = blk.transpose(0, 2, 1)
                hd[at] += bt @ blk
                gx[at] += np.einsum("kij,kj->ki", bt, grp.res)
                if grp.phi is not None:
                    hxp[at] += bt @ grp.phi
            if grp.next_state is not None:
                ho[grp.index] += grp.state.transpose(0, 2, 1) @ grp.next_state  # type: ignore[union-attr,index]
            if grp.phi is not None:
                hpp += np.einsum("kri,krj->ij", grp.phi, grp.phi)
                gp += np.einsum("kri,kr->i", grp.phi, grp.res)
        return b, NormalEquations(hd, ho, hxp, hpp, gx, gp)

    def last_covariance_qr(self, x: np.ndarray, phi: np.ndarray, inliers: np.ndarray) -> np.ndarray | None:
        """Covariance of ``[δx_K, δφ]`` (16×16) from a block QR factorisation of ``A`` (no ``AᵀA`` formed).

        With the variables ordered ``[x_1 .. x_K, φ]`` and ``A = QR``, the last 16×16 block of ``(AᵀA)⁻¹ =
        R⁻¹R⁻ᵀ`` is ``R_ll⁻¹ R_ll⁻ᵀ``. ``R`` is built state by state (a square-root information smoother): the
        rows left over on ``[x_k, φ]``, the rows of record k and the process rows k → k+1 are triangularised on
        ``[x_k, x_{k+1}, φ]``; what remains on ``[x_{k+1}, φ]`` is carried on. The normal equations square the
        condition number of ``A`` (10¹²-10¹³ for a nearly rigid process model, so their covariance is good to
        ~10⁻⁴ only); this is accurate to ``cond(A)·ε``. Returns None when ``A`` has not full column rank.

        Parameters
        ----------
        x : ndarray, shape (K, 13)
            States [r m, v m/s, q (x, y, z, w), ω rad/s] (the solution of [Doerr2021] Eq. 31).
        phi : ndarray, shape (4,)
            φ = [log m, log A, log B, log C].
        inliers : ndarray of bool, shape (K,)
            Records whose measurement (and acceleration) rows are used.

        Returns
        -------
        ndarray, shape (16, 16) or None
            Covariance of ``[δx_K (12: m, m/s, rad, rad/s), δφ (4)]``; None when ``A`` is rank deficient (too few
            rows or a negligible pivot of the last block) or the result is not finite.
        """
        _, groups = self.jacobian_groups(x, phi, inliers)
        width = TANGENT_DIM + self.n_par
        r_mat = last_triangular_block(groups, self.k, self.n_par, full_last=True)
        if r_mat is None:
            return None
        r_ll = r_mat[:width, :width]
        if np.min(np.abs(np.diag(r_ll))) <= 1e-14 * np.max(np.abs(np.diag(r_ll))):
            return None
        r_inv = sla.solve_triangular(r_ll, np.eye(width), check_finite=False)
        cov = r_inv @ r_inv.T
        return cov if np.all(np.isfinite(cov)) else None

    def d2(self, x: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """Normalised residual squared ``d²_k`` of every record against the states ``x``.

        The whitened measurement rows (and acceleration rows, if used) of record k, squared and summed; compared
        with a χ² threshold on ``dof`` degrees of freedom by the batch solve's outlier gating.

        Parameters
        ----------
        x : ndarray, shape (K, 13)
            States [r m, v m/s, q (x, y, z, w), ω rad/s].
        phi : ndarray, shape (4,)
            φ = [log m, log A, log B, log C] (for the predicted accelerations).

        Returns
        -------
        ndarray, shape (K,)
            ``d²_k`` (dimensionless); NaN for records without a state measurement.
        """
        e = boxminus(x, self.y)[:, self.state_rows] * self.w_state
        out = np.sum(e * e, axis=1)
        if self.accel_rows.size:
            f = self.model.accelerations(x, self.u, self.model.theta(phi), False)[0]
            ea = (f - self.acc)[:, self.accel_rows] * self.w_accel
            out += np.sum(ea * ea, axis=1)
        out[~self.has_state] = np.nan
        return out

    def residual_count(self, inliers: np.ndarray) -> int:
        """Rows of ``b`` that carry information (measurement, acceleration, linked process, gauge, prior).

        Parameters
        ----------
        inliers : ndarray of bool, shape (K,)
            Records whose measurement (and acceleration) rows are used.

        Returns
        -------
        int
            The number of informative residual rows (``chi2_dof`` is this minus ``n_var``).
        """
        n = int(inliers.sum()) * self.dof + int(self.link_rows.sum())
        n += self.gauge_rows.size * self.segment_starts.size
        return n + (self.n_par if self.prior is not None else 0)


def last_triangular_block(groups: list[ResidualGroup], k: int, npar: int, *, full_last: bool) -> np.ndarray | None:
    """The last triangular block, over ``[x_K, φ]``, of the block QR factorisation of the batch problem's ``A``
    (the square-root information smoother of :meth:`BatchProblem.last_covariance_qr`).

    The rows left over on ``[x_k, φ]``, the rows of record k and the process rows k → k+1 are triangularised on
    ``[x_k, x_{k+1}, φ]``; what remains on ``[x_{k+1}, φ]`` is carried on.

    Parameters
    ----------
    groups : list of ResidualGroup
        :meth:`BatchProblem.jacobian_groups`'s blocks.
    k : int
        Records.
    npar : int
        Columns of φ.
    full_last : bool
        Require as many rows as columns in the last block (a covariance needs them all); else only the 12 of the
        state (:mod:`oacli.estimation.consider` reads the state's and the estimated entries' rows only).

    Returns
    -------
    ndarray or None
        ``R`` of the last block (rows × (12 + npar)); None when a block has too few rows.
    """
    nt = TANGENT_DIM
    single: list[list[np.ndarray]] = [[] for _ in range(k)]
    phi_only: list[np.ndarray] = []
    process = None
    for grp in groups:
        if grp.next_state is not None:
            process = grp
            continue
        if grp.state is None:
            for blk in grp.phi:  # type: ignore[union-attr]
                rows = np.zeros((blk.shape[0], nt + npar))
                rows[:, nt:] = blk
                phi_only.append(rows)
            continue
        rows = np.zeros((*grp.res.shape, nt + npar))
        rows[:, :, :nt] = grp.state
        if grp.phi is not None:
            rows[:, :, nt:] = grp.phi
        for i, at in enumerate(grp.index):
            single[at].append(rows[i])
    carry = np.zeros((0, nt + npar))  # rows on [x_k, φ]
    for i in range(k):
        last = i == k - 1
        width = nt + npar if last else 2 * nt + npar
        own = [carry, *single[i], *(phi_only if last else ())]
        stacked = np.concatenate([r for r in own if r.size] or [np.zeros((0, nt + npar))])
        block = np.zeros((stacked.shape[0], width))
        block[:, :nt] = stacked[:, :nt]
        block[:, width - npar:] = stacked[:, nt:]
        if not last:
            assert process is not None and process.state is not None and process.next_state is not None
            assert process.phi is not None
            link = np.zeros((nt, width))
            link[:, :nt] = process.state[i]
            link[:, nt:2 * nt] = process.next_state[i]
            link[:, 2 * nt:] = process.phi[i]
            block = np.vstack([block, link])
        if block.shape[0] < (width if last and full_last else nt):
            return None
        r_mat: np.ndarray = np.asarray(np.linalg.qr(block, mode="r"))
        if last:
            return r_mat
        carry = r_mat[nt:, nt:]
    return None


def marginal_covariances(
    problem: BatchProblem, x: np.ndarray, phi: np.ndarray, inliers: np.ndarray, reference: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """``[(AᵀA)⁻¹]_θθ`` mapped from φ to θ, and the covariance of ``[δx_K, δφ]`` (last state and φ, 16×16).

    Singular ``AᵀA`` gives ``inf`` diagonals. The covariance ``(AᵀA)⁻¹`` of the linearised problem of
    [Doerr2021] Eq. 32 at the solution, taken from a block QR factorisation of ``A`` (default) or from a sparse LU
    of the augmented system ``[[I, A], [Aᵀ, 0]]`` (``reference``); neither forms ``AᵀA``.

    Parameters
    ----------
    problem : BatchProblem
        The problem solved.
    x : ndarray, shape (K, 13)
        States [r m, v m/s, q (x, y, z, w), ω rad/s] of the solution.
    phi : ndarray, shape (4,)
        φ = [log m, log A, log B, log C] of the solution.
    inliers : ndarray of bool, shape (K,)
        Records whose measurement (and acceleration) rows are used.
    reference : bool, default False
        Use the sparse augmented-system path instead of the block QR.

    Returns
    -------
    cov_theta : ndarray, shape (4, 4)
        ``cov(θ̂)`` of θ = [m kg, Ixx, Iyy, Izz kg·m²] [kg², kg²·m², kg²·m⁴], mapped from φ through ``∂θ/∂φ``;
        ``diag(inf)`` when singular.
    cov_last : ndarray, shape (16, 16)
        Covariance of ``[δx_K, δφ]`` (last state's 12 tangent entries, then φ); ``diag(inf)`` when singular.
    """
    npar = problem.n_par
    m = TANGENT_DIM + npar
    if reference:
        # The augmented system [[I, A], [Aᵀ, 0]] [r; z] = [0; −e]  ⇒  z = (AᵀA)⁻¹ e, by sparse LU: AᵀA is never
        # formed, so the covariance is good to cond(A)·ε like the QR (a solve of AᵀA squares the condition number:
        # 10¹²-10¹³ for a nearly rigid process model, ~1e-5 relative accuracy only).
        _, a_mat = problem.evaluate(x, phi, inliers, jacobian=True)
        rows, n = a_mat.shape  # type: ignore[union-attr]
        kkt = sp.bmat([[sp.identity(rows), a_mat], [a_mat.T, None]]).tocsc()  # type: ignore[union-attr]
        rhs = np.zeros((rows + n, m))
        rhs[rows + n - m:, :] = -np.eye(m)
        sol = sparse_solve(kkt, rhs)
        cov_last = None if sol is None else sol[rows + n - m:, :]
    else:
        cov_last = problem.last_covariance_qr(x, phi, inliers)
    jac = problem.model.jacobian(phi)
    if cov_last is None:
        return np.diag(np.full(jac.shape[0], np.inf)), np.diag(np.full(m, np.inf))
    cov_last = 0.5 * (cov_last + cov_last.T)
    cov = jac @ cov_last[TANGENT_DIM:, TANGENT_DIM:] @ jac.T
    return 0.5 * (cov + cov.T), cov_last
