"""Names, topics and JSON schemas of oacli's MCAP contract (see ``docs/mcap.md``): the sample records every
stage shares and each stage's own records (:data:`SCHEMAS` lists them all by name).

Every oacli record is a JSON object on a channel with ``message_encoding = "json"`` and a JSON-Schema
(``schema encoding = "jsonschema"``) whose ``title`` is the schema name below. Times are mission time in
seconds since the start of the stage; every message's MCAP ``log_time`` and ``publish_time`` are
``round(t * 1e9)`` nanoseconds, and the record's own ``t`` field holds the exact float.
"""

from __future__ import annotations

from typing import Any

#: Version of this contract, stored in the ``oacli`` metadata record as ``contract_version``.
CONTRACT_VERSION = "1"

TRAJECTORY_SAMPLE = "oacli.TrajectorySample"
SOLVER_STATS = "oacli.SolverStats"
WRENCH = "oacli.Wrench"

#: Topics with a fixed meaning (any other topic name is allowed too).
TOPIC_TRAJECTORY = "/trajectory"
TOPIC_REFERENCE = "/reference"
TOPIC_STATE_TRUE = "/state/true"
TOPIC_STATE_MEASURED = "/state/measured"
TOPIC_CONTROL_COMMAND = "/control/command"
TOPIC_CONTROL_APPLIED = "/control/applied"
TOPIC_DISTURBANCE = "/disturbance"
TOPIC_SOLVER_STATS = "/solver/stats"
TOPIC_ROBOT_POSE = "/robot/pose"
TOPIC_SCENE = "/scene"
TOPIC_LOG = "/log"

#: Attachment holding the resolved configuration, and the metadata record every stage writes.
CONFIG_ATTACHMENT = "config.yaml"
CONFIG_MEDIA_TYPE = "application/yaml"
METADATA_NAME = "oacli"


def _vector(n: int, description: str) -> dict[str, Any]:
    return {
        "type": "array",
        "items": {"type": "number"},
        "minItems": n,
        "maxItems": n,
        "description": description,
    }


_TIME = {"type": "number", "minimum": 0, "description": "mission time since the start of the stage [s]"}

TRAJECTORY_SAMPLE_SCHEMA: dict[str, Any] = {
    "title": TRAJECTORY_SAMPLE,
    "description": (
        "One sample of a state and input trajectory of the free flyer ([Doerr2021] Eqs. 33-35). "
        "The input is held from this sample's t to the next one's (zero-order hold)."
    ),
    "type": "object",
    "properties": {
        "t": _TIME,
        "position": _vector(3, "position r of the centre of mass in the world frame [m]"),
        "velocity": _vector(3, "velocity v in the world frame [m/s]"),
        "quaternion": _vector(4, "attitude q = [x, y, z, w] (scalar last), rotates body vectors into the world"),
        "angular_velocity": _vector(3, "body angular rate omega in the body frame [rad/s]"),
        "force": _vector(3, "force f in the world frame [N]"),
        "torque": _vector(3, "torque tau in the body frame [N·m]"),
    },
    "required": ["t", "position", "velocity", "quaternion", "angular_velocity", "force", "torque"],
}

SOLVER_STATS_SCHEMA: dict[str, Any] = {
    "title": SOLVER_STATS,
    "description": "Outcome of one controller step's optimisation.",
    "type": "object",
    "properties": {
        "t": _TIME,
        "status": {"type": "string", "description": "solver status as reported (optimal, infeasible, ...)"},
        "success": {"type": "boolean", "description": "true when the solution was used"},
        "objective": {"type": ["number", "null"], "description": "optimal objective value (null if failed)"},
        "iterations": {"type": "integer", "description": "solver iterations (-1 when unknown)"},
        "solve_time_ms": {"type": ["number", "null"], "description": "wall time of the solver call [ms]"},
        "step_time_ms": {
            "type": ["number", "null"],
            "description": "wall time of the whole controller step, solver included [ms]",
        },
    },
    "required": ["t", "status", "success", "objective", "iterations", "solve_time_ms", "step_time_ms"],
}

WRENCH_SCHEMA: dict[str, Any] = {
    "title": WRENCH,
    "description": "A force and torque held from t to the next sample (e.g. a disturbance).",
    "type": "object",
    "properties": {
        "t": _TIME,
        "force": _vector(3, "force f in the world frame [N]"),
        "torque": _vector(3, "torque tau in the body frame [N·m]"),
    },
    "required": ["t", "force", "torque"],
}

#: Fast JSON encoders. ``%r`` of a Python float is its shortest round-tripping repr, which is valid JSON
#: for finite values (the writers check finiteness first), so parsing the text gives back the same float.
TRAJECTORY_SAMPLE_TEMPLATE = (
    '{"t":%r,"position":[%r,%r,%r],"velocity":[%r,%r,%r],"quaternion":[%r,%r,%r,%r],'
    '"angular_velocity":[%r,%r,%r],"force":[%r,%r,%r],"torque":[%r,%r,%r]}'
)
WRENCH_TEMPLATE = '{"t":%r,"force":[%r,%r,%r],"torque":[%r,%r,%r]}'


# ----------------------------------------------------------------------------------------------------------------
# Stage-specific records (``StageMcapWriter.write_json``): topic, schema name and JSON schema of each
# ----------------------------------------------------------------------------------------------------------------

# -- plan --------------------------------------------------------------------------------------------------------

TOPIC_PLAN_TREE = "/plan/tree"
TOPIC_PLAN_REWIRES = "/plan/rewires"
TOPIC_PLAN_SOLUTIONS = "/plan/solutions"
PLAN_TREE_NODE = "oacli.PlanTreeNode"
PLAN_REWIRE = "oacli.PlanRewire"
PLAN_SOLUTION = "oacli.PlanSolution"

_PLANNER_T = {"type": "number", "description": "0: planner records are not on the trajectory's time axis [s]"}
_VEC3 = {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}

PLAN_TREE_NODE_SCHEMA: dict[str, Any] = {
    "description": "One node of the planner's final tree and its incoming edge.",
    "type": "object",
    "properties": {
        "t": _PLANNER_T,
        "node": {"type": "integer", "description": "node index (0 = start)"},
        "parent": {"type": "integer", "description": "parent index, -1 for the start"},
        "iteration": {"type": "integer", "description": "iteration the node was added in"},
        "wall_time_s": {"type": "number", "description": "planner wall time when the node was added [s]"},
        "position": {**_VEC3, "description": "position r, world frame [m]"},
        "velocity": {**_VEC3, "description": "velocity v, world frame [m/s]"},
        "cost": {"type": "number", "description": "cost-to-come from the start [-]"},
        "edge": {"type": "string", "description": "'root', 'lqr' (exact LQR connection) or 'primitive'"},
        "edge_steps": {"type": "integer", "description": "horizon of an LQR edge [steps of steer_dt_s]"},
        "edge_duration_s": {"type": "number", "description": "duration of the incoming edge [s]"},
        "edge_force": {**_VEC3, "description": "held force of a primitive edge, world frame [N]"},
        "in_path": {"type": "boolean", "description": "the node lies on the returned start-to-goal path"},
        "goal": {"type": "boolean", "description": "the node is the goal"},
    },
    "required": ["t", "node", "parent", "position", "velocity", "cost", "edge"],
}

PLAN_REWIRE_SCHEMA: dict[str, Any] = {
    "description": "A rewiring of LQR-RRT*: node moved to a cheaper parent; its descendants' costs followed.",
    "type": "object",
    "properties": {
        "t": _PLANNER_T,
        "iteration": {"type": "integer"},
        "node": {"type": "integer"},
        "old_parent": {"type": "integer"},
        "new_parent": {"type": "integer"},
        "old_steps": {"type": "integer", "description": "old edge horizon [steps]"},
        "new_steps": {"type": "integer", "description": "new edge horizon [steps]"},
        "old_cost": {"type": "number", "description": "cost-to-come before [-]"},
        "new_cost": {"type": "number", "description": "cost-to-come after [-]"},
        "descendants_updated": {"type": "integer", "description": "nodes below whose cost changed too"},
    },
    "required": ["t", "iteration", "node", "old_parent", "new_parent", "old_cost", "new_cost"],
}

PLAN_SOLUTION_SCHEMA: dict[str, Any] = {
    "description": "The best start-to-goal solution improved (the first record is the first solution).",
    "type": "object",
    "properties": {
        "t": _PLANNER_T,
        "iteration": {"type": "integer"},
        "wall_time_s": {"type": "number", "description": "planner wall time [s]"},
        "cost": {"type": "number", "description": "cost of the best solution [-]"},
        "nodes": {"type": "integer", "description": "tree size"},
    },
    "required": ["t", "iteration", "wall_time_s", "cost", "nodes"],
}

# -- smooth ------------------------------------------------------------------------------------------------------

TOPIC_SMOOTH_SHORTCUTS = "/smooth/shortcuts"
TOPIC_SMOOTH_POLISH = "/smooth/polish"
SHORTCUT_ATTEMPT = "oacli.ShortcutAttempt"
POLISH_ITERATION = "oacli.PolishIteration"

SHORTCUT_ATTEMPT_SCHEMA: dict[str, Any] = {
    "description": "One LQR shortcut try: the section between samples a and b, the best connection, the outcome.",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "0: shortcut records are not on the trajectory's time axis [s]"},
        "try": {"type": "integer", "description": "try number"},
        "a": {"type": "integer", "description": "first sample index (trajectory as it was at this try)"},
        "b": {"type": "integer", "description": "last sample index"},
        "t_a": {"type": "number", "description": "time of sample a [s]"},
        "t_b": {"type": "number", "description": "time of sample b [s]"},
        "steps": {"type": "integer", "description": "horizon of the best connection considered [steps]"},
        "old_cost": {"type": "number", "description": "cost of the replaced section [-]"},
        "new_cost": {"type": ["number", "null"], "description": "cost of the connection [-]"},
        "outcome": {"type": "string", "description": "accepted, not_lower_cost, input_limit, velocity_limit or "
                                                     "collision"},
    },
    "required": ["t", "try", "a", "b", "outcome"],
}

POLISH_ITERATION_SCHEMA: dict[str, Any] = {
    "description": "One SCP subproblem of the path-length polish and the verdict on its solution.",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "0: polish records are not on the trajectory's time axis [s]"},
        "iteration": {"type": "integer", "description": "subproblem number"},
        "trust_radius_m": {"type": "number", "description": "trust radius on the knot positions [m]"},
        "status": {"type": "string", "description": "solver status"},
        "objective": {"type": ["number", "null"], "description": "subproblem optimum (length bound + effort + "
                                                                 "buffer penalty)"},
        "buffer_m": {"type": ["number", "null"], "description": "largest virtual buffer (0: certified) [m]"},
        "length_m": {"type": ["number", "null"], "description": "exact path length of the candidate [m]"},
        "duration_s": {"type": ["number", "null"], "description": "candidate duration [s]"},
        "cost": {"type": ["number", "null"], "description": "LQR cost J of the candidate [-]"},
        "solve_time_s": {"type": "number", "description": "solve wall time [s]"},
        "outcome": {"type": "string", "description": "accepted, not_shorter, collision, limits, cost or "
                                                     "solver_failed"},
        "predicted": {"type": "boolean", "description": "keep-out half-spaces taken ahead of the reference "
                                                        "(look-ahead step)"},
    },
    "required": ["t", "iteration", "status", "outcome"],
}

# -- excite ------------------------------------------------------------------------------------------------------

TOPIC_EXCITATION_ITERATIONS = "/excitation/iterations"
TOPIC_EXCITATION_INFORMATION = "/excitation/information"
TOPIC_EXCITATION_REPLANS = "/excitation/replans"
SCP_ITERATION = "oacli.ScpIteration"
INFORMATION = "oacli.Information"
REPLAN = "oacli.Replan"

SCP_ITERATION_SCHEMA: dict[str, Any] = {
    "description": "One sequential convex programming iteration of the excitation design (t is always 0).",
    "properties": {
        "t": {"type": "number", "description": "0 (iterations are not in mission time) [s]"},
        "iteration": {"type": "integer", "description": "iteration number, from 1"},
        "criterion": {"type": ["number", "null"], "description": "criterion of the design after the iteration"},
        "merit": {"type": ["number", "null"], "description": "merit J/J_ref + μ V after the iteration"},
        "violation": {"type": ["number", "null"], "description": "normalised constraint violation after it"},
        "candidate_criterion": {"type": ["number", "null"], "description": "criterion at the trial point"},
        "candidate_merit": {"type": ["number", "null"], "description": "merit at the trial point"},
        "predicted_merit": {"type": ["number", "null"], "description": "convex model's merit at the trial point"},
        "ratio": {"type": ["number", "null"], "description": "actual / predicted merit decrease"},
        "trust_region_force": {"type": "number", "description": "trust region, fraction of the force limit"},
        "trust_region_torque": {"type": "number", "description": "trust region, fraction of the torque limit"},
        "accepted": {"type": "boolean", "description": "the trial point became the design"},
        "status": {"type": "string", "description": "solver status of the subproblem"},
        "solve_time_ms": {"type": "number", "description": "subproblem solve time [ms]"},
    },
}

INFORMATION_SCHEMA: dict[str, Any] = {
    "description": "Cumulative Fisher information of the measurements up to t, and its Cramér-Rao bound.",
    "properties": {
        "t": {"type": "number", "description": "mission time [s]"},
        "parameters": {"type": "array", "items": {"type": "string"}, "description": "θ names"},
        "information": {"type": "array", "description": "Fisher information F (4x4) [1/unit²]"},
        "crb_std": {"type": "array", "description": "sqrt(diag F⁻¹), null where unidentifiable [kg, kg·m²]"},
    },
}

REPLAN_SCHEMA: dict[str, Any] = {
    "description": "One replan of the RATTLE information-aware planner.",
    "properties": {
        "t": {"type": "number", "description": "mission time [s]"},
        "theta": {"type": "array", "description": "estimate used as the model [kg, kg·m²]"},
        "std": {"type": "array", "description": "its standard deviations [kg, kg·m²]"},
        "gamma": {"type": "array", "description": "information weights from the decay rule"},
        "cost": {"type": "number", "description": "true cost of the plan"},
        "information_reward": {"type": "number", "description": "Σ γ_i ½ log(1 + F_ii σ_i²) of the plan"},
        "accepted_iterations": {"type": "integer", "description": "SCP steps kept"},
        "solve_time_ms": {"type": "number", "description": "wall time of the replan [ms]"},
        "status": {"type": "string", "description": "last solver status"},
        "estimator": {"type": "string", "description": "method of the estimate"},
    },
}

# -- track with the robust tube MPC ------------------------------------------------------------------------------

TOPIC_CONTROL_NOMINAL = "/control/nominal"
TOPIC_CONTROL_ANCILLARY = "/control/ancillary"
TOPIC_STATE_NOMINAL = "/state/nominal"
TOPIC_TUBE_DESIGN = "/tube/design"
TOPIC_TUBE_DISTURBANCE = "/tube/disturbance"
TUBE_DESIGN = "oacli.TubeDesign"
TUBE_DISTURBANCE = "oacli.TubeDisturbance"

TUBE_DESIGN_SCHEMA: dict[str, Any] = {
    "title": TUBE_DESIGN,
    "description": "Robust tube MPC design per world axis x, y, z (Mayne et al. 2005; Raković et al. 2005); one "
    "record per design, at the time it took over.",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "mission time [s]"},
        "dt_s": {"type": "number", "description": "control period, the step of W and of the ancillary law [s]"},
        "design": {"type": "integer", "description": "0: the initial design; 1, 2 ...: redesigns beyond W, in use "
                   "from t"},
        "axes": {
            "type": "array",
            "description": "per axis: the QP's set (z_normals/z_offsets: Z, or R = T ⊖ S with an observer) and the "
            "tube promised for the true state (promise_normals/promise_offsets: Z, or T with an observer) as "
            "{e = [position m, velocity m/s] : H e <= h}, W's vertices, gain K (u = v + K e), RPI figures and "
            "tightened bounds",
        },
    },
    "required": ["t", "dt_s", "axes"],
}

TUBE_DISTURBANCE_SCHEMA: dict[str, Any] = {
    "title": TUBE_DISTURBANCE,
    "description": "Realised one-step disturbance w_k = x_k − (A x_{k−1} + B u_{k−1}) of the translational error "
    "model per world axis, against the design's W (oacli.control.tube_monitor).",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "control step time [s]"},
        "w_position_m": {"type": "array", "description": "measured w, position component, x y z [m] (null at the "
                         "first step)"},
        "w_velocity_mps": {"type": "array", "description": "measured w, velocity component, x y z [m/s]"},
        "w_half_position_m": {"type": "array", "description": "W's half-width in position, x y z [m]"},
        "w_half_velocity_mps": {"type": "array", "description": "W's half-width in velocity, x y z [m/s]"},
        "margin": {"type": ["number", "null"], "description": "min over axes and facets of b − a·w (>= 0 in W)"},
        "violation": {"type": "boolean", "description": "w left W on some axis"},
        "design": {"type": "integer", "description": "index of the tube design driving the step (0: initial)"},
    },
    "required": ["t", "w_position_m", "w_velocity_mps", "w_half_position_m", "w_half_velocity_mps", "violation"],
}

# -- estimate ----------------------------------------------------------------------------------------------------

TOPIC_ESTIMATE_PARAMS = "/estimate/params"
TOPIC_ESTIMATE_SAMPLES = "/estimate/samples"
TOPIC_ESTIMATE_COST = "/estimate/cost"
TOPIC_STATE_ESTIMATED = "/state/estimated"
PARAMETER_ESTIMATE = "oacli.ParameterEstimate"
ESTIMATION_SAMPLE = "oacli.EstimationSample"
ESTIMATION_COST = "oacli.EstimationCost"

_NUM = {"type": "number"}
_RECORD_TIME = {"type": "number", "minimum": 0, "description": "mission time [s]"}

PARAMETER_ESTIMATE_SCHEMA: dict[str, Any] = {
    "description": "Estimate of the inertial parameters θ = [m, Ixx, Iyy, Izz] from the records up to t "
    "([Doerr2021] Eqs. 31-32).",
    "type": "object",
    "properties": {
        "t": {**_RECORD_TIME, "description": "time of the last record used [s]"},
        "method": {"type": "string", "description": "batch, sequential or rls"},
        "mass_kg": {**_NUM, "description": "mass estimate [kg]"},
        "inertia_kgm2": {"type": "array", "items": _NUM, "minItems": 3, "maxItems": 3,
                         "description": "principal inertias Ixx, Iyy, Izz [kg·m²]"},
        "covariance": {"type": "array", "items": {"type": "array", "items": _NUM, "minItems": 4, "maxItems": 4},
                       "minItems": 4, "maxItems": 4,
                       "description": "covariance of [m, Ixx, Iyy, Izz] [kg², kg²·m², (kg·m²)²]"},
        "std": {"type": "array", "items": _NUM, "minItems": 4, "maxItems": 4,
                "description": "standard deviations sqrt(diag covariance) [kg, kg·m² ×3]"},
        "samples_used": {"type": "integer", "description": "records used"},
        "samples_rejected": {"type": "integer", "description": "records rejected (χ² gate, late, duplicate)"},
        "final": {"type": "boolean", "description": "true for the estimate from all records"},
    },
    "required": ["t", "method", "mass_kg", "inertia_kgm2", "covariance", "std", "samples_used", "samples_rejected"],
}

ESTIMATION_SAMPLE_SCHEMA: dict[str, Any] = {
    "description": "What the estimator did with one telemetry record.",
    "type": "object",
    "properties": {
        "t": _RECORD_TIME,
        "status": {"type": "string", "description": "accepted, rejected (χ² gate), initialised, reinitialised, late"},
        "d2": {"type": ["number", "null"], "description": "normalised residual or innovation squared"},
        "dof": {"type": "integer", "description": "degrees of freedom of d2"},
        "gate": {"type": ["number", "null"], "description": "χ² threshold (null: no gate)"},
    },
    "required": ["t", "status", "d2", "dof", "gate"],
}

ESTIMATION_COST_SCHEMA: dict[str, Any] = {
    "description": "Batch solver: cost ‖b‖² after each accepted Gauss-Newton iteration of the final solve.",
    "type": "object",
    "properties": {"t": _RECORD_TIME, "iteration": {"type": "integer"}, "cost": _NUM},
    "required": ["t", "iteration", "cost"],
}

# -- track: measurements as flown (``sensors.imu``, ``sensors.localisation``) -------------------------------------

TOPIC_IMU = "/imu"
TOPIC_LOCALISATION = "/localisation"
IMU_SAMPLE = "oacli.ImuSample"
LOCALISATION_SAMPLE = "oacli.LocalisationSample"

IMU_SAMPLE_SCHEMA: dict[str, Any] = {
    "title": IMU_SAMPLE,
    "description": "One IMU reading at the plant rate (62.5 Hz): specific force and angular rate in the body frame, "
    "bias and noise included (oacli.sim.imu).",
    "type": "object",
    "properties": {
        "t": _RECORD_TIME,
        "linear_acceleration": _vector(3, "accelerometer: specific force R^T f / m + bias + noise, body frame [m/s²]"),
        "angular_velocity": _vector(3, "gyro: body rate omega + bias + noise, body frame [rad/s]"),
    },
    "required": ["t", "linear_acceleration", "angular_velocity"],
}

LOCALISATION_SAMPLE_SCHEMA: dict[str, Any] = {
    "title": LOCALISATION_SAMPLE,
    "description": "One localisation message as it reached the log (oacli.sim.localisation): written at its "
    "arrival time t, which may follow later stamps; stamp is the time the state refers to.",
    "type": "object",
    "properties": {
        "t": {**_RECORD_TIME, "description": "arrival (log) time [s]"},
        "stamp": {**_RECORD_TIME, "description": "time the measured state refers to [s]"},
        "position": _vector(3, "position r, world frame [m]"),
        "velocity": _vector(3, "velocity v, world frame [m/s]"),
        "quaternion": _vector(4, "attitude q = [x, y, z, w], body to world"),
        "angular_velocity": _vector(3, "body rate omega, body frame [rad/s]"),
    },
    "required": ["t", "stamp", "position", "velocity", "quaternion", "angular_velocity"],
}

#: Every JSON schema of the contract by its name (``title``): the records above and the sample records.
SCHEMAS: dict[str, dict[str, Any]] = {
    TRAJECTORY_SAMPLE: TRAJECTORY_SAMPLE_SCHEMA,
    SOLVER_STATS: SOLVER_STATS_SCHEMA,
    WRENCH: WRENCH_SCHEMA,
    PLAN_TREE_NODE: PLAN_TREE_NODE_SCHEMA,
    PLAN_REWIRE: PLAN_REWIRE_SCHEMA,
    PLAN_SOLUTION: PLAN_SOLUTION_SCHEMA,
    SHORTCUT_ATTEMPT: SHORTCUT_ATTEMPT_SCHEMA,
    POLISH_ITERATION: POLISH_ITERATION_SCHEMA,
    SCP_ITERATION: SCP_ITERATION_SCHEMA,
    INFORMATION: INFORMATION_SCHEMA,
    REPLAN: REPLAN_SCHEMA,
    TUBE_DESIGN: TUBE_DESIGN_SCHEMA,
    TUBE_DISTURBANCE: TUBE_DISTURBANCE_SCHEMA,
    PARAMETER_ESTIMATE: PARAMETER_ESTIMATE_SCHEMA,
    ESTIMATION_SAMPLE: ESTIMATION_SAMPLE_SCHEMA,
    ESTIMATION_COST: ESTIMATION_COST_SCHEMA,
    IMU_SAMPLE: IMU_SAMPLE_SCHEMA,
    LOCALISATION_SAMPLE: LOCALISATION_SAMPLE_SCHEMA,
}
