"""The normal equations ``AᵀA δϑ = −Aᵀb`` of the batch problem ([Doerr2021] Eq. 32) in blocks.

Every residual of the batch problem touches one state, or two consecutive states, and φ, so ``AᵀA`` is block
tridiagonal in the states (12×12 blocks) with a dense border in φ (:class:`NormalEquations`, solved by a banded
Cholesky factorisation and a Schur complement on φ). :class:`ReferenceSystem` is the original sparse path (``A``
assembled, ``AᵀA`` factorised by sparse LU) kept to check against. See :mod:`oacli.estimation.batch`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from oacli.estimation.manifold import (
    TANGENT_DIM,
    so3_left_jacobian_inverse,
    so3_right_jacobian_inverse,
    xi_stack,
)


def block_coo(blocks: np.ndarray, row0: np.ndarray, col0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """COO triplets of a stack of dense blocks placed at row/column offsets of a sparse matrix.

    Used to assemble the sparse Jacobian ``A`` of the batch problem ([Doerr2021] Eq. 32) on the reference path.

    Parameters
    ----------
    blocks : ndarray, shape (n, r, c)
        The dense blocks (dimensionless entries of the whitened Jacobian).
    row0, col0 : ndarray of int, shape (n,)
        Row and column of each block's top-left entry in the assembled matrix.

    Returns
    -------
    rows, cols : ndarray of int, shape (n·r·c,)
        Row and column index of every entry.
    values : ndarray, shape (n·r·c,)
        The entries, ``blocks.ravel()`` (block by block, row-major within a block).
    """
    n, r, c = blocks.shape
    rows = np.broadcast_to(row0[:, None, None] + np.arange(r)[None, :, None], (n, r, c))
    cols = np.broadcast_to(col0[:, None, None] + np.arange(c)[None, None, :], (n, r, c))
    return rows.ravel(), cols.ravel(), blocks.ravel()


@dataclass
class ResidualGroup:
    """Residual rows of one kind, one block per record: ``res (n, r)``; ``state (n, r, 12)`` on the states
    ``index (n,)``; ``next_state`` on ``index + 1`` (process rows); ``phi (n, r, 4)`` on φ (None: no such column)."""

    res: np.ndarray
    index: np.ndarray
    state: np.ndarray | None
    next_state: np.ndarray | None = None
    phi: np.ndarray | None = None


@dataclass
class NormalEquations:
    """``AᵀA`` and ``Aᵀb`` of the batch problem in blocks: block tridiagonal in the K states, dense border in φ.

    ``hd[k]`` = the k-th 12×12 diagonal block, ``ho[k]`` = the block coupling states k and k+1, ``hxp[k]`` = state
    k against φ (12×4), ``hpp`` = φ against φ; ``gx``, ``gp`` the matching parts of ``Aᵀb``. Damped systems
    ``(AᵀA + λ diag(d)) δ = −Aᵀb`` are solved by eliminating the states first (a Schur complement on φ): one
    banded Cholesky factorisation of the state block (bandwidth 23) and a 4×4 solve, so the cost is linear in K.
    """

    hd: np.ndarray
    ho: np.ndarray
    hxp: np.ndarray
    hpp: np.ndarray
    gx: np.ndarray
    gp: np.ndarray

    def diagonal(self) -> np.ndarray:
        """Diagonal of ``AᵀA`` in the variable order ``[δx_1 .. δx_K, δφ]`` (the Levenberg-Marquardt scaling).

        Returns
        -------
        ndarray, shape (12 K + 4,)
            The K states' 12 tangent entries each, then the 4 entries of φ.
        """
        return np.concatenate([np.einsum("kii->ki", self.hd).ravel(), np.diag(self.hpp)])

    def _factor(self, damping: np.ndarray | None) -> np.ndarray | None:
        """Banded Cholesky factor (lower form) of the state block, plus ``damping`` on its diagonal."""
        k, nt = self.hd.shape[0], TANGENT_DIM
        n = k * nt
        ab = np.zeros((2 * nt, n))
        rr, cc = _TRIL
        cols0 = nt * np.arange(k)[:, None]
        ab[(rr - cc)[None, :], cols0 + cc[None, :]] = self.hd[:, rr, cc]
        if k > 1:
            r2, c2 = _FULL
            ab[(nt + r2 - c2)[None, :], cols0[:-1] + c2[None, :]] = self.ho[:, c2, r2]
        if damping is not None:
            ab[0] += damping
        try:
            return sla.cholesky_banded(ab, lower=True, check_finite=False)
        except (np.linalg.LinAlgError, ValueError):
            return None

    def solve(self, damping: np.ndarray) -> np.ndarray | None:
        """``δ = −(AᵀA + diag(damping))⁻¹ Aᵀb``, or None when the damped system is not positive definite.

        The damped Gauss-Newton step of [Doerr2021] Eq. 32: the states are eliminated by a banded Cholesky
        factorisation (bandwidth 23) and φ is solved from the 4×4 Schur complement.

        Parameters
        ----------
        damping : ndarray, shape (12 K + 4,)
            Added to the diagonal of ``AᵀA`` (``λ diag(d)``), in the order ``[δx_1 .. δx_K, δφ]``.

        Returns
        -------
        ndarray, shape (12 K + 4,) or None
            The step ``[δx_1 .. δx_K, δφ]`` (state tangent increments [m, m/s, rad, rad/s], then δφ in the log
            parameters of :mod:`oacli.estimation.parametrization`); None when the factorisation or the Schur solve
            fails or the step is not finite.
        """
        n = self.gx.size
        chol = self._factor(damping[:n])
        if chol is None:
            return None
        border = self.hxp.reshape(n, self.hxp.shape[-1])
        sol = sla.cho_solve_banded((chol, True), np.column_stack([self.gx.ravel(), border]), check_finite=False)
        schur = self.hpp + np.diag(damping[n:]) - border.T @ sol[:, 1:]
        try:
            dphi = np.linalg.solve(schur, -self.gp + border.T @ sol[:, 0])
        except np.linalg.LinAlgError:
            return None
        out = np.concatenate([-sol[:, 0] - sol[:, 1:] @ dphi, dphi])
        return out if np.all(np.isfinite(out)) else None


    def predicted_decrease(self, step: np.ndarray) -> float:
        """The cost decrease the linearised problem predicts for ``step``: ``‖b‖² − ‖b + Aδ‖² = −2 δᵀAᵀb −
        δᵀAᵀAδ`` (the Gauss-Newton model of [Doerr2021] Eq. 32), from the blocks.

        Parameters
        ----------
        step : ndarray, shape (12 K + n,)
            ``[δx_1 .. δx_K, δφ]``.

        Returns
        -------
        float
            Dimensionless (whitened cost units).
        """
        k, nt = self.hd.shape[0], TANGENT_DIM
        dx = step[:k * nt].reshape(k, nt)
        dp = step[k * nt:]
        quad = float(np.einsum("ki,kij,kj->", dx, self.hd, dx)) + float(dp @ self.hpp @ dp)
        if k > 1:
            quad += 2.0 * float(np.einsum("ki,kij,kj->", dx[:-1], self.ho, dx[1:]))
        quad += 2.0 * float(np.einsum("ki,kij,j->", dx, self.hxp, dp))
        lin = float(np.einsum("ki,ki->", self.gx, dx)) + float(self.gp @ dp)
        return -(2.0 * lin + quad)


_TRIL = np.tril_indices(TANGENT_DIM)
_FULL = tuple(np.indices((TANGENT_DIM, TANGENT_DIM)).reshape(2, -1))


def process_jacobians(
    w_proc: np.ndarray, e: np.ndarray, fx: np.ndarray, a: np.ndarray, c: np.ndarray, x_prev: np.ndarray,
    dtheta: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whitened Jacobians of the process residuals ``W_k (x_{k+1} ⊟ f(x_k, u_k, θ))`` with respect to ``δx_k``,
    ``δx_{k+1}`` and ``δφ`` (each (K, 12, ·)), from the propagation's ``a = ∂f/∂x`` and ``c = ∂f/∂θ``.

    ``−W Π(f) A Λ(x_k)`` with ``Π = diag(I₆, J_l⁻¹(e_att) 2Ξ(f_q)ᵀ, I₃)`` (:func:`~oacli.estimation.manifold.
    project_matrix` with the residual's inverse left Jacobian) and ``Λ = diag(I₆, ½Ξ(q_k), I₃)``
    (:func:`~oacli.estimation.manifold.lift_matrix`), in blocks: ``A`` of the structured propagation has a
    translational 6×6 block and a rotational 7×7 block only, so the product is formed on those (the same entries as
    the dense 12×13 · 13×13 · 13×12 product, without its zero blocks); ``W J_r⁻¹`` on the attitude columns for
    ``δx_{k+1}``.

    Parameters
    ----------
    w_proc : ndarray, shape (K, 12, 12)
        Square-root information ``W_k = Q_k^-½`` of the process noise of each interval (K = number of intervals).
    e : ndarray, shape (K, 12)
        The raw process residuals ``x_{k+1} ⊟ f(x_k, u_k, θ)`` (without the gap offset); the attitude part
        ``e[:, 6:9]`` [rad] sets the SO(3) Jacobians.
    fx : ndarray, shape (K, 13)
        Propagated states ``f(x_k, u_k, θ)`` [r m, v m/s, q (x, y, z, w), ω rad/s].
    a : ndarray, shape (K, 13, 13)
        ``∂f/∂x`` of the propagation (translational 6×6 and rotational 7×7 blocks only).
    c : ndarray, shape (K, 13, 4)
        ``∂f/∂θ``, θ = [m kg, Ixx, Iyy, Izz kg·m²].
    x_prev : ndarray, shape (K, 13)
        The states ``x_k`` at the start of each interval.
    dtheta : ndarray, shape (4, 4)
        ``∂θ/∂φ`` (:func:`oacli.estimation.parametrization.theta_jacobian`).

    Returns
    -------
    j_prev : ndarray, shape (K, 12, 12)
        ``∂r_k/∂δx_k``.
    j_next : ndarray, shape (K, 12, 12)
        ``∂r_k/∂δx_{k+1}``.
    j_phi : ndarray, shape (K, 12, 4)
        ``∂r_k/∂δφ``.
    """
    n, nt = e.shape[0], TANGENT_DIM
    jr_inv = so3_right_jacobian_inverse(e[:, 6:9])
    jl_inv = so3_left_jacobian_inverse(e[:, 6:9])
    proj_rot = np.zeros((n, 6, 7))  # rows [δφ_att, δω] of Π on the columns [q, ω]
    proj_rot[:, 0:3, 0:4] = jl_inv @ (2.0 * np.swapaxes(xi_stack(fx[:, 6:10]), -1, -2))
    proj_rot[:, 3:6, 4:7] = np.eye(3)
    lift_rot = np.zeros((n, 7, 6))  # rows [q, ω] of Λ on the columns [δφ_att, δω]
    lift_rot[:, 0:4, 0:3] = 0.5 * xi_stack(x_prev[:, 6:10])
    lift_rot[:, 4:7, 3:6] = np.eye(3)
    core = np.zeros((n, nt, nt))
    core[:, 0:6, 0:6] = a[:, 0:6, 0:6]
    core[:, 6:12, 6:12] = proj_rot @ (a[:, 6:13, 6:13] @ lift_rot)
    if np.any(a[:, 0:6, 6:13]):  # the full model: the translation depends on the attitude (body-axis force scale)
        core[:, 0:6, 6:12] = a[:, 0:6, 6:13] @ lift_rot
    cphi = c @ dtheta
    core_phi = np.empty((n, nt, dtheta.shape[1]))
    core_phi[:, 0:6] = cphi[:, 0:6]
    core_phi[:, 6:12] = proj_rot @ cphi[:, 6:13]
    j_prev = w_proc @ core
    np.negative(j_prev, out=j_prev)
    j_next = w_proc.copy()
    j_next[:, :, 6:9] = w_proc[:, :, 6:9] @ jr_inv
    j_phi = w_proc @ core_phi
    np.negative(j_phi, out=j_phi)
    return j_prev, j_next, j_phi


def sparse_solve(h: sp.csc_matrix, g: np.ndarray) -> np.ndarray | None:
    """Solve ``h z = g`` by sparse LU (the reference path of [Doerr2021] Eq. 32 and its covariance).

    Parameters
    ----------
    h : scipy.sparse.csc_matrix, shape (n, n)
        The (damped normal-equation or augmented) system matrix.
    g : ndarray, shape (n,) or (n, m)
        Right-hand side(s).

    Returns
    -------
    ndarray, shape like ``g``, or None
        The solution; None when ``h`` is exactly singular or the solution is not finite.
    """
    try:
        out = spla.splu(h).solve(g)
    except RuntimeError:  # exactly singular
        return None
    return out if np.all(np.isfinite(out)) else None


class ReferenceSystem:
    """The sparse normal equations of the original implementation (``A`` assembled, ``AᵀA`` factorised by LU)."""

    def __init__(self, b: np.ndarray, a_mat: sp.csc_matrix) -> None:
        self.h = (a_mat.T @ a_mat).tocsc()
        self.g = a_mat.T @ b

    def diagonal(self) -> np.ndarray:
        """Diagonal of ``AᵀA`` (as :meth:`NormalEquations.diagonal`).

        Returns
        -------
        ndarray, shape (12 K + 4,)
            In the variable order ``[δx_1 .. δx_K, δφ]``.
        """
        return self.h.diagonal()

    def solve(self, damping: np.ndarray) -> np.ndarray | None:
        """``δ = −(AᵀA + diag(damping))⁻¹ Aᵀb`` by sparse LU (as :meth:`NormalEquations.solve`).

        Parameters
        ----------
        damping : ndarray, shape (12 K + 4,)
            Added to the diagonal of ``AᵀA``, in the order ``[δx_1 .. δx_K, δφ]``.

        Returns
        -------
        ndarray, shape (12 K + 4,) or None
            The step ``[δx_1 .. δx_K, δφ]``; None when the damped system is singular or the step not finite.
        """
        return sparse_solve((self.h + sp.diags(damping)).tocsc(), -self.g)

    def predicted_decrease(self, step: np.ndarray) -> float:
        """``−2 δᵀAᵀb − δᵀAᵀAδ`` (as :meth:`NormalEquations.predicted_decrease`).

        Parameters
        ----------
        step : ndarray, shape (12 K + n,)

        Returns
        -------
        float
        """
        return -(2.0 * float(self.g @ step) + float(step @ (self.h @ step)))
