"""Trajectory polish, part 1: the time grid, projection onto it and exact propagation
(see :mod:`oacli.planning.polish`)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from oacli.model.robot_model import RobotModel
from oacli.planning.translational import TranslationalTrajectory


def polish_grid(duration_s: float, step_s: float, dt_s: float) -> np.ndarray:
    """Piece lengths [s] covering ``duration_s``: pieces of ``step_s``, the last one shorter if need be.

    ``duration_s`` and ``step_s`` are rounded to multiples of ``dt_s`` (the duration down); every piece is then a
    multiple of ``dt_s``.

    Parameters
    ----------
    duration_s : float
        Duration to cover [s].
    step_s : float
        Piece length [s].
    dt_s : float
        Output sample period [s].

    Returns
    -------
    ndarray, shape (N,)
    """
    total = int(np.floor(duration_s / dt_s + 1e-9))
    per = max(1, round(step_s / dt_s))
    if total < 1:
        raise ValueError(f"duration {duration_s} s is shorter than the output step {dt_s} s")
    counts = [per] * (total // per) + ([total % per] if total % per else [])
    return np.array(counts, dtype=float) * dt_s


def _final_state_map(h: np.ndarray, mass_kg: float) -> np.ndarray:
    """Per axis, the effect ``Γ`` (2, N) of each held force on the final ``[r, v]`` (steps ``h``)."""
    after = np.concatenate([np.cumsum(h[::-1])[::-1][1:], [0.0]])  # time left after each piece
    return np.stack([(h / mass_kg) * (0.5 * h + after), h / mass_kg])


def terminal_correction(x0: np.ndarray, forces: np.ndarray, goal: np.ndarray, h: np.ndarray,
                        model: RobotModel) -> np.ndarray:
    """Least-norm change of the held forces (N, 3) after which the propagated final state is ``goal``.

    Per axis the final state is affine in the forces, ``x_N = Φ x_0 + Γ f`` with the columns
    ``Γ_k = (h_k/m) [h_k/2 + Σ_{j>k} h_j, 1]``; the correction is ``Γᵀ (Γ Γᵀ)⁻¹ (x_g − x_N)`` (N >= 2).

    Parameters
    ----------
    x0 : ndarray, shape (6,)
        Start state.
    forces : ndarray, shape (N, 3)
        Held forces [N].
    goal : ndarray, shape (6,)
        Required final state.
    h : ndarray, shape (N,)
        Piece lengths [s].
    model : RobotModel
        The robot; ``m = model.mass_kg`` [kg].

    Returns
    -------
    ndarray, shape (N, 3)
        The corrected forces.
    """
    h = np.broadcast_to(np.asarray(h, dtype=float), (forces.shape[0],))
    gamma = _final_state_map(h, model.mass_kg)
    x0 = np.asarray(x0, dtype=float)
    final = np.concatenate([x0[0:3] + h.sum() * x0[3:6] + gamma[0] @ forces, x0[3:6] + gamma[1] @ forces])
    err = np.asarray(goal, dtype=float) - final
    lam = np.linalg.solve(gamma @ gamma.T, np.stack([err[0:3], err[3:6]]))  # (2, 3)
    return forces + gamma.T @ lam


def exact_trajectory(x0: np.ndarray, forces: np.ndarray, goal: np.ndarray, h: np.ndarray,
                     model: RobotModel) -> TranslationalTrajectory:
    """The motion of held ``forces`` from ``x0`` corrected to end exactly at ``goal`` (last sample pinned).

    Parameters
    ----------
    x0, forces, goal, h, model
        As in :func:`terminal_correction`.

    Returns
    -------
    TranslationalTrajectory
    """
    h = np.asarray(h, dtype=float)
    forces = terminal_correction(x0, np.asarray(forces, dtype=float).reshape(-1, 3), goal, h, model)
    x = propagate(x0, forces, h, model)
    x[-1] = goal  # equal up to rounding after the correction
    return TranslationalTrajectory.trusted(np.concatenate([[0.0], np.cumsum(h)]), x, forces, model)


def propagate(x0: np.ndarray, forces: np.ndarray, h: np.ndarray, model: RobotModel) -> np.ndarray:
    """Knot states (N+1, 6) of the exact double integrator under held ``forces`` (N, 3) for durations ``h``:
    :meth:`~oacli.planning.translational.TranslationalTrajectory.from_forces` as running sums (the same sums,
    rounded in another order).

    Parameters
    ----------
    x0 : ndarray, shape (6,)
    forces : ndarray, shape (N, 3)
    h : ndarray, shape (N,)
    model : RobotModel
        The robot (its mass [kg]).

    Returns
    -------
    ndarray, shape (N+1, 6)
    """
    x0 = np.asarray(x0, dtype=float)
    hc = np.asarray(h, dtype=float)[:, None]
    dv = forces * (hc / model.mass_kg)
    x = np.empty((forces.shape[0] + 1, 6))
    x[:, 3:6] = np.cumsum(np.vstack([x0[None, 3:6], dv]), axis=0)
    x[:, 0:3] = np.cumsum(np.vstack([x0[None, 0:3], x[:-1, 3:6] * hc + 0.5 * dv * hc]), axis=0)
    return x


def trim_rest(traj: TranslationalTrajectory, goal: np.ndarray, tolerance: float) -> TranslationalTrajectory:
    """Cut the trailing pieces that already rest at ``goal``, keeping at least two pieces; exact again.

    A piece rests when its states are within ``tolerance`` of the goal and its force changes the speed by at most
    ``tolerance`` over the piece.

    Parameters
    ----------
    traj : TranslationalTrajectory
    goal : ndarray, shape (6,)
    tolerance : float
        [m, m/s].

    Returns
    -------
    TranslationalTrajectory
        ``traj`` itself when nothing is cut.
    """
    h = traj.h
    near = np.all(np.abs(traj.x - goal) <= tolerance, axis=1)
    still = np.append(np.all(np.abs(traj.u) * h[:, None] / traj.mass_kg <= tolerance, axis=1), True)
    resting = np.flip(np.cumprod(np.flip(near & still))).astype(bool)  # this sample and every later one rest
    k = max(int(np.argmax(resting)) if resting.any() else len(h), 2)
    if k >= len(h):
        return traj
    return exact_trajectory(traj.x[0], traj.u[:k], goal, h[:k], traj.model)


def project_onto_grid(traj: TranslationalTrajectory, h: np.ndarray, goal: np.ndarray) -> TranslationalTrajectory:
    """The input as a trajectory on the polish grid: held forces fitted by least squares to its states at the
    knots, then corrected to reach ``goal`` exactly (:func:`exact_trajectory`).

    Minimises ``Σ_k ‖r_k − r̂_k‖² + (h̄)² ‖v_k − v̂_k‖²`` (h̄ the mean piece length, so both terms are lengths) over
    the forces, subject to the exact discretisation from the input's first state: an equality-constrained least
    squares problem, solved as one sparse KKT system (all three axes at once). Knots beyond the input's end take
    its final state (the goal at rest).

    Parameters
    ----------
    traj : TranslationalTrajectory
        The input.
    h : ndarray, shape (n,)
        Piece lengths [s] of the grid.
    goal : ndarray, shape (6,)

    Returns
    -------
    TranslationalTrajectory
    """
    h = np.asarray(h, dtype=float)
    n, m = h.shape[0], traj.mass_kg
    t_knots = np.concatenate([[0.0], np.cumsum(h)]) + traj.t[0]
    target = traj.states_at(np.minimum(t_knots, traj.t[-1]))[1:]  # (n, 6): knots 1..n
    w_v = float(np.mean(h)) ** 2
    # Unknowns per axis z = [r_1..r_n, v_1..v_n, f_0..f_{n-1}]; constraints: the dynamics of pieces 0..n-1.
    eye = sp.identity(n, format="csr")
    shift = sp.diags(np.ones(n - 1), -1, shape=(n, n), format="csr")  # picks x_{k-1} for row k
    dyn = sp.bmat([
        [eye - shift, -sp.diags(h) @ shift, sp.diags(-0.5 * h * h / m)],
        [None, eye - shift, sp.diags(-h / m)],
    ], format="csr")
    hess = sp.diags(np.concatenate([np.ones(n), np.full(n, w_v), np.full(n, 1e-12)]))
    kkt = sp.bmat([[hess, dyn.T], [dyn, None]], format="csc")
    x0 = traj.x[0]
    rhs_dyn = np.zeros((2 * n, 3))
    rhs_dyn[0] = x0[0:3] + h[0] * x0[3:6]  # piece 0 starts from the known first state
    rhs_dyn[n] = x0[3:6]
    rhs = np.vstack([target[:, 0:3], w_v * target[:, 3:6], np.zeros((n, 3)), rhs_dyn])
    sol = spla.spsolve(kkt, rhs)
    forces = np.asarray(sol).reshape(-1, 3)[2 * n:3 * n]
    return exact_trajectory(x0, forces, goal, h, traj.model)


def within_limits(traj: TranslationalTrajectory, force_limit_N: np.ndarray, velocity_limit_mps: np.ndarray) -> bool:
    """Every held force and every velocity within its per-axis limit (relative tolerance 1e-9, as the stages).

    Parameters
    ----------
    traj : TranslationalTrajectory
    force_limit_N, velocity_limit_mps : ndarray, shape (3,)

    Returns
    -------
    bool
    """
    return bool(np.all(traj.max_abs_force_N() <= force_limit_N * (1 + 1e-9))
                and np.all(traj.max_abs_velocity_mps() <= velocity_limit_mps * (1 + 1e-9)))
