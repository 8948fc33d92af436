"""Inertial parameter estimation ([Doerr2021] Eqs. 31-32; [ReSWARM2023] §4.4.1, §6.2.1).

* :func:`estimate_batch` -- batch maximum likelihood over all states and θ (sparse Gauss-Newton/LM on the manifold);
* :class:`SequentialEstimator` -- error-state EKF with θ as states, χ² gating, time-stamp reordering;
  ``update(Measurement) -> ParameterEstimate`` for online consumers (the RATTLE planner);
* :func:`cramer_rao_bound` -- the bound both are compared with;
* :class:`Measurement`, :class:`EstimatorSettings`, :class:`ProcessNoise` and information.py's
  :class:`MeasurementModel` -- the records and noise models they share.
"""

from oacli.estimation.batch import BatchResult, estimate_batch, estimate_batch_windows
from oacli.estimation.bounds import CramerRaoBound, cramer_rao_bound, unobservable_parameters
from oacli.estimation.models import EstimatorSettings, Measurement, MeasurementModel, ProcessNoise
from oacli.estimation.preprocessing import ReorderBuffer, measurements_from_telemetry, order_by_time
from oacli.estimation.sequential import SequentialEstimator, SequentialStep

__all__ = [
    "BatchResult",
    "CramerRaoBound",
    "EstimatorSettings",
    "Measurement",
    "MeasurementModel",
    "ProcessNoise",
    "ReorderBuffer",
    "SequentialEstimator",
    "SequentialStep",
    "cramer_rao_bound",
    "estimate_batch",
    "estimate_batch_windows",
    "measurements_from_telemetry",
    "order_by_time",
    "unobservable_parameters",
]
