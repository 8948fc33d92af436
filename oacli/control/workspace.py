"""Keep-in and keep-out rows of the MPC problems, recomputed at every controller step.

The controllers constrain each predicted position ``p_k`` (k = 0..N) to a convex inner piece of the free space
([Doerr2021] Eqs. 12-14; the same pieces as the trajectory polish and the excitation design,
:mod:`oacli.geometry.halfspaces`):

* **keep-in**: each segment ``k → k+1`` gets the keep-in box that holds the ends of both the reference segment
  and the linearisation segment (the previous plan's, when there is one) — several: the one with the largest
  margin; none: the nearest (:func:`oacli.geometry.halfspaces.best_piece`) — and step k the intersection of the
  boxes of its two segments (a box), shrunk on each axis by ``keep_in_margin_m`` (keep-in boxes bound the robot's
  centre, as in the planners' collision checks; 0 by default) and the tightening below:
  ``lower_k ≤ p_k ≤ upper_k``. Both ends of every predicted segment are then in one convex piece, so the
  segment is too, also where the union turns a corner; scoring the previous plan too keeps the box of a segment
  where the robot is until the plan reaches the next box (a reference that cuts a corner would
  otherwise switch boxes before the robot can follow). The candidates are the boxes and the bridges between
  touching boxes (:func:`oacli.geometry.halfspaces.keep_in_pieces`), so a motion from one box to the next keeps a
  feasible piece once the boxes are shrunk;
* **keep-out**: for zone j, the half-space ``n_jkᵀ p_k ≥ β_jk`` bounded by the supporting plane of the zone grown
  by the robot's body, along the metric direction of the linearisation point (the previous plan's predicted
  position when there is one, else the reference position), moved out by the tightening below. A zone farther
  than ``activation_m`` from every reference and linearisation point of the horizon gets inactive rows
  ``n = 0, β = −1`` (always satisfied), so the number of rows — the Parameters' shapes — is fixed at construction
  and the problem stays DPP.

Tightening by an error set: when the true position is ``p_k + e`` with ``e_i ∈ [−ext_neg_i, ext_pos_i]`` (the tube
MPC's Z projected on position, plus the measurement noise bound), the box shrinks by ``ext`` per face and
``β_jk`` grows by the support ``max_e (−nᵀe) = Σ_i max(n_i, 0) ext_neg_i + max(−n_i, 0) ext_pos_i``, so
``n ᵀ(p_k + e) ≥`` the zone's support: the true position is then inside the box and outside the grown zone.
A further isotropic ``clearance_m`` covers motion between the instants the rows apply to (see the controllers).

Tightening by the state-estimate error (the standard MPC, which plans from the measured state): when the true
position is ``p_k + e`` with ``e`` zero-mean Gaussian of per-axis standard deviations ``σ_i`` (uncorrelated), the
rows keep the true position clear at ``k`` σ: each box face moves in by ``k σ_i`` and ``β_jk`` grows by
``k sqrt(Σ_i n_i² σ_i²)``, the ``k``-σ quantile of ``−nᵀe`` (a Gaussian along the normal: exact for a half-space,
where the error box's support ``k Σ_i |n_i| σ_i`` would be up to √3 times larger).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from oacli.geometry.collision import RobotBody
from oacli.geometry.halfspaces import best_piece, keep_in_pieces, keep_out_zones, point_halfspaces
from oacli.geometry.shapes import Scene

#: Offset of an inactive keep-out row (with a zero normal: ``0 ≥ −1`` always holds).
INACTIVE_OFFSET = -1.0


@dataclass(frozen=True)
class PositionRows:
    """The rows of one solve for K predicted positions (arrays; J keep-out zones).

    Attributes
    ----------
    lower, upper : ndarray, shape (K, 3)
        Keep-in bounds [m] (empty (K, 0) arrays when the scene has no keep-in box).
    normals : ndarray, shape (J, K, 3)
        Unit normals of the keep-out half-spaces (zero rows when inactive).
    offsets : ndarray, shape (J, K)
        β [m] (``INACTIVE_OFFSET`` when inactive).
    """

    lower: np.ndarray
    upper: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray

    def steps(self, index: slice) -> PositionRows:
        """The rows of some of the steps.

        Parameters
        ----------
        index : slice
            Steps to keep.

        Returns
        -------
        PositionRows
        """
        return PositionRows(self.lower[index], self.upper[index], self.normals[:, index], self.offsets[:, index])

    def shifted(self, origin_m: np.ndarray) -> PositionRows:
        """The rows for positions relative to an origin (``p' = p − origin``); inactive rows are unchanged.

        Parameters
        ----------
        origin_m : ndarray, shape (3,)
            The origin [m].

        Returns
        -------
        PositionRows
        """
        o = np.asarray(origin_m, dtype=float)
        return PositionRows(self.lower - o if self.lower.size else self.lower,
                            self.upper - o if self.upper.size else self.upper,
                            self.normals, self.offsets - self.normals @ o if self.offsets.size else self.offsets)

    def violation_m(self, positions: np.ndarray) -> np.ndarray:
        """Largest violation of any row at each step [m] (0 when every row holds).

        Parameters
        ----------
        positions : ndarray, shape (K, 3)
            One position per step [m], in the rows' coordinates.

        Returns
        -------
        ndarray, shape (K,)
        """
        p = np.asarray(positions, dtype=float)
        worst = np.zeros(p.shape[0])
        if self.lower.size:
            worst = np.maximum(worst, np.max(np.maximum(self.lower - p, p - self.upper), axis=1))
        if self.offsets.size:
            gap = self.offsets - np.einsum("jki,ki->jk", self.normals, p)
            worst = np.maximum(worst, gap.max(axis=0))
        return np.maximum(worst, 0.0)


class WorkspaceRows:
    """Builds :class:`PositionRows` for a scene and a robot body (see the module docstring).

    Parameters
    ----------
    scene : Scene
        Keep-in boxes (their union) and keep-out ellipsoids (safety factor applied).
    robot : RobotBody, optional
        The robot's bounding ellipsoid the keep-out zones grow by (a point when omitted).
    keep_in_margin_m : float
        Distance kept from the keep-in walls [m] (the boxes bound the robot's centre).
    extent_m : ndarray, shape (3, 2), optional
        ``[ext_neg, ext_pos]`` per axis [m]: the error set the rows are tightened by (zero by default).
    clearance_m : float
        Extra isotropic margin [m] on every row.
    error_std_m : ndarray, shape (3,), optional
        Per-axis standard deviation σ_i [m] of a Gaussian error of the position the rows constrain (the state
        estimate's); none by default.
    error_sigmas : float
        ``k``: the rows keep the true position clear at ``k`` σ of that error (module docstring), >= 0.
    min_error_margin_m : float
        Floor [m] of the estimate-error margin per axis, ``max(k σ_i, floor)``, >= 0: what the rows keep even
        with an exact state (soft rows, their linearisation about the previous solution and the motion between
        control instants let the true position graze a zone by ~0.01 mm otherwise).
    activation_m : float
        Keep-out zones farther than this [m] from the horizon's points get inactive rows.
    """

    def __init__(self, scene: Scene, robot: RobotBody | None = None, *, keep_in_margin_m: float = 0.0,
                 extent_m: np.ndarray | None = None, clearance_m: float = 0.0, activation_m: float = 2.0,
                 error_std_m: np.ndarray | None = None, error_sigmas: float = 0.0,
                 min_error_margin_m: float = 0.0) -> None:
        self.scene = scene
        self.robot = RobotBody.point() if robot is None else robot
        self.zones = keep_out_zones(scene, self.robot)
        ext = np.zeros((3, 2)) if extent_m is None else np.asarray(extent_m, dtype=float).reshape(3, 2)
        std = np.zeros(3) if error_std_m is None else np.asarray(error_std_m, dtype=float).reshape(3)
        if (np.any(ext < 0) or clearance_m < 0 or keep_in_margin_m < 0 or np.any(std < 0) or error_sigmas < 0
                or not min_error_margin_m >= 0):
            raise ValueError("keep-in margin, tightening extents, clearance, error σ and margin floor must be >= 0")
        self.extent_m = ext
        #: ``max(k σ_i, floor)`` per axis [m]: the estimate-error margin (module docstring).
        self.error_margin_m = np.maximum(float(error_sigmas) * std, float(min_error_margin_m))
        self.clearance_m = float(clearance_m)
        self.activation_m = float(activation_m)
        self.keep_in_margin_m = float(keep_in_margin_m)
        self._shrink_lower = self.keep_in_margin_m + ext[:, 0] + self.clearance_m + self.error_margin_m
        self._shrink_upper = self.keep_in_margin_m + ext[:, 1] + self.clearance_m + self.error_margin_m
        self._lower, self._upper = keep_in_pieces(scene)
        # best_piece's shrunk pieces, (B, 1, 3) each: the same every step.
        margin = 0.5 * (self._shrink_lower + self._shrink_upper)
        self._piece_lo = self._lower[:, None, :] + margin
        self._piece_hi = self._upper[:, None, :] - margin

    @property
    def has_keep_in(self) -> bool:
        """True when the scene has keep-in boxes (else no box rows)."""
        return bool(self.scene.keep_in)

    @property
    def n_zones(self) -> int:
        """Number of keep-out zones J."""
        return len(self.zones)

    def tightening_m(self, normals: np.ndarray) -> np.ndarray:
        """``max_e (−nᵀe)`` over the error box, plus the clearance and the estimate-error margin
        ``k sqrt(Σ n_i² σ_i²)`` [m].

        Parameters
        ----------
        normals : ndarray, shape (..., 3)
            Unit normals.

        Returns
        -------
        ndarray, shape (...)
            How far each half-space's offset moves out.
        """
        n = np.asarray(normals, dtype=float)
        ext = self.extent_m
        gauss = np.sqrt((n**2) @ self.error_margin_m**2)
        return np.asarray(np.maximum(n, 0.0) @ ext[:, 0] + np.maximum(-n, 0.0) @ ext[:, 1] + self.clearance_m + gauss)

    def _best_segment_pieces(self, ref: np.ndarray, lin: np.ndarray) -> np.ndarray:
        """:func:`oacli.geometry.halfspaces.best_piece` of the segments' ends ``ref[:-1], ref[1:], lin[:-1],
        lin[1:]`` with this instance's shrunk pieces: the same differences, each point's once (it ends two
        segments), and the minimum over the same values per segment (a minimum does not depend on the grouping)."""
        points = np.empty((2, 1, *ref.shape))
        points[0, 0] = ref
        points[1, 0] = lin
        slack = np.minimum(points - self._piece_lo, self._piece_hi - points)  # (2, B, K, 3)
        per_point = np.minimum.reduce(slack, axis=3)  # (2, B, K)
        per_segment = np.minimum(per_point[..., :-1], per_point[..., 1:])  # both ends
        return np.asarray(np.minimum(per_segment[0], per_segment[1]).argmax(axis=0))  # reference and plan

    def rows(self, reference_m: np.ndarray, linearisation_m: np.ndarray | None = None) -> PositionRows:
        """Rows for the predicted positions of one solve.

        Parameters
        ----------
        reference_m : ndarray, shape (K, 3)
            Reference positions at the K steps (choose the keep-in pieces).
        linearisation_m : ndarray, shape (K, 3), optional
            The previous plan's positions at the K steps: the keep-out half-spaces are linearised there and the
            keep-in pieces must hold them too (the reference positions when omitted).

        Returns
        -------
        PositionRows
            World-frame rows of the K steps.
        """
        ref = np.asarray(reference_m, dtype=float)
        lin = ref if linearisation_m is None else np.asarray(linearisation_m, dtype=float)
        k = ref.shape[0]
        if self.has_keep_in:
            if k == 1:
                margin = 0.5 * (self._shrink_lower + self._shrink_upper)
                idx = best_piece(self._lower, self._upper, ref, margin=margin)
                lower, upper = self._lower[idx], self._upper[idx]
                lower = lower + self._shrink_lower
                upper = upper - self._shrink_upper
            else:  # the piece of each reference segment; a step is in those of both its segments
                idx = self._best_segment_pieces(ref, lin)
                seg_lo, seg_hi = self._lower[idx], self._upper[idx]
                lower, upper = np.empty((k, 3)), np.empty((k, 3))
                lower[0], lower[-1] = seg_lo[0], seg_lo[-1]
                upper[0], upper[-1] = seg_hi[0], seg_hi[-1]
                np.maximum(seg_lo[:-1], seg_lo[1:], out=lower[1:-1])
                np.minimum(seg_hi[:-1], seg_hi[1:], out=upper[1:-1])
                lower += self._shrink_lower
                upper -= self._shrink_upper
        else:
            lower = upper = np.zeros((k, 0))
        normals = np.zeros((self.n_zones, k, 3))
        offsets = np.full((self.n_zones, k), INACTIVE_OFFSET)
        for j, zone in enumerate(self.zones):
            n, beta, margin = point_halfspaces(zone, lin)
            near = margin.min() < self.activation_m
            if not near and lin is not ref:
                near = point_halfspaces(zone, ref)[2].min() < self.activation_m
            if near:
                normals[j] = n
                offsets[j] = beta + self.tightening_m(n)
        return PositionRows(lower, upper, normals, offsets)


def shifted_plan(plan_t_s: float, plan_step_s: float, plan_m: np.ndarray, times_s: np.ndarray) -> np.ndarray:
    """Positions of a previous plan at new times, linear between its samples and held beyond its ends.

    Parameters
    ----------
    plan_t_s : float
        Time of the plan's first sample [s].
    plan_step_s : float
        Its sample period [s].
    plan_m : ndarray, shape (M, 3)
        Its positions [m].
    times_s : ndarray, shape (K,)
        The new times [s].

    Returns
    -------
    ndarray, shape (K, 3)
    """
    last = plan_m.shape[0] - 1
    u = np.clip((np.asarray(times_s, dtype=float) - plan_t_s) / plan_step_s, 0.0, last)
    i = np.minimum(np.floor(u).astype(int), max(last - 1, 0))
    w = (u - i)[:, None]
    return np.asarray((1.0 - w) * plan_m[i] + w * plan_m[np.minimum(i + 1, last)])


def braking_lines(braking_mps2: np.ndarray, speed_mps: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(slope, intercept)`` per axis of the braking rows ``v ≤ intercept + slope · d`` (see
    :mod:`oacli.control.tube_qp`): ``d`` is the distance to a box face [m], v the velocity towards it [m/s].

    The chords of ``g(d) = sqrt(ā d)`` through ``d = 0, d*/4, d*`` with ``d* = v̄²/ā``: ``s₀ = 2ā/v̄`` (intercept
    0) and ``s₁ = 2ā/(3v̄)`` (intercept v̄/3).

    Parameters
    ----------
    braking_mps2 : ndarray, shape (3,)
        ā per axis [m/s²], > 0 (the rows are invariant under braking at ā; they certify half of it).
    speed_mps : ndarray, shape (3,)
        v̄ per axis [m/s], > 0.

    Returns
    -------
    list of (ndarray, ndarray)
        ``(slope [1/s], intercept [m/s])`` of each row, each shape (3,).
    """
    a = np.asarray(braking_mps2, dtype=float)
    v = np.asarray(speed_mps, dtype=float)
    if np.any(~(a > 0)) or np.any(~(v > 0)):
        raise ValueError("braking acceleration and speed bound must be > 0")
    return [(2.0 * a / v, np.zeros_like(v)), (2.0 * a / (3.0 * v), v / 3.0)]
