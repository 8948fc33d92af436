"""The sequential estimator behind the RATTLE loop's ``update(t, x_measured, u_since_last)`` protocol."""

from __future__ import annotations

import numpy as np

from oacli.estimation.online import OnlineSequentialEstimator
from oacli.estimation.sequential import SequentialEstimator
from oacli.excitation.oracle import OnlineEstimator
from tests.estimation_helpers import RATTLE_PRIOR, THETA_TRUE, records, settings, simulate_open_loop


def test_online_adapter_gives_the_filter_the_records_it_would_get_offline():
    """Fed as the RATTLE loop feeds it (input held since the previous measurement), the adapter hands the filter
    exactly the records built from the telemetry (input applied from each time stamp), one step later."""
    tel = simulate_open_loop(60, seed=3)
    offline = SequentialEstimator(settings(), RATTLE_PRIOR)
    recs = records(tel)
    for rec in recs[1:-1]:
        offline.update(rec)
    online = OnlineSequentialEstimator(SequentialEstimator(settings(), RATTLE_PRIOR))
    assert isinstance(online, OnlineEstimator)
    for k in range(1, len(tel.t_ctrl)):  # the loop's first call comes at its second control step
        est = online.update(float(tel.t_ctrl[k]), tel.x_measured[k], tel.u_applied[k - 1])
    np.testing.assert_allclose(est.theta, offline.estimate.theta, rtol=1e-12)
    np.testing.assert_allclose(est.covariance, offline.estimate.covariance, rtol=1e-10, atol=1e-18)
    assert est.samples_used == offline.estimate.samples_used
    # And the estimate is a real one: within 4σ of the truth, far tighter than the prior.
    assert np.all(np.abs(est.theta - THETA_TRUE) <= 4.0 * est.std)
    assert np.all(est.std < 0.2 * RATTLE_PRIOR.std)
