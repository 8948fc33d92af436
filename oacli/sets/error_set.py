"""Sets of robust output-feedback tube MPC (Mayne, Raković, Findeisen & Allgöwer 2006) for a 2-D axis.

The plant ``x⁺ = A x + B u + w`` (``w ∈ W``) is measured as ``y = x + n`` (``n ∈ N``, the sensor noise bounded at
a configured number of σ). A filter-form Luenberger observer with gain L,

    x̂_k = x̂_k⁻ + L (y_k − x̂_k⁻),   x̂_{k+1}⁻ = A x̂_k + B u_k,

has the estimation error ``ε = x − x̂`` with ``ε⁺ = (I − L) A ε + (I − L) w − L n⁺`` ([Mayne2006] Eq. 8, in the
filter form): its robust positively invariant set ``S`` (the *error set*) bounds it for every admissible noise and
disturbance sequence once ``ε_0 ∈ S``.

The ancillary law acts on the estimate, ``u = v + K (x̂ − z)``. The true deviation from the nominal,
``ξ = x − z``, then obeys ``ξ⁺ = A_K ξ − B K ε + w``: the noise reaches the true state only through the
feedback on the estimation error. Its RPI set ``T`` for the disturbance ``(−B K) S ⊕ W`` is the tube the
controller promises for the *true* state, ``x ∈ z ⊕ T``. Mayne et al.'s decomposition bounds ``ξ`` by
``R̄ ⊕ S`` with ``R̄`` the RPI set of the estimate's deviation ``x̂ − z`` under the innovation ``L(A ε + w + n⁺)``;
for a double integrator measured with centimetre noise that set is several times larger (the estimate's jumps are
inconsistent with the dynamics), which is why ``T`` is used. The QP constrains what it knows, the estimate:
``x̂ − z_0 ∈ R = T ⊖ S``, so that ``x − z_0 = (x̂ − z_0) + ε ∈ R ⊕ S ⊆ T``, and ``T``'s invariance carries the
bound to every later instant. Constraints on the state are tightened by ``T``, the input by ``K R``.

:func:`output_feedback_sets` builds S, T and R with Raković et al. 2005's outer approximation and the verified facet
reduction of :mod:`oacli.sets.rpi`, and checks each invariance (margins ≥ 0) and ``R ⊕ S ⊆ T``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from oacli.errors import InfeasibleError
from oacli.sets.polytope import Polytope
from oacli.sets.rpi import EpsilonMode, FacetReduction, RPIApproximation, minimal_rpi_outer, reduce_facets, rpi_margins

#: Directions (unit vectors, evenly spaced) of the outer polygon that bounds ``(−B K) S ⊕ W`` (fewer facets for the
#: RPI series; a superset, so every bound derived from it stays valid).
_OUTER_DIRECTIONS = 16


@dataclass(frozen=True)
class OutputFeedbackSets:
    """The sets of one axis (module docstring); all 2-D ``[position m, velocity m/s]``.

    Attributes
    ----------
    observer_gain : ndarray, shape (2, 2)
        L.
    a_error : ndarray, shape (2, 2)
        ``(I − L) A``.
    noise : Polytope
        N, the sensor-noise bound.
    w_error : Polytope
        ``(I − L) W ⊕ (−L) N``: the disturbance of the estimation error.
    error_rpi : RPIApproximation
        ``F(α, s)`` of the estimation error.
    error : FacetReduction
        S in use (``error.z``), verified RPI.
    w_true : Polytope
        ``(−B K) S ⊕ W`` (outer polygon): the disturbance of the true deviation.
    true_rpi : RPIApproximation
    true : FacetReduction
        T in use (``true.z``), verified RPI.
    lasso : Polytope
        ``R = T ⊖ S``.
    """

    observer_gain: np.ndarray
    a_error: np.ndarray
    noise: Polytope
    w_error: Polytope
    error_rpi: RPIApproximation
    error: FacetReduction
    w_true: Polytope
    true_rpi: RPIApproximation
    true: FacetReduction
    lasso: Polytope

    @property
    def s(self) -> Polytope:
        """The estimation-error set S."""
        return self.error.z

    @property
    def t(self) -> Polytope:
        """The true-deviation tube T."""
        return self.true.z

    def extents(self) -> dict[str, tuple[float, float]]:
        """Half-widths ``(position m, velocity m/s)`` of S, T and R (largest over ±e).

        Returns
        -------
        dict of str to (float, float)
            ``"error"`` (S), ``"true"`` (T), ``"lasso"`` (R): position [m] and velocity [m/s] half-widths.
        """
        e = np.vstack([np.eye(2), -np.eye(2)])
        out = {}
        for name, p in (("error", self.s), ("true", self.t), ("lasso", self.lasso)):
            h = np.asarray(p.support(e))
            out[name] = (float(max(h[0], h[2])), float(max(h[1], h[3])))
        return out


def _outer_polygon(p: Polytope, n: int = _OUTER_DIRECTIONS) -> Polytope:
    """A polygon containing ``p`` with ``n`` facets along evenly spaced directions (offsets: p's support)."""
    angle = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    dirs = np.column_stack([np.cos(angle), np.sin(angle)])
    return Polytope(dirs, np.asarray(p.support(dirs), dtype=float))


def _rpi(a: np.ndarray, w: Polytope, epsilon: float, mode: EpsilonMode, max_terms: int,
         growth: float) -> tuple[RPIApproximation, FacetReduction]:
    rpi = minimal_rpi_outer(a, w, epsilon, mode=mode, max_terms=max_terms)
    return rpi, reduce_facets(a, rpi.z, w, growth)


def output_feedback_sets(
    a: np.ndarray,
    b: np.ndarray,
    gain: np.ndarray,
    observer_gain: np.ndarray,
    w: Polytope,
    noise: Polytope,
    *,
    epsilon: float,
    epsilon_mode: EpsilonMode = "relative",
    max_terms: int = 1000,
    facet_growth: float = 0.02,
) -> OutputFeedbackSets:
    """S, T and R of one axis (module docstring), each invariance verified.

    Parameters
    ----------
    a, b : ndarray, shapes (2, 2), (2, 1)
        Model over one control step.
    gain : ndarray, shape (1, 2)
        Ancillary gain K.
    observer_gain : ndarray, shape (2, 2)
        L of the filter-form observer (``(I − L) A`` Schur stable).
    w : Polytope
        Process disturbance W per step.
    noise : Polytope
        Sensor-noise bound N (contains the origin).
    epsilon, epsilon_mode, max_terms, facet_growth
        Accuracy of both RPI approximations and the facet reduction (:func:`oacli.sets.minimal_rpi_outer`,
        :func:`oacli.sets.reduce_facets`).

    Returns
    -------
    OutputFeedbackSets

    Raises
    ------
    InfeasibleError
        An invariance check fails, or ``T ⊖ S`` is empty (the feedback cannot keep the true state within the
        error set's reach), or from :func:`oacli.sets.minimal_rpi_outer`.
    """
    a = np.asarray(a, dtype=float)
    ell = np.asarray(observer_gain, dtype=float).reshape(2, 2)
    eye = np.eye(2)
    a_err = (eye - ell) @ a
    w_err = w.linear_map(eye - ell).minkowski_sum(noise.linear_map(-ell))
    err_rpi, err = _rpi(a_err, w_err, epsilon, epsilon_mode, max_terms, facet_growth)
    s = err.z
    bk = np.asarray(b, dtype=float) @ np.asarray(gain, dtype=float).reshape(1, 2)
    a_k = a + bk
    w_true = _outer_polygon(s.linear_map(-bk).minkowski_sum(w))
    true_rpi, true = _rpi(a_k, w_true, epsilon, epsilon_mode, max_terms, facet_growth)
    t = true.z
    for name, margin in (("estimation-error set S", rpi_margins(a_err, s, w_err)),
                         ("true-state tube T", rpi_margins(a_k, t, w_true))):
        if float(np.min(margin)) < -1e-12 * float(np.max(np.abs(margin))):
            raise InfeasibleError(f"the {name} is not robust positively invariant (margin {np.min(margin):.3g})")
    lasso = t.pontryagin_difference(s)
    if lasso.is_empty() or not np.all(lasso.b > 0):
        raise InfeasibleError(
            "controller.tube.observer: the true-state tube T does not contain the estimation-error set S with room "
            f"to spare (T ⊖ S has no interior: S ±{s.support(np.array([1.0, 0.0])):.3g} m, T "
            f"±{t.support(np.array([1.0, 0.0])):.3g} m); choose a faster observer or a slower ancillary gain"
        )
    if not t.contains(lasso.minkowski_sum(s), tol=1e-9 * float(np.max(t.b))):
        raise InfeasibleError("the output-feedback tube fails R ⊕ S ⊆ T")
    return OutputFeedbackSets(ell, a_err, noise, w_err, err_rpi, err, w_true, true_rpi, true, lasso)


def output_feedback_summary(outs: list[OutputFeedbackSets]) -> dict[str, Any]:
    """Sizes of the output-feedback sets ([Mayne2006]) per axis: S, T, R half-widths, L, the noise bound.

    Parameters
    ----------
    outs : list of OutputFeedbackSets
        One per translational axis.

    Returns
    -------
    dict
        ``observer_gain``, the noise bounds [m, m/s], the half-widths of S (``error_set_*``), T (``true_tube_*``)
        and R (``lasso_*``) per axis [m, m/s], the error set's facets and Minkowski terms, and whether S covers
        the initial error (the noise box).
    """
    ext = [o.extents() for o in outs]
    noise = [[float(o.noise.support(np.array([1.0, 0.0]))), float(o.noise.support(np.array([0.0, 1.0])))] for o in outs]
    return {
        "observer_gain": outs[0].observer_gain.tolist(),
        "noise_bound_position_m": [n[0] for n in noise], "noise_bound_velocity_mps": [n[1] for n in noise],
        **{f"{name}_{unit}": [e[key][j] for e in ext]
           for key, name in (("error", "error_set"), ("true", "true_tube"), ("lasso", "lasso"))
           for j, unit in ((0, "position_m"), (1, "velocity_mps"))},
        "error_set_facets": [o.error.facets_after for o in outs],
        "error_set_terms": [o.error_rpi.s for o in outs],
        "initial_error_covered": [bool(o.s.contains(o.noise)) for o in outs],
    }
