"""Linear-quadratic regulators ([Doerr2021] Eqs. 3-9).

* :func:`solve_dare` / :func:`dlqr`: infinite-horizon discrete LQR by the structure-preserving doubling
  algorithm (Chu, Fan, Lin & Wang 2004), an independent method from scipy's Schur-based
  ``solve_discrete_are`` (the tests compare the two).
* :func:`tv_riccati`: finite-horizon, time-varying Riccati recursion with affine dynamics and linear cost terms
  (Eqs. 8-9), returning the quadratic value function ``V_k(δx) = ½ δxᵀ S_k δx + δxᵀ s_k + c_k`` and the
  affine policy ``δu_k = K_k δx_k + k_k``. Reused by the planners (LQR steering, cost-to-go metric).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.errors import InfeasibleError


def solve_dare(
    a: np.ndarray,
    b: np.ndarray,
    q: np.ndarray,
    r: np.ndarray,
    cross: np.ndarray | None = None,
    *,
    tol: float = 1e-13,
    max_iter: int = 200,
) -> np.ndarray:
    """Stabilising solution P of the discrete algebraic Riccati equation.

    ``P = AᵀPA − (AᵀPB + N)(R + BᵀPB)⁻¹(BᵀPA + Nᵀ) + Q`` for the cost ``Σ xᵀQx + uᵀRu + 2xᵀNu``.

    Parameters
    ----------
    a, b : ndarray, shapes (n, n), (n, m)
    q : ndarray, shape (n, n)
        Symmetric positive semidefinite state weight.
    r : ndarray, shape (m, m)
        Symmetric positive definite input weight.
    cross : ndarray, shape (n, m), optional
        Cross weight N.
    tol : float, optional
        Convergence tolerance of the doubling iteration (relative change of P).
    max_iter : int, optional
        Iteration limit.

    Returns
    -------
    ndarray, shape (n, n)
        P, symmetric positive semidefinite.

    Raises
    ------
    InfeasibleError
        When the doubling iteration does not converge ((A, B) not stabilisable or (Q, A) not detectable).
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    q = np.asarray(q, dtype=float)
    r = np.asarray(r, dtype=float)
    n = a.shape[0]
    r_inv = np.linalg.inv(r)
    if cross is not None:
        cross = np.asarray(cross, dtype=float)
        a = a - b @ r_inv @ cross.T
        q = q - cross @ r_inv @ cross.T
    ak = a.copy()
    gk = b @ r_inv @ b.T
    hk = 0.5 * (q + q.T)
    eye = np.eye(n)
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            hk = _doubling(ak, gk, hk, eye, tol, max_iter)
    except np.linalg.LinAlgError as exc:
        raise InfeasibleError(f"Riccati doubling failed ({exc}): is (A, B) stabilisable?") from exc
    if not np.all(np.isfinite(hk)):
        raise InfeasibleError("Riccati doubling diverged: is (A, B) stabilisable and (Q, A) detectable?")
    return np.asarray(hk)


def _doubling(ak: np.ndarray, gk: np.ndarray, hk: np.ndarray, eye: np.ndarray, tol: float,
              max_iter: int) -> np.ndarray:
    """Structure-preserving doubling iterations; returns H (NaN/inf when it diverges)."""
    for _ in range(max_iter):
        w = eye + gk @ hk
        w_inv_a = np.linalg.solve(w, ak)
        w_inv_g = np.linalg.solve(w, gk)
        h_next = hk + ak.T @ hk @ w_inv_a
        g_next = gk + ak @ w_inv_g @ ak.T
        ak = ak @ w_inv_a
        hk_old, hk = hk, 0.5 * (h_next + h_next.T)
        gk = 0.5 * (g_next + g_next.T)
        if not np.all(np.isfinite(hk)):
            return hk
        if np.linalg.norm(hk - hk_old, 1) <= tol * max(1.0, float(np.linalg.norm(hk, 1))):
            return hk
    raise InfeasibleError("Riccati doubling did not converge: is (A, B) stabilisable and (Q, A) detectable?")


def dlqr(
    a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray, cross: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Infinite-horizon discrete LQR.

    Parameters
    ----------
    a, b : ndarray, shapes (n, n), (n, m)
        Discrete model ``x_{k+1} = A x_k + B u_k``.
    q, r : ndarray, shapes (n, n), (m, m)
        State and input weights.
    cross : ndarray, shape (n, m), optional
        Cross weight N.

    Returns
    -------
    K : ndarray, shape (m, n)
        Gain of the law ``u = K x`` (note the sign: ``A + B K`` is the closed loop).
    P : ndarray, shape (n, n)
        Solution of the DARE, the cost-to-go ``xᵀ P x``.
    """
    p = solve_dare(a, b, q, r, cross)
    nt = np.zeros((b.shape[1], a.shape[0])) if cross is None else np.asarray(cross).T
    k = -np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a + nt)
    rho = np.max(np.abs(np.linalg.eigvals(a + b @ k)))
    if rho >= 1.0:
        raise InfeasibleError(f"LQR closed loop is not Schur stable (spectral radius {rho:.6g})")
    return k, p


@dataclass(frozen=True)
class RiccatiSolution:
    """Finite-horizon LQR solution ([Doerr2021] Eqs. 8-9).

    Attributes
    ----------
    S : ndarray, shape (N+1, n, n)
        Quadratic value-function terms.
    s : ndarray, shape (N+1, n)
        Linear value-function terms.
    c : ndarray, shape (N+1,)
        Constant value-function terms; ``V_k(δx) = ½ δxᵀ S_k δx + δxᵀ s_k + c_k``.
    K : ndarray, shape (N, m, n)
        Feedback gains.
    k : ndarray, shape (N, m)
        Feed-forward terms; the optimal policy is ``δu_k = K_k δx_k + k_k``.
    """

    S: np.ndarray
    s: np.ndarray
    c: np.ndarray
    K: np.ndarray
    k: np.ndarray

    def value(self, step: int, dx: np.ndarray) -> float:
        """Optimal cost-to-go ``V_step(δx)`` (Eq. 8).

        Parameters
        ----------
        step : int
            Step index k (0..N).
        dx : ndarray, shape (n,)
            Deviation δx.

        Returns
        -------
        float
        """
        return float(0.5 * dx @ self.S[step] @ dx + dx @ self.s[step] + self.c[step])

    def rollout(
        self, a: np.ndarray, b: np.ndarray, g: np.ndarray, dx0: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Apply the policy to ``δx_{k+1} = A_k δx_k + B_k δu_k + g_k``.

        Parameters
        ----------
        a, b : ndarray, shapes (N, n, n), (N, n, m)
        g : ndarray, shape (N, n)
        dx0 : ndarray, shape (n,)
            Initial deviation.

        Returns
        -------
        dx : ndarray, shape (N+1, n)
        du : ndarray, shape (N, m)
        """
        n_steps = self.K.shape[0]
        xs = np.empty((n_steps + 1, dx0.shape[0]))
        us = np.empty((n_steps, self.K.shape[1]))
        xs[0] = dx0
        for i in range(n_steps):
            us[i] = self.K[i] @ xs[i] + self.k[i]
            xs[i + 1] = a[i] @ xs[i] + b[i] @ us[i] + g[i]
        return xs, us


def tv_riccati(
    a: np.ndarray,
    b: np.ndarray,
    q: np.ndarray,
    r: np.ndarray,
    q_final: np.ndarray,
    *,
    g: np.ndarray | None = None,
    p: np.ndarray | None = None,
    q_lin: np.ndarray | None = None,
    r_lin: np.ndarray | None = None,
    q_final_lin: np.ndarray | None = None,
    c_final: float = 0.0,
) -> RiccatiSolution:
    """Backward Riccati recursion with affine terms ([Doerr2021] Eqs. 8-9).

    Minimises ``Σ_k [½ δxᵀQ_kδx + ½ δuᵀR_kδu + δxᵀP_kδu + q_kᵀδx + r_kᵀδu] + ½ δx_NᵀQ_Nδx_N + q_Nᵀδx_N + c``
    subject to ``δx_{k+1} = A_k δx_k + B_k δu_k + g_k``.

    [Doerr2021] Eq. 9 is written for this cost; here the constants are derived consistently with the ½ factors of
    Eq. 4 (Eq. 9c as printed omits the ½ on ``g_kᵀ S_{k+1} g_k``).

    Parameters
    ----------
    a : ndarray, shape (N, n, n)
    b : ndarray, shape (N, n, m)
    q : ndarray, shape (N, n, n)
    r : ndarray, shape (N, m, m)
    q_final : ndarray, shape (n, n)
    g : ndarray, shape (N, n), optional
        Affine drift g_k (zero by default).
    p : ndarray, shape (N, n, m), optional
        Cross weights P_k.
    q_lin, r_lin : ndarray, shapes (N, n), (N, m), optional
        Linear cost terms q_k, r_k.
    q_final_lin : ndarray, shape (n,), optional
    c_final : float

    Returns
    -------
    RiccatiSolution
        Value function and affine policy per step.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    n_steps, n, _ = a.shape
    m = b.shape[2]
    g = np.zeros((n_steps, n)) if g is None else np.asarray(g, dtype=float)
    p = np.zeros((n_steps, n, m)) if p is None else np.asarray(p, dtype=float)
    q_lin = np.zeros((n_steps, n)) if q_lin is None else np.asarray(q_lin, dtype=float)
    r_lin = np.zeros((n_steps, m)) if r_lin is None else np.asarray(r_lin, dtype=float)
    s_mat = np.empty((n_steps + 1, n, n))
    s_vec = np.empty((n_steps + 1, n))
    c = np.empty(n_steps + 1)
    gains = np.empty((n_steps, m, n))
    ff = np.empty((n_steps, m))
    s_mat[-1] = q_final
    s_vec[-1] = np.zeros(n) if q_final_lin is None else q_final_lin
    c[-1] = c_final
    for i in range(n_steps - 1, -1, -1):
        s_next, sv_next = s_mat[i + 1], s_vec[i + 1]
        ai, bi, gi = a[i], b[i], g[i]
        h = s_next @ gi + sv_next
        qxx = q[i] + ai.T @ s_next @ ai
        quu = r[i] + bi.T @ s_next @ bi
        qux = p[i].T + bi.T @ s_next @ ai
        qx = q_lin[i] + ai.T @ h
        qu = r_lin[i] + bi.T @ h
        sol = np.linalg.solve(quu, np.column_stack([qux, qu]))
        gains[i] = -sol[:, :n]
        ff[i] = -sol[:, n]
        s_new = qxx + qux.T @ gains[i]
        s_mat[i] = 0.5 * (s_new + s_new.T)
        s_vec[i] = qx + qux.T @ ff[i]
        c[i] = 0.5 * gi @ s_next @ gi + gi @ sv_next + c[i + 1] + 0.5 * qu @ ff[i]
    return RiccatiSolution(S=s_mat, s=s_vec, c=c, K=gains, k=ff)
