"""Names, topics and JSON schemas of oacli's MCAP contract (see ``docs/mcap.md``).

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
        "One sample of a state and input trajectory of the free flyer (Doerr et al. 2021, Eqs. 33-35). "
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
