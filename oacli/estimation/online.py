"""The sequential estimator as an online planner consumes it (RATTLE closed loop, [ReSWARM2023] §4.4).

The RATTLE loop (:mod:`oacli.excitation.rattle_loop`) calls ``update(t_k, x_k, u_{k-1})`` at every control step:
the state measured at ``t_k`` and the input held *since the previous* measurement. The estimator's records
(:class:`oacli.estimation.models.Measurement`) carry the input applied *from* their time stamp on. This adapter
holds the latest measurement until the input that followed it is known, then hands the completed record to
:class:`oacli.estimation.sequential.SequentialEstimator`; the estimate therefore lags by one control period.
"""

from __future__ import annotations

import numpy as np

from oacli.estimation.models import Measurement
from oacli.estimation.sequential import SequentialEstimator
from oacli.types import ParameterEstimate


class OnlineSequentialEstimator:
    """:class:`SequentialEstimator` behind the ``update(t, x_measured, u_applied)`` protocol of the RATTLE loop.

    Parameters
    ----------
    estimator : SequentialEstimator
        The filter (with its settings and prior).
    """

    def __init__(self, estimator: SequentialEstimator) -> None:
        self.filter = estimator
        self._pending: tuple[float, np.ndarray] | None = None

    @property
    def estimate(self) -> ParameterEstimate:
        """The filter's current estimate (the prior before the second measurement)."""
        return self.filter.estimate

    def update(self, t: float, x_measured: np.ndarray, u_applied: np.ndarray) -> ParameterEstimate:
        """Fuse the previous measurement, now that the input held after it (``u_applied``) is known.

        Parameters
        ----------
        t : float
            Mission time [s] of the measurement.
        x_measured : ndarray, shape (13,)
            Measured state.
        u_applied : ndarray, shape (6,)
            Input held since the previous measurement.

        Returns
        -------
        ParameterEstimate
            The filter's estimate (lags one control period).
        """
        if self._pending is not None:
            t_prev, x_prev = self._pending
            self.filter.update(Measurement(t_prev, x_prev, np.asarray(u_applied, dtype=float)))
        self._pending = (float(t), np.array(x_measured, dtype=float))
        return self.filter.estimate
