"""The Gaussian prior ``N(θ₀, P₀)`` on θ = [m, Ixx, Iyy, Izz]: one section type for ``excitation.prior`` and
``estimation.prior``.

The mean defaults to the robot model (``robot.mass_kg``, ``robot.inertia_kgm2``); ``P₀`` is diagonal, its
variances one list ``variance`` of four (the unit of ``robot.variance`` and ``mission.prior.variance``). The
defaults are RATTLE's: ``P₀ = diag(15, 0.005, 0.005, 0.005)`` ([RattleCode]
``param_est/scripts/param_est_config.py``; a covariance there: ``S = H P Hᵀ + R``), i.e. standard deviations of
3.9 kg and 0.071 kg·m².
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from oacli.config.fields import PositiveReal, PositiveVector4, PrincipalInertia, Section

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
    variance: PositiveVector4 = Field(
        default=RATTLE_PRIOR_VARIANCE,
        description="Prior variances of θ = [m, Ixx, Iyy, Izz] [kg², (kg·m²)² ×3], each > 0 (the diagonal of P₀; "
        "rattle P0: 15, 0.005, 0.005, 0.005, i.e. σ 3.9 kg and 0.071 kg·m²).",
    )

    @property
    def variances(self) -> tuple[float, float, float, float]:
        """diag(P₀) = [mass variance kg², inertia variances (kg·m²)² ×3]."""
        return self.variance  # type: ignore[return-value]

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
