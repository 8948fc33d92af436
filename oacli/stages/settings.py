"""From the config to the algorithm core's settings: one adapter per core object, shared by every stage.

A stage runner reads the config's sections only through these functions (plus ``cfg.scene()``,
``cfg.robot_params()`` and ``cfg.truth_params()``), so a new stage (mission, campaign) builds its core objects
here, runs them and writes its records (:mod:`oacli.io`): a short file.

The robot
---------
:func:`robot_model` is the controller's and the planner's model (``robot:``, with its ``variance``),
:func:`truth_model` the simulated plant (``truth:``, θ known exactly); both are
:class:`oacli.model.robot_model.RobotModel`. The excitation design's and the estimators' priors are the robot model
with ``excitation.prior`` or ``estimation.prior`` applied (:func:`excitation_prior_model`,
:func:`estimation_prior_model`).

Sections: the run folder; the robot and the simulated plant; the planners and the smoother; the excitation
design; the estimators; the robust tube. The design limits of ``plan``, ``smooth`` and ``excite``:
:mod:`oacli.stages.design_limits`.
"""

from __future__ import annotations

import contextlib
from dataclasses import replace
from pathlib import Path

import numpy as np

from oacli.config import OacliConfig, dump_config
from oacli.config.prior import PriorConfig
from oacli.control.disturbance import DisturbanceSpec
from oacli.control.observer import observer_spec
from oacli.control.tracking import TrackingWeights
from oacli.control.tube_design import AncillaryWeights, TubeDesign, design_translation_tube
from oacli.estimation.models import EstimatorSettings, ProcessNoise
from oacli.estimation.models import MeasurementModel as EstimationMeasurementModel
from oacli.excitation.design import ScpSettings
from oacli.excitation.information import MeasurementModel
from oacli.excitation.information_full import FullInformationTerm
from oacli.excitation.problem import TerminalTolerance
from oacli.excitation.rattle import InformationWeighting, PlannerWeights
from oacli.excitation.rattle_full import full_weighting
from oacli.geometry.collision import RobotBody
from oacli.io.runfolder import StageRun, open_stage_run
from oacli.model import quaternion as quat
from oacli.model.limits import MotionLimits
from oacli.model.rigid_body import theta_of
from oacli.model.robot_model import RobotModel
from oacli.planning.kino_rrt import KinoRrtSettings
from oacli.planning.lqr_rrt_star import LqrRrtStarSettings
from oacli.planning.polish import PolishSettings
from oacli.planning.steering import LqrConnector
from oacli.planning.translational import CostWeights
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.types import ParameterEstimate

# ----------------------------------------------------------------------------------------------------------------
# The run folder
# ----------------------------------------------------------------------------------------------------------------


def open_run(stage: str, cfg: OacliConfig, *, out: Path | None, runs_root: Path,
             started: float | None = None) -> contextlib.AbstractContextManager[StageRun]:
    """The stage's run folder (:func:`oacli.io.runfolder.open_stage_run`) for ``cfg``: its resolved YAML written
    first, its seed, name and world frame in the MCAP's metadata.

    Parameters
    ----------
    stage : str
        Stage name.
    cfg : OacliConfig
        Resolved configuration, as it ran (overrides applied).
    out, runs_root : Path
        The folder (see :func:`oacli.io.runfolder.create_run_dir`).
    started : float, optional
        ``time.perf_counter()`` when the stage began.

    Returns
    -------
    context manager of StageRun
    """
    return open_stage_run(stage, cfg.name, dump_config(cfg), seed=cfg.seed, frame=cfg.environment.frame, out=out,
                          runs_root=runs_root, started=started)


# ----------------------------------------------------------------------------------------------------------------
# The robot and the simulated plant
# ----------------------------------------------------------------------------------------------------------------

def robot_model(cfg: OacliConfig) -> RobotModel:
    """The controller's and the planner's model of the robot: ``robot:`` (θ, its variances, limits, radius).

    ``robot.model()``: θ = ``[robot.mass_kg, *robot.inertia_kgm2]``, covariance ``diag(robot.variance)``, so
    ``sqrt(covariance[0, 0])`` is the σ_m of the tube's W and of the planner's design limits ([Doerr2021] Eq. 28).
    The estimators' and the excitation design's priors are this model with their section's prior applied
    (:func:`estimation_prior_model`, :func:`excitation_prior_model`).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    RobotModel
    """
    return cfg.robot.model()


def truth_model(cfg: OacliConfig) -> RobotModel:
    """The simulated plant: ``truth:`` (missing values from ``robot:``), θ known exactly (zero covariance).

    Limits and radius are the robot's (the plant has the same actuators).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    RobotModel
    """
    return robot_model(cfg).with_estimate(theta_of(cfg.truth_params()), np.zeros((4, 4)))


def controller_limits(cfg: OacliConfig, model: RobotModel) -> MotionLimits:
    """The limits the tracking controllers constrain: ``model``'s, the angular rate lowered by
    ``controller.rate_margin`` (room for the overshoot of a plant whose inertia differs from the model's).

    The plant's saturation and the safety check keep the robot's own limits.

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.
    model : RobotModel
        The controller's model.

    Returns
    -------
    MotionLimits
    """
    lim = model.limits
    keep = 1.0 - cfg.controller.rate_margin
    return MotionLimits(lim.force_N, lim.torque_Nm, lim.velocity_mps, lim.angular_velocity_radps * keep)


def tracking_weights(cfg: OacliConfig) -> TrackingWeights:
    """The tracking controllers' weights (``controller.weights``).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    TrackingWeights
    """
    w = cfg.controller.weights
    return TrackingWeights(*(np.asarray(getattr(w, f)) for f in
                             ("position", "velocity", "attitude", "angular_velocity", "force", "torque")))


def sensor_noise(cfg: OacliConfig) -> SensorNoise:
    """The simulated sensors' noise (``sensors``).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    SensorNoise
    """
    s = cfg.sensors
    return SensorNoise(s.position_std_m, s.velocity_std_mps, s.attitude_std_rad, s.angular_velocity_std_radps)


def plant_disturbance(cfg: OacliConfig) -> Disturbance:
    """The force and torque disturbance acting on the simulated plant (``truth.disturbance``).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    Disturbance
    """
    dist = cfg.truth.disturbance
    return Disturbance(dist.bias, dist.random_bound)


# ----------------------------------------------------------------------------------------------------------------
# Planners and smoother (planner)
# ----------------------------------------------------------------------------------------------------------------


def robot_body(cfg: OacliConfig, q_start: np.ndarray, q_goal: np.ndarray) -> RobotBody:
    """The robot's bounding ellipsoid for collision checks (``planner.robot_semi_axes_m``).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.
    q_start, q_goal : ndarray, shape (4,)
        Attitudes at both ends ``[x, y, z, w]``: the ellipsoid is used only when they agree (the body does not
        turn), else its bounding sphere.

    Returns
    -------
    RobotBody
        A sphere of ``robot.radius_m`` when no semi-axes are given.
    """
    axes = cfg.planner.robot_semi_axes_m
    if axes is None:
        return RobotBody.sphere(robot_model(cfg).radius_m)
    if float(quat.angle_between(np.asarray(q_start), np.asarray(q_goal))) < 1e-9:
        return RobotBody.ellipsoid(np.asarray(axes), quat.to_rotation_matrix(np.asarray(q_start)))
    return RobotBody.sphere(float(max(axes)))


def cost_weights(cfg: OacliConfig) -> CostWeights:
    """The planners' LQR cost weights (``planner.weights``).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    CostWeights
    """
    w = cfg.planner.weights
    return CostWeights(w.position, w.velocity, w.force, w.time)  # type: ignore[arg-type]


def lqr_rrt_star_settings(cfg: OacliConfig) -> LqrRrtStarSettings:
    """LQR-RRT*'s settings (``planner``).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    LqrRrtStarSettings
    """
    p = cfg.planner
    return LqrRrtStarSettings(
        dt_s=p.steer_dt_s, metric_steps=p.steps(p.steer_horizon_s), max_steps=p.steps(p.max_connection_s),
        max_iterations=p.max_iterations, time_budget_s=p.time_budget_s, anytime=p.anytime,
        goal_bias=p.goal_bias, gamma=p.near_gamma, max_near=p.max_near,
    )


def kino_rrt_settings(cfg: OacliConfig) -> KinoRrtSettings:
    """The kinodynamic RRT's settings (``planner`` and ``planner.kino``).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    KinoRrtSettings
    """
    p = cfg.planner
    k = p.kino
    return KinoRrtSettings(
        primitive_fraction=k.primitive_fraction, primitive_dt_s=k.primitive_dt_s, primitive_set=k.primitive_set,
        position_weight=k.position_weight, velocity_weight=k.velocity_weight,
        goal_tolerance_m=p.goal_tolerance_m, goal_tolerance_mps=p.goal_tolerance_mps, dt_s=p.steer_dt_s,
        max_link_steps=p.steps(p.max_connection_s), max_iterations=p.max_iterations,
        time_budget_s=p.time_budget_s, goal_bias=k.goal_bias,
    )


def shortcut_connector(cfg: OacliConfig) -> LqrConnector:
    """The LQR steering of the shortcutting (``planner.weights``, ``planner.shortcut.max_horizon_s``).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    LqrConnector
    """
    p = cfg.planner
    return LqrConnector(robot_model(cfg), p.steer_dt_s, cost_weights(cfg), p.steps(p.shortcut.max_horizon_s))


def polish_settings(cfg: OacliConfig) -> PolishSettings:
    """The path-length polish's settings (``planner.polish``).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    PolishSettings
    """
    p = cfg.planner.polish
    return PolishSettings(iterations=p.iterations, step_s=p.step_s, effort_weight=p.effort_weight,
                          trust_radius_m=p.trust_radius_m, clearance_m=p.clearance_m)


# ----------------------------------------------------------------------------------------------------------------
# Excitation (excitation)
# ----------------------------------------------------------------------------------------------------------------


def measurement_model(cfg: OacliConfig) -> MeasurementModel:
    """The Fisher information's measurement model (``excitation.measurement``).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    oacli.excitation.information.MeasurementModel
    """
    return MeasurementModel(**cfg.excitation.measurement.model_dump())


def _model_with_prior(cfg: OacliConfig, prior: PriorConfig) -> RobotModel:
    """:func:`robot_model` with ``prior``'s mean (where given) and covariance."""
    model = robot_model(cfg)
    return model.with_estimate(prior.theta(model.theta), prior.covariance())


def excitation_prior_model(cfg: OacliConfig) -> RobotModel:
    """The excitation design's model: :func:`robot_model` with ``excitation.prior``'s mean (where given) and
    covariance.

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    RobotModel
    """
    return _model_with_prior(cfg, cfg.excitation.prior)


def terminal_tolerance(cfg: OacliConfig) -> TerminalTolerance:
    """How close to the goal at rest an excitation must end (``excitation.terminal_tolerance``).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    TerminalTolerance
    """
    tol = cfg.excitation.terminal_tolerance
    return TerminalTolerance(tol.position_m, tol.velocity_mps, tol.attitude_rad, tol.angular_velocity_radps)


def scp_settings(cfg: OacliConfig) -> ScpSettings:
    """The offline design's sequential convex programming settings (``excitation.scp``).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    ScpSettings
    """
    s = cfg.excitation.scp
    return ScpSettings(
        max_iterations=s.max_iterations,
        trust_region_initial=s.trust_region_initial,
        trust_region_min=s.trust_region_min,
        trust_region_max=s.trust_region_max,
        penalty=s.penalty,
        tolerance=s.tolerance,
        starts=s.starts,
        screening_iterations=s.screening_iterations,
    )


def rattle_planner_weights(cfg: OacliConfig) -> PlannerWeights:
    """The RATTLE planner's cost weights (``excitation.rattle.weights``).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    PlannerWeights
    """
    w = cfg.excitation.rattle.weights
    return PlannerWeights(w.position, w.velocity, w.attitude, w.angular_velocity, w.force, w.torque, w.terminal)


def information_weighting(cfg: OacliConfig) -> InformationWeighting:
    """RATTLE's information weights γ and their decay rule (``excitation.rattle``).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    InformationWeighting
    """
    r = cfg.excitation.rattle
    base = InformationWeighting(np.array(r.gamma0), np.array(r.floor), r.alpha, r.beta)
    info = cfg.excitation.information
    if info.is_legacy:
        return base
    g0 = {"products": info.products_gamma0, "com": info.com_gamma0, "force_scale": info.scale_gamma0,
          "torque_scale": info.scale_gamma0}
    floor = {"products": info.products_floor_kgm2, "com": info.com_floor_m, "force_scale": info.scale_floor,
             "torque_scale": info.scale_floor}
    return full_weighting(base, tuple(info.parameters), g0, floor)


def excitation_prior_std_full(cfg: OacliConfig) -> np.ndarray:
    """Prior σ of the full θ (16): ``excitation.prior``'s for [m, I], ``estimation.rigid_body``'s for the rest.

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    ndarray, shape (16,)
    """
    return np.r_[np.sqrt(np.array(cfg.excitation.prior.variances, dtype=float)), cfg.estimation.rigid_body.std()]


def full_information_term(cfg: OacliConfig, input_scale: np.ndarray) -> FullInformationTerm | None:
    """RATTLE's information term over ``excitation.information.parameters``; None for mass and inertia only.

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.
    input_scale : ndarray, shape (6,)
        The planner's input limits [N, N·m] (difference steps of the information gradient).

    Returns
    -------
    FullInformationTerm or None
    """
    info = cfg.excitation.information
    if info.is_legacy:
        return None
    return FullInformationTerm(tuple(info.parameters), cfg.estimation.rigid_body.mean(),
                               excitation_prior_std_full(cfg), np.asarray(input_scale, dtype=float))


# ----------------------------------------------------------------------------------------------------------------
# Estimation (estimation)
# ----------------------------------------------------------------------------------------------------------------


def estimator_settings(cfg: OacliConfig) -> EstimatorSettings:
    """The batch and sequential estimators' settings (``estimation``).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    EstimatorSettings
        Measurement and process noise, integration step (default: the plant period), gate and iterations.
    """
    est = cfg.estimation
    noise = est.measurement_noise
    return EstimatorSettings(
        measurement=EstimationMeasurementModel(
            position_std_m=noise.position_std_m,
            velocity_std_mps=noise.velocity_std_mps,
            attitude_std_rad=noise.attitude_std_rad,
            angular_velocity_std_radps=noise.angular_velocity_std_radps,
            linear_acceleration_std_mps2=noise.linear_acceleration_std_mps2,
        ),
        process=ProcessNoise(est.process_noise.force_std_N, est.process_noise.torque_std_Nm),
        substep_s=est.substep_s if est.substep_s is not None else cfg.simulation.plant_period_s,
        gate_probability=est.gate_probability,
        max_iterations=est.max_iterations,
        tolerance=est.tolerance,
        max_gating_rounds=est.max_gating_rounds,
        reorder_window=est.reorder_window,
    )


def estimation_prior(cfg: OacliConfig) -> ParameterEstimate:
    """The estimators' prior ``N(θ₀, P₀)`` (``estimation.prior``; the mean defaults to the robot model).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    ParameterEstimate
        At t = 0, method ``"prior"``.
    """
    model = estimation_prior_model(cfg)
    return ParameterEstimate(0.0, np.array(model.theta), np.array(model.covariance), "prior")


def estimation_prior_model(cfg: OacliConfig) -> RobotModel:
    """The estimators' prior as a robot model: :func:`robot_model` with ``estimation.prior``'s mean (where
    given); its covariance is the robot model's already.

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    RobotModel
    """
    return _model_with_prior(cfg, cfg.estimation.prior)


# ----------------------------------------------------------------------------------------------------------------
# Robust tube (controller.tube)
# ----------------------------------------------------------------------------------------------------------------


def tube_disturbance_spec(cfg: OacliConfig) -> DisturbanceSpec:
    """What W is made of besides the model (``controller.tube.disturbance``): n_σ of [Doerr2021] Eq. 28, the force,
    box and noise terms; m₀ and σ_m are the model's, passed with it to the design.

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.

    Returns
    -------
    DisturbanceSpec
    """
    dist = cfg.controller.tube.disturbance
    return DisturbanceSpec(
        n_sigma=dist.mass_sigmas,
        force_N=np.asarray(dist.force_N), box_position_m=np.asarray(dist.position_m),
        box_velocity_mps=np.asarray(dist.velocity_mps), noise_position_m=np.asarray(dist.position_noise_m),
        noise_velocity_mps=np.asarray(dist.velocity_noise_mps),
    )


def tube_design_from_config(cfg: OacliConfig, *, extra_box: np.ndarray | None = None,
                            max_terms: int | None = None, model: RobotModel | None = None) -> TubeDesign:
    """The translational tube of ``controller.tube`` ([Mayne2005]; [Rakovic2005]; [Doerr2021] Eqs. 15-28).

    Parameters
    ----------
    cfg : OacliConfig
        Resolved configuration.
    extra_box : ndarray, shape (3, 2), optional
        ``[position m, velocity m/s]`` half-widths per axis added to W's box (a redesign beyond W,
        :mod:`oacli.control.tube_monitor`; then an empty tightening always refuses).
    max_terms : int, optional
        Caps the invariant-set terms below ``rpi_max_terms``.
    model : RobotModel, optional
        The controller's model (default :func:`robot_model`): mass and, from its covariance, σ_m of W's mass term,
        force limit (unless ``controller.tube.force_limit_N``) and velocity limit.

    Returns
    -------
    TubeDesign

    Raises
    ------
    InfeasibleError
        No tube for this W (the message gives W and the margin).
    """
    tube = cfg.controller.tube
    model = robot_model(cfg) if model is None else model
    dist = tube.disturbance
    force_limit = np.asarray(tube.force_limit_N) if tube.force_limit_N is not None else model.force_limit_N
    spec = tube_disturbance_spec(cfg)
    on_empty = dist.on_empty_tightening
    if extra_box is not None:
        extra = np.asarray(extra_box, dtype=float).reshape(3, 2)
        spec = replace(spec, box_position_m=spec.box_position_m + extra[:, 0],
                       box_velocity_mps=spec.box_velocity_mps + extra[:, 1])
        on_empty = "error"
    anc = tube.ancillary
    obs = tube.observer
    observer = None if not obs.enabled else observer_spec(
        model=model, dt_s=cfg.controller.period_s, position_std_m=cfg.sensors.position_std_m,
        velocity_std_mps=cfg.sensors.velocity_std_mps, noise_sigmas=obs.noise_sigmas, gain=obs.gain,
        accel_std_mps2=obs.accel_std_mps2)
    return design_translation_tube(
        model=model, dt_s=cfg.controller.period_s, force_limit_N=force_limit,
        velocity_limit_mps=model.velocity_limit_mps,
        weights=AncillaryWeights(anc.position, anc.velocity, anc.force), spec=spec, epsilon=tube.rpi_epsilon,
        epsilon_mode=tube.rpi_epsilon_mode,
        max_terms=tube.rpi_max_terms if max_terms is None else min(max_terms, tube.rpi_max_terms),
        facet_growth=tube.lasso_facet_growth, on_empty=on_empty, min_nominal_fraction=dist.min_nominal_fraction,
        observer=observer,
    )
