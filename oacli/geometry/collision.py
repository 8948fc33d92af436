"""Exact continuous collision checks of constant-acceleration motion against the workspace.

The planners move the robot's centre along *pieces* of constant acceleration (a double integrator under a
zero-order-hold force, [Doerr2021] Eq. 34)::

    p(τ) = p0 + v0 τ + ½ a τ²,   0 <= τ <= h,

and a straight segment is the special case ``a = 0``. Checking only the samples of a trajectory misses obstacles
the robot passes through between two samples (the tunnelling problem named in [Doerr2021] §"Ellipsoid Method" and
[ReSWARM2023] §4.2.1); here every piece is checked over its whole time interval:

* **Keep-out ellipsoids** ([Doerr2021] Eqs. 12-14, safety factor already applied by :class:`oacli.geometry.Scene`)
  against the robot's bounding ellipsoid ([ReSWARM2023] §4.2.2, :class:`RobotBody`). For a point robot,
  ``f(τ) = (p(τ) - c)ᵀ P (p(τ) - c) - 1`` is a quartic in τ and its minimum over [0, h] is found exactly from
  the real roots of the cubic ``f'`` (plus the end points). For a robot ellipsoid Σ2 the same exact quartic test
  is made against an outer ellipsoid ``E_s`` of the Minkowski sum (:mod:`oacli.geometry.overlap`): a piece outside
  ``E_s`` for one ``s`` is certified free; a time at which the Gilitschenski-Hanebeck test finds the two
  ellipsoids overlapping is a witness of a collision; otherwise ``s`` is re-optimised at the closest approach and,
  if that still does not decide, the piece is halved and both halves are checked. After ``max_depth`` halvings an
  undecided piece is reported as colliding (conservative; counted in :attr:`CollisionReport.undecided`). For two
  spheres, ``E_s`` at the optimal ``s`` *is* the Minkowski sum, so the test is exact at once.
* **Keep-in boxes**: the robot's centre must stay in the union of the (closed) boxes, as Astrobee's keep-in
  zones are defined for the centre. Each coordinate is a quadratic in τ, so the extremes over a piece are exact;
  a piece that is not inside one box is checked against the union exactly by splitting it at every time a
  coordinate crosses a box face and testing each sub-interval once.

Everything is vectorised over pieces and obstacles; a broad phase (bounding spheres) discards most pairs first.
"Exact" means up to floating-point rounding: the minimum of ``f`` is evaluated at the computed critical points, so
a contact shallower than about 1e-12 (in units of the ellipsoid's own metric) can go unnoticed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.geometry.overlap import max_clearance_sq
from oacli.geometry.quartic import BERNSTEIN, quadratic_form_coeffs, quartic_minimum, quartic_minimum_at_least_zero
from oacli.geometry.shapes import Scene

#: Points on a keep-in box face (within this distance [m]) count as inside (closed boxes).
KEEP_IN_TOLERANCE_M = 1e-9
#: Rounds of re-optimising s at the closest approach before a piece is halved.
_CERTIFY_ROUNDS = 4


@dataclass(frozen=True)
class RobotBody:
    """The robot's bounding ellipsoid ``{x : (x - p)ᵀ Σ⁻¹ (x - p) <= 1}`` around its centre p (world frame).

    Attributes
    ----------
    sigma : ndarray, shape (3, 3)
        Symmetric positive semidefinite Σ [m²]; ``r² I`` for a sphere of radius r, zero for a point.
    """

    sigma: np.ndarray

    def __post_init__(self) -> None:
        sigma = np.array(self.sigma, dtype=float).reshape(3, 3)
        if not np.allclose(sigma, sigma.T, rtol=1e-10, atol=1e-14):
            raise ValueError("robot body Σ must be symmetric")
        if np.linalg.eigvalsh(sigma).min() < -1e-14:
            raise ValueError("robot body Σ must be positive semidefinite")
        sigma.setflags(write=False)
        object.__setattr__(self, "sigma", sigma)

    @classmethod
    def point(cls) -> RobotBody:
        """A point robot (Doerr's ellipsoid-on-point check).

        Returns
        -------
        RobotBody
        """
        return cls(np.zeros((3, 3)))

    @classmethod
    def sphere(cls, radius_m: float) -> RobotBody:
        """A sphere of radius ``radius_m`` [m] (0 gives a point).

        Parameters
        ----------
        radius_m : float
            Radius [m], >= 0.

        Returns
        -------
        RobotBody
        """
        if radius_m < 0:
            raise ValueError(f"robot radius must be >= 0, got {radius_m}")
        return cls(radius_m**2 * np.eye(3))

    @classmethod
    def ellipsoid(cls, semi_axes_m: np.ndarray, rotation: np.ndarray | None = None) -> RobotBody:
        """An ellipsoid with semi-axes [m] along the columns of ``rotation`` (body axes in the world frame).

        Parameters
        ----------
        semi_axes_m : ndarray, shape (3,)
            Semi-axes [m], >= 0.
        rotation : ndarray, shape (3, 3), optional
            Body axes in the world frame (columns); identity by default.

        Returns
        -------
        RobotBody
        """
        a = np.asarray(semi_axes_m, dtype=float).reshape(3)
        if np.any(a < 0):
            raise ValueError(f"semi-axes must be >= 0, got {a}")
        r = np.eye(3) if rotation is None else np.asarray(rotation, dtype=float).reshape(3, 3)
        return cls(r @ np.diag(a**2) @ r.T)

    @property
    def is_point(self) -> bool:
        """True for a point robot."""
        return not np.any(self.sigma)

    @property
    def bounding_radius_m(self) -> float:
        """Radius of the smallest sphere about the centre containing the body [m]."""
        return float(np.sqrt(max(np.linalg.eigvalsh(self.sigma).max(), 0.0)))


@dataclass(frozen=True)
class Pieces:
    """Constant-acceleration pieces ``p(τ) = p0 + v0 τ + ½ acc τ²`` for ``0 <= τ <= h``.

    Attributes
    ----------
    p0 : ndarray, shape (M, 3)
        Start positions [m].
    v0 : ndarray, shape (M, 3)
        Start velocities [m/s].
    acc : ndarray, shape (M, 3)
        Constant accelerations [m/s²] (force / mass).
    h : ndarray, shape (M,)
        Durations [s], >= 0.
    """

    p0: np.ndarray
    v0: np.ndarray
    acc: np.ndarray
    h: np.ndarray

    @classmethod
    def segments(cls, start: np.ndarray, end: np.ndarray) -> Pieces:
        """Straight segments ``start[i] -> end[i]`` (unit duration, zero acceleration).

        Parameters
        ----------
        start, end : ndarray, shape (M, 3)
            End points [m] of each segment.

        Returns
        -------
        Pieces
        """
        a = np.atleast_2d(np.asarray(start, dtype=float))
        b = np.atleast_2d(np.asarray(end, dtype=float))
        return cls(a, b - a, np.zeros_like(a), np.ones(a.shape[0]))

    def __len__(self) -> int:
        return int(self.h.shape[0])

    def position(self, tau: np.ndarray) -> np.ndarray:
        """Positions at times ``tau`` (M,) into each piece, shape (M, 3).

        Parameters
        ----------
        tau : ndarray, shape (M,)
            Time [s] into each piece, ``0 <= tau <= h``.

        Returns
        -------
        ndarray, shape (M, 3)
            Positions [m].
        """
        t = np.asarray(tau, dtype=float)[:, None]
        return self.p0 + self.v0 * t + 0.5 * self.acc * t * t


@dataclass(frozen=True)
class CollisionReport:
    """Outcome of a continuous check of a sequence of pieces.

    Attributes
    ----------
    free : bool
        True when every piece is collision-free.
    piece_free : ndarray of bool, shape (M,)
        Per piece.
    first_piece : int
        Index of the first colliding piece (-1 when free).
    kind : str
        ``"keep_out"`` or ``"keep_in"`` for the first collision, ``""`` when free.
    zone : int
        Index of the keep-out ellipsoid (``kind == "keep_out"``), -1 otherwise.
    time_in_piece_s : float
        Time into the first colliding piece of a witness point [s] (NaN when free or undecided).
    undecided : int
        Pieces reported as colliding because the subdivision depth ran out (conservative).
    """

    free: bool
    piece_free: np.ndarray
    first_piece: int = -1
    kind: str = ""
    zone: int = -1
    time_in_piece_s: float = float("nan")
    undecided: int = 0


class CollisionChecker:
    """Continuous collision checks of a robot body against a :class:`~oacli.geometry.Scene`.

    Parameters
    ----------
    scene : Scene
        Keep-in boxes (for the robot's centre) and keep-out ellipsoids (safety factor applied).
    robot : RobotBody
        The robot's bounding ellipsoid (default: a point).
    max_depth : int
        Halvings of a piece before an undecided piece is declared colliding (robot ellipsoids only).
    """

    def __init__(self, scene: Scene, robot: RobotBody | None = None, *, max_depth: int = 30) -> None:
        self.scene = scene
        self.robot = robot if robot is not None else RobotBody.point()
        self.max_depth = int(max_depth)
        n = len(scene.keep_out)
        self._centers = np.array([e.center for e in scene.keep_out], dtype=float).reshape(n, 3)
        self._shapes = np.array([e.shape for e in scene.keep_out], dtype=float).reshape(n, 3, 3)
        self._transform = np.empty((n, 3, 3))
        self._lam = np.empty((n, 3))
        radii = np.empty(n)
        sigma_r = self.robot.sigma
        for j, e in enumerate(scene.keep_out):
            sigma_o = np.linalg.inv(e.shape)
            chol_inv = np.linalg.inv(np.linalg.cholesky(0.5 * (sigma_o + sigma_o.T)))
            if self.robot.is_point:
                lam, vec = np.zeros(3), np.eye(3)
            else:
                red = chol_inv @ sigma_r @ chol_inv.T
                lam, vec = np.linalg.eigh(0.5 * (red + red.T))
                lam = np.clip(lam, 0.0, None)
            self._transform[j] = vec.T @ chol_inv
            self._lam[j] = lam
            radii[j] = e.principal_axes()[0].max()
        self._broad_radius = radii + self.robot.bounding_radius_m
        self._point_robot = self.robot.is_point
        # One outer ellipsoid E_s of each zone grown by the robot (the zone itself for a point robot), at the s
        # that is optimal for the mean generalised eigenvalue: a piece outside it is free (is_free's pre-pass).
        if self._point_robot:
            self._outer = self._shapes
        else:
            s0 = 1.0 / (1.0 + np.sqrt(np.maximum(self._lam, 1e-300).mean(axis=1)))[:, None]  # (n, 1)
            d0 = s0 * (1.0 - s0) / (s0 + self._lam * (1.0 - s0))
            self._outer = np.einsum("nai,na,naj->nij", self._transform, d0, self._transform)
        self._lower = np.array([b.lower for b in scene.keep_in], dtype=float).reshape(-1, 3)
        self._upper = np.array([b.upper for b in scene.keep_in], dtype=float).reshape(-1, 3)
        # The same numbers as plain floats for the one-position test of a point robot (_point_free_scalar).
        lo_tol, hi_tol = self._lower - KEEP_IN_TOLERANCE_M, self._upper + KEEP_IN_TOLERANCE_M
        self._scalar_boxes: list[tuple[float, ...]] = [tuple(float(v) for v in (*lo, *hi))
                                                       for lo, hi in zip(lo_tol, hi_tol, strict=True)]
        self._scalar_zones: list[tuple[float, float, float, tuple[float, ...]]] = []
        for j in range(n):
            cx, cy, cz = (float(v) for v in self._centers[j])
            self._scalar_zones.append((cx, cy, cz, tuple(float(v) for v in self._transform[j].ravel())))

    # -- points --------------------------------------------------------------------------------------------

    def clearance_sq(self, points: np.ndarray) -> np.ndarray:
        """``g*`` of every point against every keep-out zone, shape (..., n_obstacles); < 1 means overlap.

        Parameters
        ----------
        points : ndarray, shape (..., 3)
            Robot centre positions [m].

        Returns
        -------
        ndarray, shape (..., n_obstacles)
            ``g*`` per keep-out zone (:mod:`oacli.geometry.overlap`).
        """
        p = np.asarray(points, dtype=float)
        delta = p[..., None, :] - self._centers
        w2 = np.einsum("nij,...nj->...ni", self._transform, delta) ** 2
        if self._point_robot:
            return w2.sum(axis=-1)
        g, _ = max_clearance_sq(w2, self._lam)
        return g

    def in_keep_in(self, points: np.ndarray) -> np.ndarray:
        """True where the centre lies in the union of the keep-in boxes (always True without boxes).

        Parameters
        ----------
        points : ndarray, shape (..., 3)
            Robot centre positions [m].

        Returns
        -------
        ndarray of bool, shape (...)
        """
        p = np.asarray(points, dtype=float)
        if self._lower.shape[0] == 0:
            return np.ones(p.shape[:-1], dtype=bool)
        tol = KEEP_IN_TOLERANCE_M
        inside = np.all((p[..., None, :] >= self._lower - tol) & (p[..., None, :] <= self._upper + tol), axis=-1)
        return np.any(inside, axis=-1)

    def points_free(self, points: np.ndarray) -> np.ndarray:
        """True where the robot, centred at each point, is inside the keep-in union and touches no keep-out.

        Parameters
        ----------
        points : ndarray, shape (..., 3)
            Robot centre positions [m].

        Returns
        -------
        ndarray of bool, shape (...)
        """
        p = np.asarray(points, dtype=float)
        if p.shape == (3,) and self._point_robot:  # one position (the planners' samples): plain floats
            return np.array(self._point_free_scalar(float(p[0]), float(p[1]), float(p[2])))
        ok = self.in_keep_in(p)
        if self._centers.shape[0]:
            if self._point_robot:
                ok &= np.all(self.clearance_sq(p) >= 1.0, axis=-1)
                return ok
            # Broad phase (exact outer bound): beyond the zone's bounding sphere grown by the robot's, the
            # robot cannot touch the zone; the overlap test (a Newton search) runs only for the nearer points.
            flat = p.reshape(-1, 3)
            dist = np.linalg.norm(flat[:, None, :] - self._centers, axis=-1)  # (K, n_obstacles)
            near = dist <= self._broad_radius * (1.0 + 1e-9) + 1e-12
            if np.any(near):
                rows, zones = np.nonzero(near)
                # Pre-pass: outside the outer ellipsoid E_s0 of the zone grown by the robot (g(s0) >= 1, so
                # g* >= 1) a point is clear; the overlap test (a Newton search) runs only for the others.
                delta = flat[rows] - self._centers[zones]
                inside = np.einsum("ki,ki->k", np.einsum("kij,kj->ki", self._outer[zones], delta), delta) < 1.0
                if np.any(inside):
                    r_in, z_in = rows[inside], zones[inside]
                    w2 = np.einsum("kij,kj->ki", self._transform[z_in], flat[r_in] - self._centers[z_in]) ** 2
                    g, _ = max_clearance_sq(w2, self._lam[z_in])
                    clear = np.ones(flat.shape[0], dtype=bool)
                    clear[r_in[g < 1.0]] = False
                    ok &= clear.reshape(ok.shape)
        return ok

    def _point_free_scalar(self, x: float, y: float, z: float) -> bool:
        """:meth:`points_free` of one position of a point robot in Python floats (the same sums, in the same
        order: keep-in bounds with the tolerance, ``g = Σ_i (T_i · (p − c))²`` per zone, ``g >= 1``)."""
        if self._scalar_boxes:
            for lx, ly, lz, ux, uy, uz in self._scalar_boxes:
                if lx <= x <= ux and ly <= y <= uy and lz <= z <= uz:
                    break
            else:
                return False
        for cx, cy, cz, t in self._scalar_zones:
            dx, dy, dz = x - cx, y - cy, z - cz
            w0 = t[0] * dx + t[1] * dy + t[2] * dz
            w1 = t[3] * dx + t[4] * dy + t[5] * dz
            w2 = t[6] * dx + t[7] * dy + t[8] * dz
            if w0 * w0 + w1 * w1 + w2 * w2 < 1.0:
                return False
        return True

    def point_violations(self, point: np.ndarray) -> list[tuple[str, int]]:
        """Every violated constraint of one position: ``("keep_in", -1)`` and/or ``("keep_out", j)``.

        Parameters
        ----------
        point : ndarray, shape (3,)
            Robot centre [m].

        Returns
        -------
        list of (str, int)
            Empty when the position is free.
        """
        p = np.asarray(point, dtype=float).reshape(3)
        out: list[tuple[str, int]] = []
        if not self.in_keep_in(p):
            out.append(("keep_in", -1))
        if self._centers.shape[0]:
            g = self.clearance_sq(p)
            out.extend(("keep_out", int(j)) for j in np.flatnonzero(g < 1.0))
        return out

    # -- pieces --------------------------------------------------------------------------------------------

    def is_free(self, pieces: Pieces) -> bool:
        """True when every piece is collision-free (continuous time).

        The same verdict as ``check(pieces).free`` (up to rounding at an exact contact), with less work: no
        per-piece report, the keep-in test first, and the keep-out pairs left by the broad phase first tested
        against one outer ellipsoid ``E_s`` of each zone grown by the robot (the zone itself for a point robot,
        :mod:`oacli.geometry.overlap`): the quartic of a piece outside it has non-negative Bernstein coefficients
        and the piece is free; only the other pairs get the exact test of :meth:`check`.

        Parameters
        ----------
        pieces : Pieces
            The trajectory's constant-acceleration pieces.

        Returns
        -------
        bool
        """
        if len(pieces) == 0:
            return True
        if self._lower.shape[0] and not self._all_in_keep_in(pieces):
            return False
        if not self._centers.shape[0]:
            return True
        piece_idx, zone_idx = self._near_pairs(pieces)
        if piece_idx.shape[0] == 0:
            return True
        dur = pieces.h[piece_idx].astype(float)
        alpha = pieces.p0[piece_idx] - self._centers[zone_idx]
        beta = pieces.v0[piece_idx] * dur[:, None]
        gamma = 0.5 * pieces.acc[piece_idx] * (dur * dur)[:, None]
        coeffs = quadratic_form_coeffs(alpha, beta, gamma, self._outer[zone_idx])
        bern = coeffs @ BERNSTEIN.T
        certified = bern.min(axis=1) >= 0.0
        if certified.all():
            return True
        if self._point_robot:  # the outer ellipsoid is the zone: the test of check() itself
            if np.any(np.minimum(bern[:, 0], bern[:, 4]) < 0.0):
                return False
            value, _ = quartic_minimum(coeffs[~certified])
            return bool(np.all(value >= 0.0))
        rest = ~certified
        free = self._keep_out_pairs(pieces, piece_idx[rest], zone_idx[rest])[2]
        return bool(np.all(free))

    def _all_in_keep_in(self, pc: Pieces) -> bool:
        """Whether every piece stays in the union of the keep-in boxes (as :meth:`_keep_in_ok`, one verdict)."""
        lo, hi = self._axis_extremes(pc)
        tol = KEEP_IN_TOLERANCE_M
        if self._lower.shape[0] == 1:
            return bool(np.all(lo >= self._lower[0] - tol) and np.all(hi <= self._upper[0] + tol))
        inside_box = np.all((lo[:, None, :] >= self._lower - tol) & (hi[:, None, :] <= self._upper + tol), axis=-1)
        ok = np.any(inside_box, axis=1)
        return all(self._inside_union(pc.p0[i], pc.v0[i], pc.acc[i], float(pc.h[i])) for i in np.flatnonzero(~ok))

    def check(self, pieces: Pieces) -> CollisionReport:
        """Check every piece in continuous time; see the module docstring.

        Parameters
        ----------
        pieces : Pieces
            The trajectory's constant-acceleration pieces.

        Returns
        -------
        CollisionReport
            The verdict per piece and the first collision (kind, zone, time).
        """
        m = len(pieces)
        free = np.ones(m, dtype=bool)
        if m == 0:
            return CollisionReport(True, free)
        kind = np.full(m, "", dtype=object)
        zone = np.full(m, -1)
        witness = np.full(m, np.nan)
        if self._lower.shape[0]:
            ok_in = self._keep_in_ok(pieces)
            free &= ok_in
            kind[~ok_in] = "keep_in"
        undecided = np.zeros(m, dtype=bool)
        if self._centers.shape[0]:
            pair_piece, pair_zone, pair_free, pair_tau, pair_undecided = self._keep_out(pieces)
            bad = ~pair_free
            for i, j, tau, und in zip(pair_piece[bad], pair_zone[bad], pair_tau[bad], pair_undecided[bad],
                                      strict=True):
                if free[i]:  # the first violation found names the piece's collision
                    kind[i], zone[i], witness[i] = "keep_out", j, tau
                    free[i] = False
                undecided[i] |= bool(und)
        if np.all(free):
            return CollisionReport(True, free)
        first = int(np.argmin(free))
        return CollisionReport(
            False, free, first, str(kind[first]), int(zone[first]), float(witness[first]), int(undecided.sum())
        )

    # -- keep-in -------------------------------------------------------------------------------------------

    def _keep_in_ok(self, pc: Pieces) -> np.ndarray:
        lo, hi = self._axis_extremes(pc)
        tol = KEEP_IN_TOLERANCE_M
        inside_box = np.all(
            (lo[:, None, :] >= self._lower - tol) & (hi[:, None, :] <= self._upper + tol), axis=-1
        )  # (M, B)
        ok = np.any(inside_box, axis=1)
        if self._lower.shape[0] > 1:
            for i in np.flatnonzero(~ok):
                ok[i] = self._inside_union(pc.p0[i], pc.v0[i], pc.acc[i], float(pc.h[i]))
        return ok

    @staticmethod
    def _axis_extremes(pc: Pieces) -> tuple[np.ndarray, np.ndarray]:
        """Exact per-axis minimum and maximum of the quadratic coordinates over each piece, shapes (M, 3)."""
        h = pc.h[:, None]
        start = pc.p0
        end = pc.p0 + pc.v0 * h + 0.5 * pc.acc * h * h
        tv = np.full(pc.v0.shape, -1.0)
        np.divide(-pc.v0, pc.acc, out=tv, where=pc.acc != 0.0)
        interior = (tv > 0.0) & (tv < h)
        tv = np.where(interior, tv, 0.0)
        vertex = np.where(interior, pc.p0 + pc.v0 * tv + 0.5 * pc.acc * tv * tv, start)
        lo = np.minimum(np.minimum(start, end), vertex)
        hi = np.maximum(np.maximum(start, end), vertex)
        return lo, hi

    def _inside_union(self, p0: np.ndarray, v0: np.ndarray, acc: np.ndarray, h: float) -> bool:
        """Exact test that one piece stays in the union of the boxes: split at every face crossing."""
        times = [0.0, h]
        for bound in (self._lower, self._upper):
            for b in range(bound.shape[0]):
                for i in range(3):
                    a2, a1, a0 = 0.5 * acc[i], v0[i], p0[i] - bound[b, i]
                    if abs(a2) > 1e-300:
                        disc = a1 * a1 - 4.0 * a2 * a0
                        if disc >= 0.0:
                            sq = np.sqrt(disc)
                            times += [(-a1 + sq) / (2.0 * a2), (-a1 - sq) / (2.0 * a2)]
                    elif abs(a1) > 1e-300:
                        times.append(-a0 / a1)
        t = np.unique(np.clip(np.array(times), 0.0, h))
        probes = np.concatenate([t, 0.5 * (t[:-1] + t[1:])])
        pts = p0 + np.outer(probes, v0) + 0.5 * np.outer(probes**2, acc)
        return bool(np.all(self.in_keep_in(pts)))

    # -- keep-out ------------------------------------------------------------------------------------------

    def _near_pairs(self, pc: Pieces) -> tuple[np.ndarray, np.ndarray]:
        """Broad phase: the (piece, zone) pairs whose bounding spheres meet, ``(piece_idx, zone_idx)``."""
        h = pc.h
        mid_t = 0.5 * h
        mid = pc.position(mid_t)
        # np.linalg.norm's own arithmetic (sqrt of the sum of squares), without its overhead.
        reach = np.sqrt((pc.v0 * pc.v0).sum(axis=1)) * mid_t + 0.375 * np.sqrt((pc.acc * pc.acc).sum(axis=1)) * h * h
        delta = mid[:, None, :] - self._centers
        dist = np.sqrt((delta * delta).sum(axis=-1))
        near = dist <= reach[:, None] + self._broad_radius * (1.0 + 1e-9) + 1e-12
        piece_idx, zone_idx = np.nonzero(near)
        return piece_idx, zone_idx

    def _keep_out(self, pc: Pieces):
        """Continuous keep-out test of every (piece, zone) pair surviving the broad phase.

        Returns ``(piece, zone, free, witness_tau, undecided)`` arrays over the tested pairs.
        """
        piece_idx, zone_idx = self._near_pairs(pc)
        return self._keep_out_pairs(pc, piece_idx, zone_idx)

    def _keep_out_pairs(self, pc: Pieces, piece_idx: np.ndarray, zone_idx: np.ndarray):
        """The continuous keep-out test of the given (piece, zone) pairs (:meth:`_keep_out`)."""
        h = pc.h
        n_pairs = piece_idx.shape[0]
        free = np.ones(n_pairs, dtype=bool)
        witness = np.full(n_pairs, np.nan)
        undecided = np.zeros(n_pairs, dtype=bool)
        if n_pairs == 0:
            return piece_idx, zone_idx, free, witness, undecided
        # Work items: (pair, time offset into the piece, sub-piece start state, duration).
        pair = np.arange(n_pairs)
        t_off = np.zeros(n_pairs)
        p0 = pc.p0[piece_idx]
        v0 = pc.v0[piece_idx]
        acc = pc.acc[piece_idx]
        dur = h[piece_idx].astype(float)
        for depth in range(self.max_depth + 1):
            zone = zone_idx[pair]
            ok, bad, tau = self._certify(p0, v0, acc, dur, zone)
            hit = bad & free[pair]
            free[pair[hit]] = False
            witness[pair[hit]] = t_off[hit] + tau[hit]
            open_ = ~ok & ~bad & free[pair]
            if not np.any(open_):
                break
            if depth == self.max_depth:
                free[pair[open_]] = False
                undecided[pair[open_]] = True
                break
            # Halve the undecided sub-pieces.
            half = 0.5 * dur[open_]
            pm, vm, am = p0[open_], v0[open_], acc[open_]
            p_mid = pm + vm * half[:, None] + 0.5 * am * (half * half)[:, None]
            v_mid = vm + am * half[:, None]
            pair = np.concatenate([pair[open_], pair[open_]])
            t_off = np.concatenate([t_off[open_], t_off[open_] + half])
            p0 = np.concatenate([pm, p_mid])
            v0 = np.concatenate([vm, v_mid])
            acc = np.concatenate([am, am])
            dur = np.concatenate([half, half])
        return piece_idx, zone_idx, free, witness, undecided

    def _certify(self, p0, v0, acc, dur, zone):
        """One decision round per sub-piece: certified free, witnessed collision, or open.

        Returns ``(free, collides, witness_tau)`` arrays.
        """
        k = dur.shape[0]
        alpha = p0 - self._centers[zone]
        beta = v0 * dur[:, None]
        gamma = 0.5 * acc * (dur * dur)[:, None]
        if self._point_robot:
            ok, _, smin = quartic_minimum_at_least_zero(quadratic_form_coeffs(alpha, beta, gamma,
                                                                               self._shapes[zone]))
            return ok, ~ok, smin * dur
        t_mat = self._transform[zone]
        lam = self._lam[zone]
        # Start from the outer ellipsoid that is tightest at the closest approach in the zone's own metric.
        _, s0 = quartic_minimum(quadratic_form_coeffs(alpha, beta, gamma, self._shapes[zone]))
        delta = alpha + beta * s0[:, None] + gamma * (s0 * s0)[:, None]
        w2 = np.einsum("kij,kj->ki", t_mat, delta) ** 2
        g, s_param = max_clearance_sq(w2, lam)
        free = np.zeros(k, dtype=bool)
        collides = g < 1.0
        tau = np.where(collides, s0 * dur, np.nan)
        open_ = ~collides
        for _ in range(_CERTIFY_ROUNDS):
            idx = np.flatnonzero(open_)
            if idx.size == 0:
                break
            sp = s_param[idx][:, None]
            d = sp * (1.0 - sp) / (sp + lam[idx] * (1.0 - sp))
            m = np.einsum("kai,ka,kaj->kij", t_mat[idx], d, t_mat[idx])
            cert, _, smin = quartic_minimum_at_least_zero(quadratic_form_coeffs(alpha[idx], beta[idx],
                                                                                  gamma[idx], m))
            free[idx[cert]] = True
            open_[idx[cert]] = False
            rest = idx[~cert]
            if rest.size == 0:
                break
            sr = smin[~cert]
            delta = alpha[rest] + beta[rest] * sr[:, None] + gamma[rest] * (sr * sr)[:, None]
            w2 = np.einsum("kij,kj->ki", t_mat[rest], delta) ** 2
            g, s_new = max_clearance_sq(w2, lam[rest])
            hit = g < 1.0
            collides[rest[hit]] = True
            tau[rest[hit]] = sr[hit] * dur[rest[hit]]
            open_[rest[hit]] = False
            s_param[rest] = s_new
        return free, collides, tau
