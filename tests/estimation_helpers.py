"""Synthetic data for the estimator tests: the simulator driven open loop by an exciting input sequence."""

from __future__ import annotations

import math

import numpy as np

from oacli.estimation.models import EstimatorSettings, Measurement, MeasurementModel, ProcessNoise
from oacli.estimation.preprocessing import measurements_from_telemetry
from oacli.model import quaternion as quat
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.sim.simulator import simulate
from oacli.types import ControlStep, InertialParams, ParameterEstimate, SolveInfo, Telemetry

THETA_TRUE = np.array([15.0, 0.1464, 0.1376, 0.1604])  # [Doerr2021] Table 1: Astrobee with the printed object
# rattle param_est_config.py: params_init_6DOF_simplified and P_6DOF_simplified (a covariance: variances).
RATTLE_PRIOR = ParameterEstimate(0.0, [15.0, 0.1, 0.1, 0.1], np.diag([15.0, 0.005, 0.005, 0.005]), "prior")
# Position/attitude: the ISS preset's localisation noise; velocity/angular velocity: rattle's R (variances 5e-6,
# 2.5e-4).
MODEL = MeasurementModel(0.01, math.sqrt(5e-6), 0.005, math.sqrt(2.5e-4))
SENSORS = SensorNoise(0.01, math.sqrt(5e-6), 0.005, math.sqrt(2.5e-4))
CONTROL_PERIOD_S = 0.2
PLANT_PERIOD_S = 1.0 / 62.5


def settings(**changes) -> EstimatorSettings:
    base = {"measurement": MODEL, "process": ProcessNoise(1e-5, 1e-6), "substep_s": PLANT_PERIOD_S}
    base.update(changes)
    return EstimatorSettings(**base)


def exciting_inputs(n: int, seed: int = 7) -> np.ndarray:
    """A smooth multisine on every force and torque axis, |f| <= 0.2 N, |τ| <= 0.02 N·m, shape (n, 6)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * CONTROL_PERIOD_S
    u = np.zeros((n, 6))
    for axis in range(6):
        freqs = rng.uniform(0.02, 0.15, 3)
        phases = rng.uniform(0, 2 * np.pi, 3)
        u[:, axis] = sum(np.sin(2 * np.pi * f * t + p) for f, p in zip(freqs, phases, strict=True)) / 3.0
    return u * np.array([0.2, 0.2, 0.2, 0.02, 0.02, 0.02])


class Playback:
    """Open-loop controller that replays an input sequence (one row per control step)."""

    def __init__(self, u: np.ndarray) -> None:
        self.u = u
        self.k = 0

    def step(self, t: float, x_measured: np.ndarray) -> ControlStep:
        u = self.u[min(self.k, len(self.u) - 1)]
        self.k += 1
        return ControlStep(u=u, info=SolveInfo("playback", True), x_reference=x_measured)


def initial_state() -> np.ndarray:
    x0 = np.zeros(13)
    x0[0:3] = [10.8, -7.75, 5.2]
    x0[6:10] = quat.normalize(np.array([0.1, -0.2, -0.7, 0.7]))
    x0[10:13] = [0.01, -0.02, 0.015]
    return x0


def simulate_open_loop(
    n: int = 100, *, theta: np.ndarray = THETA_TRUE, sensors: SensorNoise = SENSORS, seed: int = 0,
    input_seed: int = 7,
) -> Telemetry:
    """``n`` control steps (0.2 s) of the simulator (62.5 Hz plant) driven by :func:`exciting_inputs`."""
    u = exciting_inputs(n, input_seed)
    return simulate(
        Playback(u), initial_state(), InertialParams(theta[0], theta[1:4]),
        duration_s=n * CONTROL_PERIOD_S, control_period_s=CONTROL_PERIOD_S, plant_period_s=PLANT_PERIOD_S,
        input_limits=np.full(6, 10.0), sensors=sensors, disturbance=Disturbance.none(),
        rng=np.random.default_rng(seed),
    )


def records(tel: Telemetry, **kwargs) -> list[Measurement]:
    return measurements_from_telemetry(tel, **kwargs)


class FeedbackPD:
    """Closed loop for the gap tests: a multisine feed-forward plus a PD law on the *measured* state (so the input
    depends on the measurement noise, as the MPC's does)."""

    def __init__(self, u: np.ndarray, x0: np.ndarray) -> None:
        self.u, self.x0, self.k = u, x0, 0

    def step(self, t: float, x_measured: np.ndarray) -> ControlStep:
        u = self.u[min(self.k, len(self.u) - 1)].copy()
        u[:3] -= 2.0 * (x_measured[0:3] - self.x0[0:3]) + 4.0 * x_measured[3:6]
        u[3:] -= 0.2 * x_measured[10:13]
        self.k += 1
        return ControlStep(u=u, info=SolveInfo("feedback", True), x_reference=x_measured)


def closed_loop_pd(seed: int, n: int) -> Telemetry:
    """``n`` control periods of :class:`FeedbackPD` around :func:`exciting_inputs` (its seed ``7 + seed``) flown by
    the simulator with the RATTLE-level sensors of :data:`SENSORS`, the noise drawn from ``seed``."""
    x0 = initial_state()
    return simulate(
        FeedbackPD(exciting_inputs(n, 7 + seed), x0), x0, InertialParams(THETA_TRUE[0], THETA_TRUE[1:4]),
        duration_s=n * CONTROL_PERIOD_S, control_period_s=CONTROL_PERIOD_S, plant_period_s=PLANT_PERIOD_S,
        input_limits=np.full(6, 10.0), sensors=SENSORS, disturbance=Disturbance.none(),
        rng=np.random.default_rng(seed),
    )


def dense_jacobian_matching_central_differences(problem, x: np.ndarray, phi: np.ndarray, inliers: np.ndarray,
                                                step: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Assert that the batch problem's Jacobian ``A = ∂b/∂δϑ`` (``BatchProblem.evaluate``) equals central differences
    of its residuals ``b`` in every column (states through ``⊞``, then the parameters φ); return ``(b, A)`` dense.

    ``x`` is (K, 13) states, ``phi`` the parameter vector, ``inliers`` a (K,) mask.
    """
    from oacli.estimation.manifold import boxplus

    b, a_mat = problem.evaluate(x, phi, inliers, jacobian=True)
    a_dense = a_mat.toarray()
    n_states = 12 * x.shape[0]
    for col in range(problem.n_var):
        d = np.zeros(problem.n_var)
        d[col] = step
        xp, pp = boxplus(x, d[:n_states].reshape(-1, 12)), phi + d[n_states:]
        xm, pm = boxplus(x, -d[:n_states].reshape(-1, 12)), phi - d[n_states:]
        fd = (problem.evaluate(xp, pp, inliers, False)[0] - problem.evaluate(xm, pm, inliers, False)[0]) / (2 * step)
        np.testing.assert_allclose(a_dense[:, col], fd, rtol=2e-5, atol=2e-5 * max(1.0, np.abs(fd).max()))
    assert b.shape[0] == a_dense.shape[0]
    return b, a_dense
