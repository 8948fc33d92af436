"""When the sequential filter's batch bootstrap may hand over ([Doerr2021] Eqs. 31-32; [ReSWARM2023] §4.4.1).

:class:`oacli.estimation.sequential.SequentialEstimator` starts as repeated batch solves of the records so far and
hands over to the filter once θ is known to ``bootstrap_relative_std``. A full solve at every check is costly;
:func:`handover_in_reach` answers first, for about a tenth of a solve's cost, whether a check can hand over at all.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from oacli.estimation.batch import BatchResult, covariance_at, estimate_batch, extend_states
from oacli.estimation.batch_model import FullModel, LegacyModel
from oacli.estimation.models import EstimatorSettings, Measurement
from oacli.estimation.preprocessing import order_by_time
from oacli.types import ParameterEstimate

HANDOVER_MARGIN = 1.15
"""Offline bootstrap checks are solved in full only when the covariance at the previous solution puts the largest
``std/|θ|`` within this factor of ``bootstrap_relative_std`` (its largest ``std/|θ|`` was 8 % below to 6.5 % above
the converged solve's on the default mission and two 12 s test runs)."""


def handover_in_reach(
    records: Sequence[Measurement], last_solve: BatchResult | None, settings: EstimatorSettings,
    prior: ParameterEstimate, relative_std: float, model: FullModel | None = None,
) -> bool:
    """Whether the covariance of the records so far may be within reach of the hand-over (offline checks).

    The batch covariance at a point it does not move (:func:`~oacli.estimation.batch.covariance_at`, no
    iteration): the last full solve's states and φ, the new records' states propagated by
    :func:`~oacli.estimation.batch.extend_states`; the prior mean and the measured states before the first full
    solve. Its largest ``std/|θ|`` is within 8 % of the converged solve's (default mission, two test runs), for
    about a tenth of its cost. A check whose largest ``std/|θ|`` exceeds :data:`HANDOVER_MARGIN` times
    ``relative_std`` cannot hand over and is not solved; any other is solved in full, so the hand-over record is
    the one a full solve at every check finds unless the approximation is off by more than that margin (the
    hand-over then comes a check later). A numerical failure or a singular covariance answers True: the check is
    solved as before.

    Parameters
    ----------
    records : sequence of Measurement
        The bootstrap's records so far.
    last_solve : BatchResult or None
        The last full bootstrap solve (None before the first).
    settings : EstimatorSettings
    prior : ParameterEstimate
        The filter's prior on θ.
    relative_std : float
        The hand-over threshold ``bootstrap_relative_std`` on ``std/|θ|`` [-] (on mass and inertia).
    model : FullModel, optional
        The full rigid body's chosen part (:mod:`oacli.estimation.batch_model`); default θ = [m, Ixx, Iyy, Izz].

    Returns
    -------
    bool
        False only when the check certainly cannot hand over.
    """
    try:
        recs = order_by_time(records).records
        pm: LegacyModel | FullModel = LegacyModel() if model is None else model
        if last_solve is not None and last_solve.states.shape[0] <= len(recs):
            phi = last_solve.phi
            states = extend_states(last_solve.states, recs, _theta_of(last_solve), settings.substep_s, model)
        else:
            phi = pm.phi(prior.theta if model is None else model.prior_mean)
            states = np.array([r.x_measured for r in recs])
        cov = covariance_at(recs, settings, prior, states, phi, prior.theta, model)[:4, :4]
    except (ValueError, ArithmeticError, np.linalg.LinAlgError):  # e.g. no measured record yet
        return True
    ratio = np.sqrt(np.diag(cov)) / (relative_std * np.abs(pm.theta4(phi)))
    return not bool(np.all(np.isfinite(ratio))) or float(np.max(ratio)) <= HANDOVER_MARGIN


def solve_bootstrap(
    records: Sequence[Measurement], last_solve: BatchResult | None, settings: EstimatorSettings,
    prior: ParameterEstimate, reference: bool = False, model: FullModel | None = None,
) -> BatchResult:
    """Batch-solve the bootstrap's records ([Doerr2021] Eqs. 31-32), warm-started at the last solve when there is one.

    The warm start takes the last solve's φ and its states, extended to the new records by
    :func:`~oacli.estimation.batch.extend_states`; a warm-started solve that does not converge is solved again from
    the same point without the warm start's reduced damping and continuation (as before the warm start existed).

    Parameters
    ----------
    records : sequence of Measurement
        The bootstrap's records so far.
    last_solve : BatchResult or None
        The last full bootstrap solve (None: a cold solve).
    settings : EstimatorSettings
    prior : ParameterEstimate
        The filter's prior on θ.
    reference : bool
        Solve on the batch's reference path (never warm-started).
    model : FullModel, optional
        The full rigid body's chosen part; default θ = [m, Ixx, Iyy, Izz].

    Returns
    -------
    BatchResult
    """
    init_phi, init_states = None, None
    if last_solve is not None:
        init_phi = last_solve.phi
        init_states = extend_states(last_solve.states, records, _theta_of(last_solve), settings.substep_s, model)
    warm = init_phi is not None and not reference
    result = estimate_batch(records, settings, prior, initial_phi=init_phi, initial_states=init_states,
                            warm_start=warm, reference=reference, model=model)
    if warm and not result.converged:  # the warm start did not pay off: solve as before
        result = estimate_batch(records, settings, prior, initial_phi=init_phi, initial_states=init_states,
                                model=model)
    return result


def _theta_of(result: BatchResult) -> np.ndarray:
    """The θ a solve's process model used: the full θ when it had one, else [m, Ixx, Iyy, Izz]."""
    return result.estimate.theta if result.theta_full is None else result.theta_full
