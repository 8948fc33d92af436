"""cvxpy building blocks shared by the offline design and the online planner (DPP, built once).

Both linearise the free-flyer along a rollout: translation is an exact LTI double integrator in the world frame,
rotation ``[q (4), ω (3)]`` follows the time-varying RK4 Jacobians ``δx⁺ = A_k δx + B_k δτ`` ([Doerr2021] Eq. 2). The
time-varying products are written column by column with element-wise Parameters
(``δx⁺ = Σ_j A[:, :, j] ⊙ δx_j + Σ_j B[:, :, j] ⊙ δτ_j`` for all k at once) so that cvxpy canonicalises a
handful of expressions instead of one matrix product per step.
"""

from __future__ import annotations

import cvxpy as cp
import numpy as np

N_ROT = 7  # [q (4), ω (3)]


def _columns(expr: cp.Expression, n: int, width: int) -> list[cp.Expression]:
    """Each column of an (n, k) expression repeated ``width`` times across: a list of (n, width) expressions."""
    ones = np.ones((1, width))
    return [cp.reshape(expr[:, j], (n, 1), order="C") @ ones for j in range(expr.shape[1])]


class RotationDynamics:
    """The linearised rotational dynamics over N steps as cvxpy constraints with Parameters.

    Parameters
    ----------
    drot : cp.Variable, shape (N+1, 7)
        Deviation of ``[q, ω]`` from the rollout; ``drot[0] = 0`` is imposed.
    dtau : cp.Expression, shape (N, 3)
        Deviation of the body torque.
    """

    def __init__(self, drot: cp.Variable, dtau: cp.Expression) -> None:
        n = dtau.shape[0]
        self.n = n
        self.a_cols = [cp.Parameter((n, N_ROT), name=f"a_rot_col{j}") for j in range(N_ROT)]
        self.b_cols = [cp.Parameter((n, N_ROT), name=f"b_rot_col{j}") for j in range(3)]
        prev = _columns(drot[:-1], n, N_ROT)
        tau = _columns(dtau, n, N_ROT)
        rhs = sum(cp.multiply(a, x) for a, x in zip(self.a_cols, prev, strict=True)) + sum(
            cp.multiply(b, t) for b, t in zip(self.b_cols, tau, strict=True)
        )
        self.constraints = [drot[0] == 0, drot[1:] == rhs]

    def set(self, a: np.ndarray, b: np.ndarray) -> None:
        """Set the Jacobians ``a (N, 13, 13)``, ``b (N, 13, 6)`` of the full RK4 step (rotational block used).

        Parameters
        ----------
        a : ndarray, shape (N, 13, 13)
        b : ndarray, shape (N, 13, 6)
        """
        a_rot = a[:, 6:13, 6:13]
        b_rot = b[:, 6:13, 3:6]
        for j, param in enumerate(self.a_cols):
            param.value = a_rot[:, :, j]
        for j, param in enumerate(self.b_cols):
            param.value = b_rot[:, :, j]


class AttitudeErrorModel:
    """Affine model ``e_k ≈ e(q̄_k) + E_k δq_k`` of the attitude error to a fixed goal for every sample k.

    Parameters
    ----------
    dq : cp.Expression, shape (K, 4)
        Quaternion deviations.
    """

    def __init__(self, dq: cp.Expression) -> None:
        k = dq.shape[0]
        self.e0 = cp.Parameter((k, 3), name="attitude_error0")
        self.e_cols = [cp.Parameter((k, 3), name=f"attitude_jac_col{j}") for j in range(4)]
        cols = _columns(dq, k, 3)
        self.expr = self.e0 + sum(cp.multiply(c, q) for c, q in zip(self.e_cols, cols, strict=True))

    def set(self, e0: np.ndarray, jac: np.ndarray) -> None:
        """Set the errors ``e0 (K, 3)`` and Jacobians ``jac (K, 3, 4)`` at the rollout.

        Parameters
        ----------
        e0 : ndarray, shape (K, 3)
        jac : ndarray, shape (K, 3, 4)
        """
        self.e0.value = e0
        for j, param in enumerate(self.e_cols):
            param.value = jac[:, :, j]
