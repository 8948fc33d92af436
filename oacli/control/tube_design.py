"""Offline design of the translational tube: ancillary gain K, invariant set Z, tightened constraints.

Under the hover model every world axis of translation is the exact double integrator ``[p, v]⁺ = A [p, v] + B f``
(force in the world frame), decoupled from the other axes and from attitude. The tube is therefore designed per
axis in 2-D (Mayne, Seron & Raković 2005; [Doerr2021] Eqs. 18-27):

1. ``K``: discrete LQR of the axis model (``u = K e``, [Doerr2021] Eq. 18; ReSWARM: Q = diag(5, 10), R = 2);
2. ``W``: :mod:`oacli.control.disturbance` ([Doerr2021] Eq. 28 and configured terms);
3. ``Z``: the RPI outer ε-approximation ``F(α, s)`` of Raković et al. 2005 (Algorithm 1), then
   :func:`oacli.sets.reduce_facets` for a cheaper lasso constraint that is verified RPI and within
   ``(1 + growth) F(α, s)``. With a *relative* ε (the default) the bound covers the set in use:
   ``F_∞ ⊆ Z ⊆ (1 + ε) F_∞`` (see :func:`split_relative_epsilon`); with the paper's *absolute* ε,
   ``Z ⊆ (1 + growth)(F_∞ ⊕ B_∞(ε))``;
4. tightened sets ``Ū = U ⊖ K Z`` and ``X̄ = X ⊖ (Z ⊕ (−N))`` (N: measurement noise box; the true state is
   ``x = x̃ − n``), with X the velocity limit.

The summary measures Z against the minimal box, the box hull of ``F_∞`` from the independent series
:func:`oacli.sets.minimal_rpi_support`, and states what the tightened bounds gain over the ReSWARM flight
settings (absolute ε = 0.005, 5 % facet growth; :data:`BASELINE_EPSILON`) and how far they are from the ideal
``U ⊖ K F_∞``, ``X ⊖ (F_∞ ⊕ N)``.

With an observer (:class:`ObserverSpec`, [Mayne2006]) Z is replaced by the sets of :mod:`oacli.sets.error_set`:
the lasso ``R = T ⊖ S``, the promise T, ``Ū = U ⊖ K R`` and ``X̄ = X ⊖ T``.

If a tightened set loses the origin (W too large for the actuators, [ReSWARM2023] §4.5), the design refuses with
W and the actuator margin, unless the explicit policy ``"scale_w"`` is chosen: then W of that axis is scaled down
to the largest factor that leaves ``min_nominal_fraction`` of each limit to the nominal MPC (reported).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np

from oacli.control.disturbance import AxisDisturbance, DisturbanceSpec
from oacli.control.lqr import dlqr
from oacli.control.tube_epsilon import reduction_growth, split_relative_epsilon
from oacli.control.tube_qp import LinearConstraint
from oacli.errors import InfeasibleError
from oacli.model.double_integrator import double_integrator
from oacli.model.robot_model import RobotModel
from oacli.sets import (
    EpsilonMode,
    FacetReduction,
    Polytope,
    RPIApproximation,
    RPITermsError,
    minimal_rpi_outer,
    minimal_rpi_support,
    reduce_facets,
)
from oacli.sets.error_set import OutputFeedbackSets, output_feedback_sets, output_feedback_summary

AXIS_NAMES = ("x", "y", "z")

#: Default facet growth of the lasso reduction (with a relative ε: its largest share of the bound).
DEFAULT_FACET_GROWTH = 0.02

#: The tube of the ReSWARM flight code (rattle ``z_poly_calc``: absolute ε = 0.005 [m, m/s]) with the 5 % facet
#: growth oacli used before relative ε: the baseline the summary's ``tightening_gain`` is measured against.
BASELINE_EPSILON = 0.005
BASELINE_FACET_GROWTH = 0.05

_E_POSITION = np.array([1.0, 0.0])
_E_VELOCITY = np.array([0.0, 1.0])


@dataclass(frozen=True)
class AncillaryWeights:
    """LQR weights of the ancillary law per axis: ``Q = diag(position, velocity)``, ``R = force``."""

    position: float = 5.0
    velocity: float = 10.0
    force: float = 2.0


@dataclass(frozen=True)
class ObserverSpec:
    """Output feedback ([Mayne2006]): observer gain L (2, 2) of every axis, noise bound ``(3, 2)`` [m, m/s]."""

    gain: np.ndarray
    noise: np.ndarray


@dataclass(frozen=True)
class AxisTube:
    """The tube of one world axis (state ``[position m, velocity m/s]``, input force N).

    Attributes
    ----------
    name : str
    a, b : ndarray, shapes (2, 2), (2, 1)
        Exact model over one control step.
    gain : ndarray, shape (1, 2)
        Ancillary gain K: ``u = v + K (x − z)``.
    disturbance : AxisDisturbance
    rpi : RPIApproximation
        ``F(α, s)`` (before facet reduction).
    reduction : FacetReduction
        The set used (``reduction.z``) and how it was obtained.
    force_limit_N, velocity_limit_mps : float
        The constraints U and X of the axis.
    force_bounds_N, velocity_bounds_mps : tuple of float
        Tightened ``(lower, upper)`` bounds for the nominal MPC.
    epsilon : float
        The configured ε (relative [-] or absolute [m, m/s], by ``epsilon_mode``).
    epsilon_mode : {"relative", "absolute"}
    output : OutputFeedbackSets or None
        With an observer ([Mayne2006]): S, the tube T (then ``rpi``/``reduction``), the lasso ``R = T ⊖ S``.
    """

    name: str
    a: np.ndarray
    b: np.ndarray
    gain: np.ndarray
    disturbance: AxisDisturbance
    rpi: RPIApproximation
    reduction: FacetReduction
    force_limit_N: float
    velocity_limit_mps: float
    force_bounds_N: tuple[float, float]
    velocity_bounds_mps: tuple[float, float]
    epsilon: float
    epsilon_mode: EpsilonMode
    output: OutputFeedbackSets | None = None

    @property
    def z(self) -> Polytope:
        """The lasso set of the QP: Z (state feedback) or ``R = T ⊖ S`` (output feedback)."""
        return self.reduction.z if self.output is None else self.output.lasso

    @property
    def promise(self) -> Polytope:
        """The tube promised for the true state around the nominal: Z, or T with an observer."""
        return self.reduction.z

    @property
    def w_promise(self) -> Polytope:
        """The disturbance of the promised tube's invariance: W, or ``(−B K) S ⊕ W`` with an observer."""
        return self.disturbance.w if self.output is None else self.output.w_true

    @property
    def a_closed(self) -> np.ndarray:
        """``A_K = A + B K``."""
        return np.asarray(self.a + self.b @ self.gain)

    @property
    def ancillary_force_N(self) -> float:
        """Largest ancillary force ``max_{e ∈ Z} |K e|`` [N]."""
        k = self.gain[0]
        return float(max(self.z.support(k), self.z.support(-k)))

    @property
    def feasible(self) -> bool:
        """True when both tightened sets keep the origin in their interior."""
        (ulo, uhi), (vlo, vhi) = self.force_bounds_N, self.velocity_bounds_mps
        return ulo < 0 < uhi and vlo < 0 < vhi

    @property
    def relative_bound(self) -> float:
        """Guaranteed ``b`` with ``Z ⊆ (1 + b) F_∞`` in every direction: ``(1 − α)⁻¹ (1 + growth) − 1``
        (``F(α, s) ⊆ (1 − α)⁻¹ F_∞`` and ``Z ⊆ (1 + growth) F(α, s)``, whichever ε mode was used)."""
        return (1.0 + self.rpi.relative_accuracy) * (1.0 + self.reduction.growth) - 1.0

    @cached_property
    def minimal_support(self) -> dict[str, float]:
        """Support values of ``F_∞`` (independent series, :func:`oacli.sets.minimal_rpi_support`), largest over
        ``±d``: ``position`` [m], ``velocity`` [m/s] (the minimal box), ``force`` ``max |K e|`` [N]."""
        k = self.gain[0]
        dirs = np.vstack([_E_POSITION, -_E_POSITION, _E_VELOCITY, -_E_VELOCITY, k, -k])
        h, _ = minimal_rpi_support(self.a_closed, self.w_promise, dirs)
        return {"position": float(max(h[0], h[1])), "velocity": float(max(h[2], h[3])),
                "force": float(max(h[4], h[5]))}

    @property
    def ratio_to_minimal_box(self) -> tuple[float, float]:
        """``(position, velocity)``: Z's half-width over the minimal box's, largest over ``±e`` (≥ 1)."""
        h, z = self.minimal_support, self.promise
        pos = max(z.support(_E_POSITION), z.support(-_E_POSITION)) / h["position"]
        vel = max(z.support(_E_VELOCITY), z.support(-_E_VELOCITY)) / h["velocity"]
        return float(pos), float(vel)

    def ideal_bounds(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The tightened ``(force, velocity)`` bounds with ``Z = F_∞`` itself: what no tube can beat.

        Returns
        -------
        force_N, velocity_mps : tuple of float
            ``(lower, upper)`` of ``U ⊖ K F_∞`` [N] and of ``X ⊖ (F_∞ ⊕ N)`` [m/s].
        """
        h = self.minimal_support
        v = self.velocity_limit_mps - h["velocity"] - float(self.disturbance.noise_bound[1])
        u = self.force_limit_N - h["force"]
        return (-u, u), (-v, v)

    @cached_property
    def baseline(self) -> AxisTube | None:
        """This axis designed with the ReSWARM flight settings (absolute ε = :data:`BASELINE_EPSILON`, facet
        growth :data:`BASELINE_FACET_GROWTH`), same A, K and W; None when that design needs too many terms, and
        with an observer (the flight's tube had none)."""
        if self.output is not None:
            return None
        try:
            return _axis_from_parts(
                self.name, self.a, self.b, self.gain, self.disturbance, force_limit_N=self.force_limit_N,
                velocity_limit_mps=self.velocity_limit_mps, epsilon=BASELINE_EPSILON, epsilon_mode="absolute",
                max_terms=2000, facet_growth=BASELINE_FACET_GROWTH,
            )
        except (RPITermsError, InfeasibleError):
            return None


@dataclass(frozen=True)
class TubeDesign:
    """The translational tube of all three axes; vectors are ordered ``[r (3), v (3)]`` and ``f (3)``."""

    axes: tuple[AxisTube, AxisTube, AxisTube]
    dt_s: float
    model: RobotModel

    @property
    def gain(self) -> np.ndarray:
        """Ancillary gain (3, 6) on the error ``[r − r_z, v − v_z]``."""
        k = np.zeros((3, 6))
        for i, ax in enumerate(self.axes):
            k[i, i], k[i, i + 3] = ax.gain[0]
        return k

    def _embed(self, i: int, a2: np.ndarray) -> np.ndarray:
        out = np.zeros((a2.shape[0], 6))
        out[:, i], out[:, i + 3] = a2[:, 0], a2[:, 1]
        return out

    @cached_property
    def lasso(self) -> LinearConstraint:
        """Z of the 6-D translational error as ``H e ≤ h`` (block diagonal over the axes)."""
        h_mat = np.vstack([self._embed(i, ax.z.a) for i, ax in enumerate(self.axes)])
        return LinearConstraint(h_mat, np.concatenate([ax.z.b for ax in self.axes]))

    @cached_property
    def promise(self) -> LinearConstraint:
        """The tube promised for the true state (Z, or T with an observer) as ``H e ≤ h`` (block diagonal)."""
        if all(ax.output is None for ax in self.axes):
            return self.lasso
        h_mat = np.vstack([self._embed(i, ax.promise.a) for i, ax in enumerate(self.axes)])
        return LinearConstraint(h_mat, np.concatenate([ax.promise.b for ax in self.axes]))

    @property
    def output_feedback(self) -> bool:
        """True when the design has an observer ([Mayne2006])."""
        return self.axes[0].output is not None

    @cached_property
    def lasso_for_solver(self) -> LinearConstraint:
        """The lasso of the QP: Z shrunk by half of each axis's smallest invariance margin.

        A QP solution may violate a constraint by the solver's feasibility tolerance; with this back-off the
        applied nominal state still satisfies ``x̃ − z_0 ∈ Z`` exactly. Recursive feasibility is kept: with
        every margin ``h_i − h_Z(A_Kᵀa_i) − h_W(a_i) ≥ m``, the predicted ``ẑ`` gives ``a_iᵀ(x̃⁺ − ẑ) ≤ h_i − m``.
        """
        backoff = np.concatenate([np.full(ax.z.n_facets, 0.5 * max(ax.reduction.min_margin, 0.0))
                                  for ax in self.axes])
        lasso = self.lasso
        return LinearConstraint(lasso.h_matrix, lasso.h_vector - backoff)

    @property
    def tightened_state(self) -> LinearConstraint:
        """X̄ on ``[r, v]``: the tightened velocity bounds (positions are free)."""
        lo = np.array([ax.velocity_bounds_mps[0] for ax in self.axes])
        hi = np.array([ax.velocity_bounds_mps[1] for ax in self.axes])
        return LinearConstraint.box(np.r_[np.full(3, np.inf), hi], np.r_[np.full(3, -np.inf), lo])

    @property
    def tightened_input(self) -> LinearConstraint:
        """Ū on the force."""
        lo = np.array([ax.force_bounds_N[0] for ax in self.axes])
        hi = np.array([ax.force_bounds_N[1] for ax in self.axes])
        return LinearConstraint.box(hi, lo)

    def error_margin(self, e: np.ndarray) -> float:
        """``min_i (h_i − H_i e)`` for the 6-D error ``e``: ≥ 0 exactly when ``e ∈ Z``.

        Parameters
        ----------
        e : ndarray, shape (6,)
            Error ``[r, v] − z``.

        Returns
        -------
        float
        """
        lasso = self.lasso
        # np.min's own reduction (np.minimum.reduce), without its wrapper: the same value.
        return float(np.minimum.reduce(lasso.h_vector - lasso.h_matrix @ np.asarray(e, dtype=float), axis=None))

    def position_extent(self) -> np.ndarray:
        """Half-extents ``[−min, max]`` per axis of the promised tube's (Z's or T's) projection on position [m].

        Returns
        -------
        ndarray, shape (3, 2)
        """
        return np.array([[ax.promise.support(np.array([-1.0, 0.0])), ax.promise.support(np.array([1.0, 0.0]))]
                         for ax in self.axes])

    def summary(self) -> dict[str, Any]:
        """Figures a reviewer wants: RPI size and cost, W, gains, tightened bounds (lists over x, y, z).

        ``rpi.epsilon`` is the configured ε (``rpi.epsilon_mode``), ``rpi.epsilon_rpi`` the ε of ``F(α, s)``
        (relative mode: its share of the bound), ``rpi.relative_bound`` the guaranteed ``Z ⊆ (1 + b) F_∞``.
        ``minimal_box_*`` is the box hull of ``F_∞`` and ``z_to_minimal_box`` Z's ratio to it.
        ``tightening_gain`` compares the tightened bounds with the ReSWARM flight settings (``baseline``) and
        with the ideal ``Z = F_∞``: ``*_gain_*`` = upper bound now − upper bound of the baseline (> 0: the
        nominal MPC got more room), ``*_to_ideal_*`` = ideal − now (≥ 0).

        Returns
        -------
        dict
            JSON-ready values.
        """
        axes = self.axes
        axes_sets = [ax.output for ax in axes if ax.output is not None]
        baselines = [ax.baseline for ax in axes]
        ideal = [ax.ideal_bounds() for ax in axes]

        def upper(bounds: Any) -> Any:
            return None if bounds is None else float(bounds[1])

        base_force = [None if b is None else list(b.force_bounds_N) for b in baselines]
        base_vel = [None if b is None else list(b.velocity_bounds_mps) for b in baselines]
        return {
            "rpi": {
                "s": [ax.rpi.s for ax in axes],
                "alpha": [ax.rpi.alpha for ax in axes],
                "facets": [ax.reduction.facets_after for ax in axes],
                "facets_before_reduction": [ax.reduction.facets_before for ax in axes],
                "facet_growth": [ax.reduction.growth for ax in axes],
                "epsilon": axes[0].epsilon,
                "epsilon_mode": axes[0].epsilon_mode,
                "epsilon_rpi": [ax.rpi.epsilon for ax in axes],
                "epsilon_achieved": [ax.rpi.epsilon_achieved for ax in axes],
                "relative_bound": [ax.relative_bound for ax in axes],
                "min_invariance_margin": [ax.reduction.min_margin for ax in axes],
                "spectral_radius": [ax.rpi.spectral_radius for ax in axes],
            },
            "minimal_box_position_m": [ax.minimal_support["position"] for ax in axes],
            "minimal_box_velocity_mps": [ax.minimal_support["velocity"] for ax in axes],
            "z_to_minimal_box": {
                "position": [ax.ratio_to_minimal_box[0] for ax in axes],
                "velocity": [ax.ratio_to_minimal_box[1] for ax in axes],
            },
            "tightening_gain": {
                "baseline": {"epsilon_mode": "absolute", "epsilon": BASELINE_EPSILON,
                             "facet_growth": BASELINE_FACET_GROWTH},
                "baseline_force_N": base_force,
                "baseline_velocity_mps": base_vel,
                "force_gain_N": [None if b is None else ax.force_bounds_N[1] - b.force_bounds_N[1]
                                 for ax, b in zip(axes, baselines, strict=True)],
                "velocity_gain_mps": [None if b is None else ax.velocity_bounds_mps[1] - b.velocity_bounds_mps[1]
                                      for ax, b in zip(axes, baselines, strict=True)],
                "ideal_force_N": [list(f) for f, _ in ideal],
                "ideal_velocity_mps": [list(v) for _, v in ideal],
                "force_to_ideal_N": [upper(f) - ax.force_bounds_N[1] for ax, (f, _) in zip(axes, ideal, strict=True)],
                "velocity_to_ideal_mps": [upper(v) - ax.velocity_bounds_mps[1]
                                          for ax, (_, v) in zip(axes, ideal, strict=True)],
            },
            "w_position_m": [float(ax.disturbance.half_widths[0]) for ax in axes],
            "w_velocity_mps": [float(ax.disturbance.half_widths[1]) for ax in axes],
            "w_scale": [ax.disturbance.scale for ax in axes],
            "ancillary_gain": [[float(g) for g in ax.gain[0]] for ax in axes],
            "z_position_m": [float(ax.z.support(np.array([1.0, 0.0]))) for ax in axes],
            "z_velocity_mps": [float(ax.z.support(np.array([0.0, 1.0]))) for ax in axes],
            "ancillary_force_max_N": [ax.ancillary_force_N for ax in axes],
            "tightened_force_N": [list(ax.force_bounds_N) for ax in axes],
            "tightened_velocity_mps": [list(ax.velocity_bounds_mps) for ax in axes],
            **({} if axes[0].output is None else {"output_feedback": output_feedback_summary(axes_sets)}),
        }


def _interval(p: Polytope) -> tuple[float, float]:
    """``(lower, upper)`` of a 1-D polytope (−inf/inf where unbounded)."""
    return -float(p.support(np.array([-1.0]))), float(p.support(np.array([1.0])))


def design_axis(
    axis: int,
    *,
    model: RobotModel,
    dt_s: float,
    force_limit_N: float,
    velocity_limit_mps: float,
    weights: AncillaryWeights,
    spec: DisturbanceSpec,
    epsilon: float,
    epsilon_mode: EpsilonMode = "relative",
    max_terms: int = 1000,
    facet_growth: float = DEFAULT_FACET_GROWTH,
    w_scale: float = 1.0,
    observer: ObserverSpec | None = None,
) -> AxisTube:
    """Design the tube of one axis (no feasibility decision: see :attr:`AxisTube.feasible`).

    Parameters
    ----------
    axis : int
        World axis 0, 1 or 2.
    model, dt_s, weights, spec, epsilon, epsilon_mode, max_terms, facet_growth
        As in :func:`design_translation_tube`.
    force_limit_N, velocity_limit_mps : float
        U and X of this axis.
    w_scale : float, optional
        Factor applied to W (1: none).
    observer : ObserverSpec, optional
        Output feedback (:mod:`oacli.sets.error_set`); None: state feedback.

    Returns
    -------
    AxisTube
    """
    a, b = double_integrator(dt_s, 1.0 / model.mass_kg)
    gain, _ = dlqr(a, b, np.diag([weights.position, weights.velocity]), np.array([[weights.force]]))
    dist = spec.axis(model, axis, force_limit_N, dt_s, w_scale)
    parts = None if observer is None else (np.asarray(observer.gain, dtype=float), np.asarray(observer.noise)[axis])
    try:
        return _axis_from_parts(AXIS_NAMES[axis], a, b, gain, dist, force_limit_N=force_limit_N,
                                velocity_limit_mps=velocity_limit_mps, epsilon=epsilon, epsilon_mode=epsilon_mode,
                                max_terms=max_terms, facet_growth=facet_growth, observer=parts)
    except RPITermsError as exc:
        needed = f"{exc.needed} terms" if exc.needed is not None else f"more than {20 * exc.max_terms} terms"
        raise InfeasibleError(
            f"controller.tube.rpi_max_terms: the invariant set of the {AXIS_NAMES[axis]} axis needs {needed} for "
            f"the {epsilon_mode} rpi_epsilon = {epsilon:g}, more than rpi_max_terms = {exc.max_terms} (spectral "
            f"radius of A + BK {exc.spectral_radius:.6g}); raise controller.tube.rpi_max_terms (at most 2000) or "
            "controller.tube.rpi_epsilon, or choose faster ancillary weights (controller.tube.ancillary)"
        ) from None


def _axis_from_parts(
    name: str,
    a: np.ndarray,
    b: np.ndarray,
    gain: np.ndarray,
    dist: AxisDisturbance,
    *,
    force_limit_N: float,
    velocity_limit_mps: float,
    epsilon: float,
    epsilon_mode: EpsilonMode,
    max_terms: int,
    facet_growth: float,
    observer: tuple[np.ndarray, np.ndarray] | None = None,
) -> AxisTube:
    """Z (Raković et al. 2005 + facet reduction) and the tightened bounds of one axis from A, B, K and W.

    The result depends on the inputs only (numbers, no randomness), so it is memoised within the process by their
    exact values (:data:`_AXIS_CACHE`): the mission's tube stages and their summaries' flight-settings baselines
    often design the same axis twice, and the three axes of an isotropic robot are the same design under three
    names (the name is the only field that differs: the other axes copy the first one's, with its ``minimal_support``
    when computed). The returned :class:`AxisTube` is immutable; its cached figures (``minimal_support``,
    ``baseline``) are shared with every later caller of the same inputs.
    """
    values = (*(np.ascontiguousarray(m, dtype=float).tobytes() for m in (a, b, gain, dist.w.a, dist.w.b,
                                                                      dist.mass_term, dist.force_term,
                                                                      dist.box_term, dist.noise_bound)),
              a.shape, dist.w.a.shape, float(dist.scale), float(force_limit_N), float(velocity_limit_mps),
              float(epsilon), epsilon_mode, int(max_terms), float(facet_growth),
              None if observer is None else tuple(np.ascontiguousarray(m, dtype=float).tobytes() for m in observer))
    named = _AXIS_CACHE.get(values)
    if named is None:
        named = {}
        if len(_AXIS_CACHE) >= _AXIS_CACHE_SIZE:
            _AXIS_CACHE.pop(next(iter(_AXIS_CACHE)))
        _AXIS_CACHE[values] = named
    cached = named.get(name)
    if cached is not None:
        return cached
    if named:  # the same design under another name
        other = next(iter(named.values()))
        axis = replace(other, name=name)
        if "minimal_support" in other.__dict__:
            axis.__dict__["minimal_support"] = other.__dict__["minimal_support"]
    else:
        axis = _design_axis_from_parts(name, a, b, gain, dist, force_limit_N=force_limit_N,
                                       velocity_limit_mps=velocity_limit_mps, epsilon=epsilon,
                                       epsilon_mode=epsilon_mode, max_terms=max_terms, facet_growth=facet_growth,
                                       observer=observer)
    named[name] = axis
    return axis


#: Memo of :func:`_axis_from_parts` by the exact input values, then by axis name (oldest inputs dropped beyond the
#: size).
_AXIS_CACHE: dict[tuple[Any, ...], dict[str, AxisTube]] = {}
_AXIS_CACHE_SIZE = 64


def _design_axis_from_parts(
    name: str,
    a: np.ndarray,
    b: np.ndarray,
    gain: np.ndarray,
    dist: AxisDisturbance,
    *,
    force_limit_N: float,
    velocity_limit_mps: float,
    epsilon: float,
    epsilon_mode: EpsilonMode,
    max_terms: int,
    facet_growth: float,
    observer: tuple[np.ndarray, np.ndarray] | None = None,
) -> AxisTube:
    """The uncached body of :func:`_axis_from_parts`."""
    a_k = a + b @ gain
    if observer is not None:
        return _output_feedback_axis(name, a, b, gain, dist, force_limit_N=force_limit_N,
                                     velocity_limit_mps=velocity_limit_mps, epsilon=epsilon,
                                     epsilon_mode=epsilon_mode, max_terms=max_terms, facet_growth=facet_growth,
                                     observer=observer)
    if epsilon_mode == "relative":
        epsilon_rpi, _ = split_relative_epsilon(epsilon, facet_growth)
        rpi = minimal_rpi_outer(a_k, dist.w, epsilon_rpi, mode="relative", max_terms=max_terms)
        growth = reduction_growth(epsilon, facet_growth, rpi.alpha)
    elif epsilon_mode == "absolute":
        rpi = minimal_rpi_outer(a_k, dist.w, epsilon, mode="absolute", max_terms=max_terms)
        growth = facet_growth
    else:
        raise ValueError(f"epsilon_mode must be 'relative' or 'absolute', got {epsilon_mode!r}")
    reduction = reduce_facets(a_k, rpi.z, dist.w, growth)
    z = reduction.z
    u_set = Polytope.symmetric_box([force_limit_N])
    u_bar = u_set.pontryagin_difference(z.linear_map(gain))  # Ū = U ⊖ K Z
    x_set = Polytope(np.array([[0.0, 1.0], [0.0, -1.0]]), np.array([velocity_limit_mps, velocity_limit_mps]))
    noise = dist.noise_bound
    z_true = z if not np.any(noise > 0) else z.minkowski_sum(Polytope.symmetric_box(noise))  # Z ⊕ (−N), N symmetric
    x_bar = x_set.pontryagin_difference(z_true)  # X̄ = X ⊖ (Z ⊕ −N)
    vel_hi, vel_neg_lo = x_bar.b  # rows [0, 1] and [0, −1]
    return AxisTube(
        name=name,
        a=a,
        b=b,
        gain=gain,
        disturbance=dist,
        rpi=rpi,
        reduction=reduction,
        force_limit_N=float(force_limit_N),
        velocity_limit_mps=float(velocity_limit_mps),
        force_bounds_N=_interval(u_bar),
        velocity_bounds_mps=(-float(vel_neg_lo), float(vel_hi)),
        epsilon=float(epsilon),
        epsilon_mode=epsilon_mode,
    )


def _output_feedback_axis(
    name: str,
    a: np.ndarray,
    b: np.ndarray,
    gain: np.ndarray,
    dist: AxisDisturbance,
    *,
    force_limit_N: float,
    velocity_limit_mps: float,
    epsilon: float,
    epsilon_mode: EpsilonMode,
    max_terms: int,
    facet_growth: float,
    observer: tuple[np.ndarray, np.ndarray],
) -> AxisTube:
    """One axis with an observer ([Mayne2006]; :mod:`oacli.sets.error_set`): ``Ū = U ⊖ K R``, ``X̄ = X ⊖ T``."""
    eps, growth = (split_relative_epsilon(epsilon, facet_growth) if epsilon_mode == "relative"
                   else (epsilon, facet_growth))
    ell, noise = observer
    sets = output_feedback_sets(a, b, gain, ell, dist.w, Polytope.symmetric_box(noise), epsilon=eps,
                                epsilon_mode=epsilon_mode, max_terms=max_terms, facet_growth=growth)
    u_bar = Polytope.symmetric_box([force_limit_N]).pontryagin_difference(sets.lasso.linear_map(gain))
    x_set = Polytope(np.array([[0.0, 1.0], [0.0, -1.0]]), np.array([velocity_limit_mps, velocity_limit_mps]))
    x_bar = x_set.pontryagin_difference(sets.t)
    vel_hi, vel_neg_lo = x_bar.b
    return AxisTube(name=name, a=a, b=b, gain=gain, disturbance=dist, rpi=sets.true_rpi, reduction=sets.true,
                    force_limit_N=float(force_limit_N), velocity_limit_mps=float(velocity_limit_mps),
                    force_bounds_N=_interval(u_bar), velocity_bounds_mps=(-float(vel_neg_lo), float(vel_hi)),
                    epsilon=float(epsilon), epsilon_mode=epsilon_mode, output=sets)


def _describe_infeasible(ax: AxisTube, dt_s: float) -> str:
    wp, wv = ax.disturbance.half_widths
    d = ax.disturbance
    z_vel = max(ax.z.support(np.array([0.0, 1.0])), ax.z.support(np.array([0.0, -1.0])))
    return (
        f"controller.tube: the tightened constraints are empty on the {ax.name} axis. W per {dt_s:g} s control step "
        f"is position ±{wp:.4g} m, velocity ±{wv:.4g} m/s (mass term ±{d.mass_term[1]:.3g} m/s, force term "
        f"±{d.force_term[1]:.3g} m/s, noise ±{d.noise_bound[1]:.3g} m/s); its invariant tube needs up to "
        f"{ax.ancillary_force_N:.4g} N of ancillary force of the {ax.force_limit_N:g} N tube force limit (actuator "
        f"margin {ax.force_limit_N - ax.ancillary_force_N:+.4g} N) and {z_vel:.4g} m/s of the "
        f"{ax.velocity_limit_mps:g} m/s velocity limit (margin {ax.velocity_bounds_mps[1]:+.4g} m/s). Reduce the "
        "disturbance (controller.tube.disturbance), raise controller.tube.force_limit_N, or choose the explicit "
        "policy controller.tube.disturbance.on_empty_tightening: scale_w"
    )


def design_translation_tube(
    *,
    model: RobotModel,
    dt_s: float,
    force_limit_N: np.ndarray,
    velocity_limit_mps: np.ndarray,
    weights: AncillaryWeights,
    spec: DisturbanceSpec,
    epsilon: float,
    epsilon_mode: EpsilonMode = "relative",
    max_terms: int = 1000,
    facet_growth: float = DEFAULT_FACET_GROWTH,
    on_empty: str = "error",
    min_nominal_fraction: float = 0.1,
    observer: ObserverSpec | None = None,
) -> TubeDesign:
    """Design the three axis tubes (see the module docstring).

    Parameters
    ----------
    model : RobotModel
        The controller's model: m₀ of the double integrator and, from its covariance, σ_m of W's mass term
        ([Doerr2021] Eq. 28, ``spec.n_sigma`` σ).
    dt_s : float
        Control period (the step of the ancillary law and of W) [s].
    force_limit_N, velocity_limit_mps : ndarray, shape (3,)
        U and X per world axis.
    weights : AncillaryWeights
    spec : DisturbanceSpec
    epsilon : float
        Accuracy of Z: relative, ``F_∞ ⊆ Z ⊆ (1 + ε) F_∞`` for the set in use [-], or Raković et al. 2005's
        absolute ε of ``F(α, s) ⊆ F_∞ ⊕ B_∞(ε)`` [m, m/s], by ``epsilon_mode``.
    epsilon_mode : {"relative", "absolute"}
    max_terms : int
        Largest number of terms s of ``F(α, s)`` (more needed: InfeasibleError naming
        ``controller.tube.rpi_max_terms``).
    facet_growth : float
        Allowed growth of Z by facet reduction (0: keep every facet of F(α, s)); with a relative ε it is the
        largest share of the bound the reduction gets (:func:`split_relative_epsilon`).
    on_empty : {"error", "scale_w"}
        What to do when a tightened set loses the origin: refuse, or scale W of that axis down (explicit).
    min_nominal_fraction : float
        With ``"scale_w"``: fraction of each limit the nominal MPC keeps.
    observer : ObserverSpec, optional
        Output feedback ([Mayne2006], :mod:`oacli.sets.error_set`): the lasso is ``R = T ⊖ S``, the promise T.

    Returns
    -------
    TubeDesign
        The three axis tubes, the control period and the model.

    Raises
    ------
    InfeasibleError
        With W and the actuator margin when the tightening empties a set and the policy is ``"error"``; also from
        :func:`oacli.sets.minimal_rpi_outer` (unstable A_K, too many terms).
    """
    if on_empty not in ("error", "scale_w"):
        raise ValueError(f"on_empty must be 'error' or 'scale_w', got {on_empty!r}")
    common = {"model": model, "dt_s": dt_s, "weights": weights, "spec": spec, "epsilon": epsilon,
              "epsilon_mode": epsilon_mode, "max_terms": max_terms, "facet_growth": facet_growth,
              "observer": observer}
    axes = []
    for i in range(3):
        limits = {"force_limit_N": float(force_limit_N[i]), "velocity_limit_mps": float(velocity_limit_mps[i])}
        ax = design_axis(i, **common, **limits)  # type: ignore[arg-type]
        if not ax.feasible:
            if on_empty == "error":
                raise InfeasibleError(_describe_infeasible(ax, dt_s))
            ax = _scaled_axis(i, common, limits, min_nominal_fraction)
        axes.append(ax)
    return TubeDesign(axes=tuple(axes), dt_s=float(dt_s), model=model)  # type: ignore[arg-type]


def _keeps_fraction(ax: AxisTube, fraction: float) -> bool:
    (ulo, uhi), (vlo, vhi) = ax.force_bounds_N, ax.velocity_bounds_mps
    f, v = fraction * ax.force_limit_N, fraction * ax.velocity_limit_mps
    return ulo <= -f and uhi >= f and vlo <= -v and vhi >= v


def _scaled_axis(i: int, common: dict[str, Any], limits: dict[str, Any], fraction: float) -> AxisTube:
    """Largest W scale (bisection, 1e-3 resolution) for which the axis keeps ``fraction`` of its limits."""
    lo, hi = 0.0, 1.0
    best = None
    while hi - lo > 1e-3:
        mid = 0.5 * (lo + hi)
        ax = design_axis(i, **common, **limits, w_scale=mid)
        if _keeps_fraction(ax, fraction):
            lo, best = mid, ax
        else:
            hi = mid
    if best is None:
        raise InfeasibleError(
            f"controller.tube: even W scaled to {lo:.1e} of its size leaves less than {fraction:g} of the "
            f"{AXIS_NAMES[i]}-axis limits to the nominal MPC"
        )
    return best
