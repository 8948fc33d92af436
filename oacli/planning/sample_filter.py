"""Early rejection of candidate connections by their sampled positions, many candidates in one product.

The planners try connections in cost order (choose-parent and goal links of LQR-RRT*, the horizons of an LQR
shortcut) and most of them fail because one of their samples already collides: on the S2 slalom of the planner
benchmark 99 % of the rejected choose-parent edges had a colliding sample (issue 13 profile). Their samples are
linear maps of the end points (:meth:`~oacli.planning.steering.LqrConnector.batch`), so the samples of a whole
candidate list can be tested at once here; only a candidate that passes gets the exact continuous check
(:meth:`~oacli.geometry.collision.CollisionChecker.is_free`), so every verdict that lets an edge in is the
checker's.

The test is *sufficient* for a collision (it never rejects a free position), with a relative margin so that
rounding cannot make it disagree with the checker:

* **keep-out** ([Doerr2021] Eqs. 12-14, zones with the safety factor applied): the robot's bounding ellipsoid
  ``{x : xᵀ Σ⁻¹ x <= 1}`` contains the ball of radius ``ρ = √λ_min(Σ)``, and a zone
  ``E = {x : (x - c)ᵀ P (x - c) <= 1}`` lies in the ball of its largest semi-axis ``a_max``, so that ball contains
  ``(ρ / a_max)(E - c)`` and the Minkowski sum ``E ⊕ body`` contains ``c + (1 + ρ / a_max)(E - c)``: the robot
  centred at ``p`` overlaps the zone when ``(p - c)ᵀ P (p - c) < (1 + ρ / a_max)²`` (for a point robot, ρ = 0:
  the centre is inside the zone);
* **keep-in**: the centre is outside every keep-in box by more than the checker's tolerance.
"""

from __future__ import annotations

import numpy as np

from oacli.geometry.collision import KEEP_IN_TOLERANCE_M, CollisionChecker

#: Relative margin of the keep-out threshold (never reject a position the checker might call free).
_KEEP_OUT_RTOL = 1e-9
#: Margin beyond the keep-in tolerance [m].
_KEEP_IN_MARGIN_M = 1e-7


class SampleFilter:
    """Vectorised sufficient collision test of robot centre positions (module docstring).

    Parameters
    ----------
    checker : CollisionChecker
        Its scene (keep-in boxes, keep-out zones) and robot body define the test.
    """

    def __init__(self, checker: CollisionChecker) -> None:
        zones = checker.scene.keep_out
        sigma = checker.robot.sigma
        rho = float(np.sqrt(max(float(np.linalg.eigvalsh(sigma).min()), 0.0)))
        n = len(zones)
        # |L_j (p - c_j)|² = (p - c_j)ᵀ P_j (p - c_j) with P_j = L_jᵀ L_j: all zones in one (K, 3n) product.
        factors = np.array([np.linalg.cholesky(e.shape).T for e in zones], dtype=float).reshape(n, 3, 3)
        centers = np.array([e.center for e in zones], dtype=float).reshape(n, 3)
        self._map = factors.reshape(3 * n, 3).T.copy()  # (3, 3n)
        self._offset = np.einsum("nij,nj->ni", factors, centers).reshape(3 * n)
        a_max = np.array([e.principal_axes()[0].max() for e in zones], dtype=float)
        self._threshold = (1.0 + rho / a_max) ** 2 * (1.0 - _KEEP_OUT_RTOL)
        self._zones = n
        margin = KEEP_IN_TOLERANCE_M + _KEEP_IN_MARGIN_M
        self._lower = np.array([b.lower for b in checker.scene.keep_in], dtype=float).reshape(-1, 3) - margin
        self._upper = np.array([b.upper for b in checker.scene.keep_in], dtype=float).reshape(-1, 3) + margin

    def colliding(self, points: np.ndarray) -> np.ndarray:
        """True where the robot centred at a point certainly collides (never for a free position).

        Parameters
        ----------
        points : ndarray, shape (..., 3)
            Robot centre positions [m].

        Returns
        -------
        ndarray of bool, shape (...)
        """
        p = np.asarray(points, dtype=float)
        flat = p.reshape(-1, 3)
        hit = np.zeros(flat.shape[0], dtype=bool)
        if self._zones:
            w = flat @ self._map
            w -= self._offset
            w *= w
            q = w.reshape(-1, self._zones, 3).sum(axis=2)
            hit = np.any(q < self._threshold, axis=1)
        n_boxes = self._lower.shape[0]
        if n_boxes == 1:
            hit |= np.any((flat < self._lower[0]) | (flat > self._upper[0]), axis=1)
        elif n_boxes > 1:
            inside = np.all((flat[:, None, :] >= self._lower) & (flat[:, None, :] <= self._upper), axis=2)
            hit |= ~np.any(inside, axis=1)
        return hit.reshape(p.shape[:-1])

    def connections_colliding(self, states: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """True for each connection with a certainly colliding sample.

        Parameters
        ----------
        states : ndarray, shape (C, S + 1, 6)
            Sampled states of C connections, zero-padded beyond each horizon
            (:meth:`~oacli.planning.steering.LqrConnector.batch`).
        steps : ndarray of int, shape (C,)
            Horizon of each connection (its samples ``0..steps``).

        Returns
        -------
        ndarray of bool, shape (C,)
        """
        hit = self.colliding(states[:, :, 0:3])
        hit &= np.arange(states.shape[1]) <= np.asarray(steps)[:, None]
        return np.asarray(hit.any(axis=1), dtype=bool)
