"""Convex sets of tube MPC: polytopes with support functions, and robust positively invariant sets."""

from oacli.sets.polytope import Polytope
from oacli.sets.rpi import (
    EpsilonMode,
    FacetReduction,
    RPIApproximation,
    RPITermsError,
    minimal_rpi_outer,
    minimal_rpi_support,
    reduce_facets,
    rpi_margins,
)

__all__ = [
    "EpsilonMode",
    "FacetReduction",
    "Polytope",
    "RPIApproximation",
    "RPITermsError",
    "minimal_rpi_outer",
    "minimal_rpi_support",
    "reduce_facets",
    "rpi_margins",
]
