"""Convex sets of tube MPC: polytopes with support functions, and robust positively invariant sets."""

from oacli.sets.polytope import Polytope
from oacli.sets.rpi import FacetReduction, RPIApproximation, minimal_rpi_outer, reduce_facets, rpi_margins

__all__ = ["FacetReduction", "Polytope", "RPIApproximation", "minimal_rpi_outer", "reduce_facets", "rpi_margins"]
