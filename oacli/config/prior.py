"""The Gaussian prior ``N(θ₀, P₀)`` on θ = [m, Ixx, Iyy, Izz]: one section type for ``excitation.prior`` and
``estimation.prior``.

The mean defaults to the robot model (``robot.mass_kg``, ``robot.inertia_kgm2``); ``P₀`` is diagonal. Its variances
are written either as ``mass_variance_kg2`` and ``inertia_variance_kg2m4`` or as one list ``variance`` of four
(the two spellings the presets use; one of them per section). The defaults are RATTLE's: ``P₀ = diag(15, 0.005,
0.005, 0.005)`` ([RattleCode] ``param_est/scripts/param_est_config.py``; a covariance there: ``S = H P Hᵀ + R``),
i.e. standard deviations of 3.9 kg and 0.071 kg·m².
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator
from pydantic_core import PydanticCustomError

from oacli.config.fields import PositiveReal, PositiveVector3, PositiveVector4, PrincipalInertia, Section

RATTLE_PRIOR_THETA = (15.0, 0.1, 0.1, 0.1)
"""rattle ``params_init_6DOF_simplified``: [m kg, Ixx, Iyy, Izz kg·m²]."""
RATTLE_PRIOR_VARIANCE = (15.0, 0.005, 0.005, 0.005)
"""rattle ``vec_cov_6DOF_simplified`` (diagonal of the initial covariance P): [kg², (kg·m²)² ×3]."""


class PriorConfig(Section):
    """Gaussian prior ``N(θ₀, P₀)`` on θ = [m, Ixx, Iyy, Izz]; a missing mean is taken from ``robot``."""

    mass_kg: PositiveReal | None = Field(
        default=None, description="Prior mean of the mass [kg], > 0 (default: robot.mass_kg, the model as prior)."
    )
    inertia_kgm2: PrincipalInertia | None = Field(
        default=None,
        description="Prior mean of the principal inertias [kg·m²] (default: robot.inertia_kgm2); triangle "
        "inequalities must hold.",
    )
    mass_variance_kg2: PositiveReal = Field(
        default=RATTLE_PRIOR_VARIANCE[0],
        description="Prior variance of the mass [kg²], > 0 (rattle P0: 15, i.e. a standard deviation of 3.9 kg).",
    )
    inertia_variance_kg2m4: PositiveVector3 = Field(
        default=RATTLE_PRIOR_VARIANCE[1:],
        description="Prior variances of Ixx, Iyy, Izz [(kg·m²)²], > 0 (rattle P0: 0.005 each, std 0.071 kg·m²).",
    )
    variance: PositiveVector4 | None = Field(
        default=None,
        exclude=True,
        description="The four variances [kg², (kg·m²)² ×3] in one list, another spelling of mass_variance_kg2 and "
        "inertia_variance_kg2m4 (give one or the other); written back as those two.",
    )

    @model_validator(mode="after")
    def _one_spelling(self) -> PriorConfig:
        if self.variance is None:
            return self
        both = {"mass_variance_kg2", "inertia_variance_kg2m4"} & self.model_fields_set
        if both:
            raise PydanticCustomError(
                "oacli_prior_variance",
                "give the variances either as variance or as mass_variance_kg2 / inertia_variance_kg2m4, not both "
                "(both: variance and {names})",
                {"names": ", ".join(sorted(both))},
            )
        object.__setattr__(self, "mass_variance_kg2", self.variance[0])
        object.__setattr__(self, "inertia_variance_kg2m4", tuple(self.variance[1:]))
        object.__setattr__(self, "variance", None)
        return self

    @property
    def variances(self) -> tuple[float, float, float, float]:
        """diag(P₀) = [mass variance kg², inertia variances (kg·m²)² ×3]."""
        return (self.mass_variance_kg2, *self.inertia_variance_kg2m4)  # type: ignore[return-value]

    def theta(self, robot_theta: np.ndarray) -> np.ndarray:
        """θ₀ [kg, kg·m² ×3]: the configured mean, missing entries from the robot model ``robot_theta``.

        Parameters
        ----------
        robot_theta : ndarray, shape (4,)
            The robot model's θ.

        Returns
        -------
        ndarray, shape (4,)
        """
        out = np.array(robot_theta, dtype=float)
        if self.mass_kg is not None:
            out[0] = self.mass_kg
        if self.inertia_kgm2 is not None:
            out[1:4] = self.inertia_kgm2
        return out

    def covariance(self) -> np.ndarray:
        """P₀ = diag(mass variance, inertia variances) [kg², (kg·m²)²], shape (4, 4)."""
        return np.diag(np.array(self.variances, dtype=float))


__all__ = ["RATTLE_PRIOR_THETA", "RATTLE_PRIOR_VARIANCE", "PriorConfig"]
