"""Tests of oacli.config: presets, round trips, one precise message per problem, and a corruption property test."""

from __future__ import annotations

import copy
import itertools
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import BaseModel, ValidationError

from oacli.config import (
    KeepInBox,
    KeepOutEllipsoid,
    OacliConfig,
    Pose,
    config_from_dict,
    dump_config,
    load_config,
)
from oacli.config import models as m
from oacli.errors import ConfigError
from oacli.geometry import Ellipsoid, Scene
from oacli.types import InertialParams

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
PRESETS = sorted(p for p in CONFIGS.glob("*.yaml") if not p.name.startswith(("campaign_", "study_")))  # campaigns
PRESET_NAMES = ["doerr2021.yaml", "iss_reswarm.yaml", "iss_reswarm_flight_sensors.yaml", "iss_reswarm_tube.yaml",
                "mission_doerr2021.yaml", "mission_iss.yaml", "mission_unknown_payload.yaml",
                "rattle_flight_rls.yaml"]

BASE: dict[str, Any] = {
    "robot": {
        "mass_kg": 9.0,
        "inertia_kgm2": [0.15, 0.14, 0.16],
        "force_limit_N": [0.5, 0.5, 0.5],
        "torque_limit_Nm": [0.05, 0.05, 0.05],
    },
    "environment": {
        "keep_in": [{"corners": [[-2.0, -2.0, -2.0], [2.0, 2.0, 2.0]]}],
        "keep_out": [{"center": [1.0, 0.0, 0.0], "shape_matrix": [[4.0, 0.0, 0.0], [0.0, 4.0, 0.0], [0.0, 0.0, 4.0]]}],
    },
    "waypoints": {"A": {"position": [0.0, 0.0, 0.0]}, "B": {"position": [1.0, 1.0, 1.0]}},
    "reference": {"waypoints": ["A", "B"]},
}


def base() -> dict[str, Any]:
    return copy.deepcopy(BASE)


def write_yaml(folder: Path, data: Any, name: str = "cfg.yaml") -> Path:
    path = folder / name
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def problems_of(path: Path) -> list[str]:
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert info.value.exit_code == 2
    assert str(info.value) == "\n".join(info.value.problems)
    return info.value.problems


# --------------------------------------------------------------------------------------------------------------
# Presets
# --------------------------------------------------------------------------------------------------------------


def test_both_presets_exist():
    assert [p.name for p in PRESETS] == PRESET_NAMES


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_preset_round_trips_through_dump(tmp_path, name):
    cfg = load_config(CONFIGS / name)
    text = dump_config(cfg)
    assert "!!" not in text  # plain safe YAML, no Python tags
    again_path = tmp_path / "config.yaml"
    again_path.write_text(text, encoding="utf-8")
    again = load_config(again_path)
    assert again == cfg
    assert dump_config(again) == text  # a fixed point
    assert config_from_dict(yaml.safe_load(text)) == cfg


def test_iss_preset_values():
    cfg = load_config(CONFIGS / "iss_reswarm.yaml")
    assert cfg.name == "iss-reswarm"
    params = cfg.robot.inertial_params()
    assert isinstance(params, InertialParams)
    assert params.mass_kg == 9.583788668  # astrobee iss.config
    np.testing.assert_array_equal(params.inertia_kgm2, [0.153427995, 0.14271405, 0.162302759])
    np.testing.assert_array_equal(cfg.robot.input_limits, [0.452, 0.216, 0.257, 0.0452, 0.0216, 0.0257])
    assert cfg.truth_params().mass_kg == params.mass_kg  # truth omitted: plant = robot
    assert cfg.truth.disturbance.is_zero
    boxes = cfg.environment.keep_in
    assert len(boxes) == 3
    # keepin.json corners are unordered: stored sorted per axis.
    assert boxes[0].lower == (9.8595, -9.2365, 3.7831)
    assert boxes[0].upper == (11.995, -2.7532, 5.918)
    for box in boxes:
        assert all(lo < hi for lo, hi in zip(box.lower, box.upper, strict=True))
    assert cfg.environment.frame == "iss"
    assert set(cfg.waypoints) == {"A", "B", "C"}
    assert cfg.waypoints["B"].position == (10.8, -7.75, 5.2)
    assert math.isclose(np.linalg.norm(cfg.waypoints["A"].quaternion), 1.0, abs_tol=1e-15)
    poses = cfg.reference_poses()
    assert [p.position for p in poses] == [(10.8, -9.6, 4.8), (10.8, -7.75, 5.2)]
    assert cfg.controller.horizon == 10 and cfg.controller.period_s == pytest.approx(0.2)
    assert cfg.sensors.position_std_m == 0.01
    assert cfg.simulation.plant_period_s == pytest.approx(0.016)


def test_doerr_preset_values():
    cfg = load_config(CONFIGS / "doerr2021.yaml")
    assert cfg.robot.mass_kg == 9.0877  # [Doerr2021] Table 1
    assert cfg.robot.inertia_kgm2 == (0.1454, 0.1366, 0.1594)
    assert cfg.robot.force_limit_N == (0.5, 0.5, 0.5)  # [Doerr2021] Results
    assert cfg.truth_params().mass_kg == 9.0877  # segment 1: model known
    assert cfg.environment.safety_factor > 1.0
    assert len(cfg.environment.keep_out) >= 2
    assert {"A", "B", "C"} <= set(cfg.waypoints)
    assert [p for p in cfg.reference.waypoints] == ["A", "V", "B"]
    # The straight A-B line crosses a keep-out zone: segment 1 needs the planner (or the via point V).
    a, b = np.array(cfg.waypoints["A"].position), np.array(cfg.waypoints["B"].position)
    assert np.any(cfg.scene().in_keep_out(a + np.linspace(0, 1, 101)[:, None] * (b - a)))


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_preset_reference_path_is_free(name):
    """The piecewise-straight reference path of each preset stays in the keep-in set and clear of the keep-out
    zones grown by the robot radius."""
    cfg = load_config(CONFIGS / name)
    poses = np.array([p.position for p in cfg.reference_poses()])
    scene = cfg.environment.scene()
    radius = cfg.robot.radius_m
    s = np.linspace(0.0, 1.0, 201)[:, None]
    start, end = poses[0], poses[-1]
    points = np.vstack([a + s * (b - a) for a, b in itertools.pairwise(poses)])
    assert np.all(scene.in_keep_in(points))
    assert np.all(scene.in_keep_in(np.array([start, end]), margin_m=radius))
    for zone in scene.keep_out:
        semi, rot = zone.principal_axes()
        grown = Ellipsoid.from_semi_axes(zone.center, semi + radius, rot)  # ⊇ zone ⊕ ball(radius)
        assert not np.any(grown.contains(points))
    for pose in cfg.waypoints.values():
        assert not np.any(scene.in_keep_out(np.array(pose.position)))


# --------------------------------------------------------------------------------------------------------------
# Convenience methods and accepted inputs
# --------------------------------------------------------------------------------------------------------------


def test_minimal_config_uses_defaults():
    cfg = config_from_dict({"robot": BASE["robot"]})
    assert cfg.name == "oacli" and cfg.seed == 0
    assert cfg.controller.type == "mpc" and cfg.controller.horizon == 10
    assert cfg.robot.velocity_limit_mps == (0.2, 0.2, 0.2)
    assert cfg.environment.scene() == Scene(frame="world")
    assert cfg.reference_poses() == ()
    assert cfg.truth.mass_kg == 9.0 and cfg.truth.inertia_kgm2 == (0.15, 0.14, 0.16)


def test_empty_yaml_sections_mean_defaults(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(
        "robot: {mass_kg: 9.0, inertia_kgm2: [0.15, 0.14, 0.16], force_limit_N: [0.5, 0.5, 0.5],\n"
        "        torque_limit_Nm: [0.05, 0.05, 0.05]}\nsensors:\nenvironment:\n  keep_out:\n",
        encoding="utf-8",
    )
    cfg = load_config(path)
    assert cfg.sensors.position_std_m == 0.0 and cfg.environment.keep_out == ()


def test_values_are_floats_in_tuples_and_models_are_frozen():
    cfg = config_from_dict(base())
    assert cfg.robot.mass_kg == 9.0 and type(cfg.robot.mass_kg) is float
    assert isinstance(cfg.robot.force_limit_N, tuple)
    assert all(type(v) is float for v in cfg.robot.force_limit_N)
    with pytest.raises(ValidationError):
        cfg.robot.mass_kg = 1.0  # type: ignore[misc]
    limits = cfg.robot.input_limits
    assert limits.shape == (6,) and not limits.flags.writeable


def test_numpy_inputs_are_accepted():
    data = base()
    data["robot"]["inertia_kgm2"] = np.array([0.15, 0.14, 0.16])
    data["robot"]["mass_kg"] = np.float64(9.0)
    data["environment"]["keep_out"][0]["shape_matrix"] = 4.0 * np.eye(3)
    assert config_from_dict(data) == config_from_dict(base())


def test_nearly_unit_quaternion_is_normalised():
    data = base()
    data["waypoints"]["A"]["quaternion"] = [0.0, 0.0, 0.0, 1.0009]
    q = config_from_dict(data).waypoints["A"].quaternion
    assert q == (0.0, 0.0, 0.0, 1.0)
    half = math.sqrt(0.5)
    assert Pose(position=(0, 0, 0), quaternion=(0, 0, half, half)).quaternion == (0.0, 0.0, half, half)


def test_box_corners_are_sorted_per_axis():
    box = KeepInBox(corners=((1.0, -1.0, 5.0), (0.0, 2.0, 4.0)))
    assert box.corners == ((0.0, -1.0, 4.0), (1.0, 2.0, 5.0))
    np.testing.assert_array_equal(box.box().lower, [0.0, -1.0, 4.0])


def test_scene_applies_safety_factor_and_rotation():
    half = math.sqrt(0.5)
    zone = KeepOutEllipsoid(center=(0, 0, 0), semi_axes_m=(1.0, 2.0, 3.0), quaternion=(0, 0, half, half))
    # 90° about z: the 2 m body y axis points along world -x.
    e = zone.ellipsoid()
    assert e.contains(np.array([1.9, 0.0, 0.0])) and not e.contains(np.array([0.0, 1.5, 0.0]))
    data = base()
    data["environment"] = {"safety_factor": 1.5, "keep_out": [zone.model_dump()]}
    scene = config_from_dict(data).environment.scene()
    semi, _ = scene.keep_out[0].principal_axes()
    np.testing.assert_allclose(np.sort(semi), [1.5, 3.0, 4.5])


def test_shape_matrix_ellipsoid_matches_semi_axes():
    a = KeepOutEllipsoid(center=(1, 2, 3), semi_axes_m=(0.5, 0.5, 0.5)).ellipsoid()
    b = KeepOutEllipsoid(center=(1, 2, 3), shape_matrix=((4, 0, 0), (0, 4, 0), (0, 0, 4))).ellipsoid()
    np.testing.assert_allclose(a.shape, b.shape)


def test_weights_accept_a_scalar():
    data = base()
    data["controller"] = {"weights": {"position": 3, "torque": [1, 2, 3]}}
    w = config_from_dict(data).controller.weights
    assert w.position == (3.0, 3.0, 3.0) and w.torque == (1.0, 2.0, 3.0)
    np.testing.assert_array_equal(w.state_weights()[:3], [3.0, 3.0, 3.0])
    assert w.input_weights().shape == (6,)


def test_truth_overrides_only_what_it_names():
    data = base()
    data["truth"] = {"mass_kg": 15.0, "disturbance": {"force_random_N": [0.01, 0.0, 0.0]}}
    cfg = config_from_dict(data)
    truth = cfg.truth_params()
    assert truth.mass_kg == 15.0
    np.testing.assert_array_equal(truth.inertia_kgm2, [0.15, 0.14, 0.16])
    assert cfg.robot.mass_kg == 9.0
    np.testing.assert_array_equal(cfg.truth.disturbance.random_bound, [0.01, 0, 0, 0, 0, 0])


def test_relative_reference_file_is_resolved_against_config_folder(tmp_path):
    data = base()
    data["reference"] = {"source": "file", "file": "../data/MIT-ISS"}
    (tmp_path / "sub").mkdir()
    cfg = load_config(write_yaml(tmp_path / "sub", data))
    assert cfg.reference.file == str(tmp_path / "data" / "MIT-ISS")  # existence is not checked here
    assert os.path.isabs(cfg.reference.file)
    again = tmp_path / "again.yaml"
    again.write_text(dump_config(cfg), encoding="utf-8")
    assert load_config(again).reference.file == cfg.reference.file


def test_inline_reference_pose():
    data = base()
    data["reference"]["waypoints"] = ["A", {"position": [0.5, 0.5, 0.5]}]
    poses = config_from_dict(data).reference_poses()
    assert poses[1].position == (0.5, 0.5, 0.5) and poses[1].quaternion == (0.0, 0.0, 0.0, 1.0)
    np.testing.assert_array_equal(poses[1].state()[6:10], [0, 0, 0, 1])


def _all_models() -> list[type[BaseModel]]:
    return [v for v in vars(m).values() if isinstance(v, type) and issubclass(v, m.Section) and v is not m.Section]


@pytest.mark.parametrize("model", _all_models(), ids=lambda c: c.__name__)
def test_every_field_is_described(model):
    assert model.model_config.get("extra") == "forbid" and model.model_config.get("frozen") is True
    for name, field in model.model_fields.items():
        assert field.description and len(field.description) > 10, f"{model.__name__}.{name}"


# --------------------------------------------------------------------------------------------------------------
# One precise line per problem
# --------------------------------------------------------------------------------------------------------------


def _set(path: str, value: Any):
    def apply(data: dict) -> None:
        *parents, last = path.split(".")
        node: Any = data
        for key in parents:
            node = node[int(key)] if isinstance(node, list) else node.setdefault(key, {})
        if isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value

    return apply


def _delete(path: str):
    def apply(data: dict) -> None:
        *parents, last = path.split(".")
        node: Any = data
        for key in parents:
            node = node[int(key)] if isinstance(node, list) else node[key]
        del node[last]

    return apply


BAD_INPUTS = [
    ("negative mass", _set("robot.mass_kg", -1.0), "robot.mass_kg: -1.0: must be > 0"),
    ("zero mass", _set("robot.mass_kg", 0), "robot.mass_kg: 0: must be > 0"),
    (
        "triangle inequality",
        _set("robot.inertia_kgm2", [0.1, 0.1, 0.3]),
        "robot.inertia_kgm2: [0.1, 0.1, 0.3]: principal inertias violate the triangle inequality "
        "Ixx + Iyy >= Izz (0.2 < 0.3)",
    ),
    (
        "triangle inequality, other axis",
        _set("truth.inertia_kgm2", [0.5, 0.1, 0.1]),
        "truth.inertia_kgm2: [0.5, 0.1, 0.1]: principal inertias violate the triangle inequality "
        "Iyy + Izz >= Ixx (0.2 < 0.5)",
    ),
    (
        "negative inertia element",
        _set("robot.inertia_kgm2", [0.1, -0.1, 0.1]),
        "robot.inertia_kgm2.1: -0.1: must be > 0",
    ),
    (
        "shape matrix not positive definite",
        _set("environment.keep_out.0.shape_matrix", [[1, 0, 0], [0, -2, 0], [0, 0, 1]]),
        "environment.keep_out.0.shape_matrix: [[1, 0, 0], [0, -2, 0], [0, 0, 1]]: "
        "must be positive definite (smallest eigenvalue -2)",
    ),
    (
        "shape matrix not symmetric",
        _set("environment.keep_out.0.shape_matrix", [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]),
        "environment.keep_out.0.shape_matrix: [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]: "
        "must be symmetric (largest |P - Pᵀ| entry 0.5)",
    ),
    (
        "ellipsoid with both descriptions",
        _set("environment.keep_out.0.semi_axes_m", [1, 1, 1]),
        "environment.keep_out.0: {'center': [1.0, 0.0, 0.0], 'semi_axes_m': [1, 1, 1], 'sh...: "
        "give exactly one of semi_axes_m or shape_matrix (got both)",
    ),
    (
        "quaternion with a shape matrix",
        _set("environment.keep_out.0.quaternion", [0, 0, 0, 1]),
        "environment.keep_out.0.quaternion: [0.0, 0.0, 0.0, 1.0]: only allowed with semi_axes_m, not with shape_matrix",
    ),
    ("unknown top-level key", _set("robt", 1), "robt: 1: unknown key (did you mean 'robot'?)"),
    (
        "abbreviated key",
        _set("environment.keep_out.0.quat", [0, 0, 0, 1]),
        "environment.keep_out.0.quat: [0, 0, 0, 1]: unknown key (did you mean 'quaternion'?)",
    ),
    ("misspelt key", _set("robot.masskg", 9.0), "robot.masskg: 9.0: unknown key (did you mean 'mass_kg'?)"),
    (
        "unknown nested key",
        _set("environment.keep_out.0.radius", 0.3),
        "environment.keep_out.0.radius: 0.3: unknown key (allowed: center, semi_axes_m, quaternion, shape_matrix)",
    ),
    (
        "unknown key in a waypoint",
        _set("waypoints.A.orientation", [0, 0, 0, 1]),
        "waypoints.A.orientation: [0, 0, 0, 1]: unknown key (allowed: position, quaternion)",
    ),
    (
        "non-normalised quaternion",
        _set("waypoints.A.quaternion", [0, 0, 0, 2]),
        "waypoints.A.quaternion: [0, 0, 0, 2]: quaternion norm 2 is not 1 (tolerance 0.001)",
    ),
    (
        "zero quaternion",
        _set("waypoints.B.quaternion", [0, 0, 0, 0]),
        "waypoints.B.quaternion: [0, 0, 0, 0]: quaternion norm 0 is not 1 (tolerance 0.001)",
    ),
    ("NaN mass", _set("robot.mass_kg", float("nan")), "robot.mass_kg: nan: must be finite (not NaN or infinity)"),
    (
        "infinite vector element",
        _set("robot.force_limit_N", [0.5, float("inf"), 0.5]),
        "robot.force_limit_N.1: inf: must be finite (not NaN or infinity)",
    ),
    (
        "wrong vector length",
        _set("robot.force_limit_N", [0.5, 0.5]),
        "robot.force_limit_N: [0.5, 0.5]: must have exactly 3 elements, got 2",
    ),
    (
        "vector given as a number",
        _set("waypoints.A.position", 1.0),
        "waypoints.A.position: 1.0: must be a list of 3 items",
    ),
    ("text for a number", _set("robot.mass_kg", "heavy"), "robot.mass_kg: 'heavy': must be a number"),
    ("bool for a number", _set("robot.radius_m", True), "robot.radius_m: True: must be a number"),
    (
        "unknown waypoint name",
        _set("reference.waypoints", ["A", "Z"]),
        "reference.waypoints.1: 'Z': unknown waypoint name (defined in waypoints: A, B)",
    ),
    (
        "bad inline waypoint",
        _set("reference.waypoints", ["A", 7]),
        "reference.waypoints.1: 7: must be a waypoint name or a {position, quaternion} mapping",
    ),
    (
        "source file without file",
        _set("reference.source", "file"),
        "reference.file: None: required when reference.source is 'file'",
    ),
    (
        "cruise speed above velocity limit",
        _set("reference.cruise_speed_mps", 0.3),
        "reference.cruise_speed_mps: 0.3: must be <= the smallest robot.velocity_limit_mps (0.2 m/s)",
    ),
    (
        "acceleration beyond force limit",
        _set("reference.acceleration_mps2", 0.1),
        "reference.acceleration_mps2: 0.1: needs robot.mass_kg × acceleration = 0.9 N, more than the smallest "
        "robot.force_limit_N (0.5 N)",
    ),
    (
        "controller faster than the plant",
        _set("controller.rate_hz", 100.0),
        "controller.rate_hz: 100.0: must be <= simulation.plant_rate_hz (62.5 Hz)",
    ),
    ("missing mass", _delete("robot.mass_kg"), "robot.mass_kg: <missing>: required key is missing"),
    ("missing robot", _delete("robot"), "robot: <missing>: required key is missing"),
    ("unknown controller type", _set("controller.type", "pid"), "controller.type: 'pid': must be 'mpc' or 'tube'"),
    ("float horizon", _set("controller.horizon", 10.0), "controller.horizon: 10.0: must be an integer"),
    ("horizon too long", _set("controller.horizon", 501), "controller.horizon: 501: must be <= 500"),
    ("bool seed", _set("seed", True), "seed: True: must be an integer"),
    ("negative seed", _set("seed", -1), "seed: -1: must be >= 0"),
    ("zero weight", _set("controller.weights.force", 0), "controller.weights.force: 0: must be > 0"),
    ("safety factor below 1", _set("environment.safety_factor", 0.9), "environment.safety_factor: 0.9: must be >= 1"),
    ("negative noise", _set("sensors.position_std_m", -0.1), "sensors.position_std_m: -0.1: must be >= 0"),
    (
        "negative random disturbance",
        _set("truth.disturbance.torque_random_Nm", [0, -1, 0]),
        "truth.disturbance.torque_random_Nm.1: -1: must be >= 0",
    ),
    (
        "zero-width keep-in box",
        _set("environment.keep_in.0.corners", [[0, 0, 0], [1, 0, 1]]),
        "environment.keep_in.0.corners: [[0, 0, 0], [1, 0, 1]]: box has zero width along y (both corners at 0.0)",
    ),
    (
        "bad run name",
        _set("name", "../escape"),
        "name: '../escape': must contain only letters, digits, '_', '.' and '-' (not starting with '.' or '-')",
    ),
    ("section not a mapping", _set("sensors", [1, 2]), "sensors: [1, 2]: must be a mapping"),
]


@pytest.mark.parametrize(("mutate", "expected"), [c[1:] for c in BAD_INPUTS], ids=[c[0] for c in BAD_INPUTS])
def test_bad_input_gives_exactly_one_precise_line(tmp_path, mutate, expected):
    data = base()
    mutate(data)
    path = write_yaml(tmp_path, data)
    assert problems_of(path) == [f"{path}: {expected}"]


def test_all_problems_are_collected(tmp_path):
    data = base()
    data["robot"]["mass_kg"] = -1.0
    data["robot"]["colour"] = "blue"
    data["sensors"] = {"velocity_std_mps": float("nan")}
    data["environment"]["keep_out"][0]["center"] = [0, 0]
    path = write_yaml(tmp_path, data)
    lines = problems_of(path)
    assert len(lines) == 4
    assert all(line.startswith(f"{path}: ") for line in lines)
    paths = {line[len(f"{path}: ") :].split(":")[0] for line in lines}
    assert paths == {"robot.mass_kg", "robot.colour", "sensors.velocity_std_mps", "environment.keep_out.0.center"}


def test_cross_field_problems_are_collected_together(tmp_path):
    data = base()
    data["reference"] = {"source": "file", "waypoints": ["A", "Q", "R"]}
    data["robot"]["velocity_limit_mps"] = [0.2, 0.05, 0.2]
    lines = problems_of(write_yaml(tmp_path, data))
    assert [line.split(": ")[1] for line in lines] == [
        "reference.waypoints.1",
        "reference.waypoints.2",
        "reference.file",
    ]


def test_long_values_are_shortened(tmp_path):
    data = base()
    data["robot"]["mass_kg"] = list(range(1000))
    (line,) = problems_of(write_yaml(tmp_path, data))
    value = line.split(": ")[2]
    assert len(value) <= 60 and value.startswith("[0, 1, 2")


# --------------------------------------------------------------------------------------------------------------
# File-level problems
# --------------------------------------------------------------------------------------------------------------


def test_malformed_yaml_names_line_and_column(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("robot:\n  mass_kg: 9.0\n   inertia_kgm2: [0.1, 0.1\n", encoding="utf-8")
    assert problems_of(path) == [f"{path}: line 3, column 16: invalid YAML: mapping values are not allowed here"]


def test_unclosed_flow_list_names_a_line(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("name: x\nrobot:\n  mass_kg: [1.0, 2.0\nseed: 1\n", encoding="utf-8")
    (line,) = problems_of(path)
    assert line.startswith(f"{path}: line ") and "invalid YAML" in line


def test_duplicate_key_is_rejected(tmp_path):
    path = tmp_path / "dup.yaml"
    path.write_text("robot:\n  mass_kg: 9.0\n  mass_kg: 10.0\n", encoding="utf-8")
    assert problems_of(path) == [
        f"{path}: line 3, column 3: invalid YAML: found duplicate key 'mass_kg' (while constructing a mapping)"
    ]


def test_python_tags_are_refused(tmp_path):
    path = tmp_path / "tag.yaml"
    path.write_text("robot: !!python/object/apply:os.system ['true']\n", encoding="utf-8")
    (line,) = problems_of(path)
    assert line.startswith(f"{path}: line 1, column 8: invalid YAML: could not determine a constructor")


def test_missing_file(tmp_path):
    path = tmp_path / "nope.yaml"
    assert problems_of(path) == [f"{path}: file not found"]


def test_directory(tmp_path):
    assert problems_of(tmp_path) == [f"{tmp_path}: is a directory, expected a YAML file"]


def test_non_utf8(tmp_path):
    path = tmp_path / "latin1.yaml"
    path.write_bytes("name: caf\u00e9\n".encode("latin-1"))
    assert problems_of(path) == [f"{path}: not valid UTF-8 text (byte 0xe9 at offset 9)"]


def test_control_character(tmp_path):
    path = tmp_path / "ctl.yaml"
    path.write_text('name: "a\x01"\n', encoding="utf-8")
    assert problems_of(path) == [f"{path}: line 1, column 9: invalid YAML: unacceptable character #x0001"]


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n", "---\n"])
def test_empty_file(tmp_path, text):
    path = tmp_path / "empty.yaml"
    path.write_text(text, encoding="utf-8")
    assert problems_of(path) == [f"{path}: file is empty (expected a mapping with at least a 'robot' section)"]


@pytest.mark.parametrize(("text", "kind"), [("- 1\n- 2\n", "list"), ("42\n", "int"), ("just text\n", "str")])
def test_top_level_not_a_mapping(tmp_path, text, kind):
    path = tmp_path / "top.yaml"
    path.write_text(text, encoding="utf-8")
    assert problems_of(path) == [f"{path}: the top level must be a mapping of config sections, got {kind}"]


def test_config_from_dict_names_its_source():
    with pytest.raises(ConfigError) as info:
        config_from_dict({"robot": {}}, source="cli")
    assert info.value.problems[0] == "cli: robot.mass_kg: <missing>: required key is missing"
    assert len(info.value.problems) == 4


# --------------------------------------------------------------------------------------------------------------
# Property: any single corruption of a valid preset is reported at its field path, one line, file first
# --------------------------------------------------------------------------------------------------------------

PRESET_DATA = {name: yaml.safe_load((CONFIGS / name).read_text(encoding="utf-8")) for name in PRESET_NAMES}
NAN = float("nan")
INVALID = {
    # kind -> values that must be rejected wherever that kind of field sits
    "pos": [-1.0, 0.0, -1e-9, NAN, float("inf"), "abc", [1.0, 2.0], None, True],
    "nonneg": [-0.5, -1e-12, NAN, float("-inf"), "abc", [0.0], None, False],
    "ge1": [0.99, 0.0, -2.0, NAN, "abc"],
    "posint": [0, -3, 1.5, "abc", None, 10.0],
    "vec": [[1.0, 2.0], [1.0, 2.0, 3.0, 4.0], "abc", NAN, {"x": 1.0}],  # null = absent for optional vectors
    "elem_real": [NAN, float("inf"), "abc", None, [1.0]],
    "elem_pos": [-1.0, 0.0, NAN, "abc", None],
    "quat": [[0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 2.0], [0.0, 0.0, 0.0, 0.0], "abc", [NAN, 0.0, 0.0, 1.0]],
    "matrix": [[[1.0, 0.0], [0.0, 1.0]], [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "abc", 4.0],
    "corners": [[[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0]], [[0.0, 0.0, NAN], [1.0, 1.0, 1.0]], "abc"],
}
FIELD_KINDS = {
    "robot.mass_kg": "pos",
    "robot.radius_m": "nonneg",
    "environment.safety_factor": "ge1",
    **{f"sensors.{f}": "nonneg" for f in ("position_std_m", "velocity_std_mps", "attitude_std_rad",
                                          "angular_velocity_std_radps")},
    **{f"sensors.imu.{f}": "nonneg" for f in ("accelerometer_noise_std_mps2", "gyro_noise_std_radps",
                                              "accelerometer_bias_std_mps2", "gyro_bias_std_radps",
                                              "accelerometer_bias_random_walk", "gyro_bias_random_walk")},
    **{f"sensors.localisation.{f}": "nonneg" for f in ("jump_probability", "drop_probability",
                                                       "delay_probability", "delay_mean_s")},
    "sensors.localisation.rate_hz": "pos",
    "simulation.plant_rate_hz": "pos",
    "simulation.settle_time_s": "nonneg",
    "simulation.initial_offset_m": "vec",
    "controller.rate_hz": "pos",
    "controller.horizon": "posint",
    "controller.max_consecutive_failures": "posint",
    "controller.weights.*": "pos",
    "reference.cruise_speed_mps": "pos",
    "reference.acceleration_mps2": "pos",
    "reference.angular_rate_radps": "pos",
    "reference.angular_acceleration_radps2": "pos",
    "reference.hold_s": "nonneg",
    "robot.inertia_kgm2": "vec",
    "robot.force_limit_N": "vec",
    "robot.torque_limit_Nm": "vec",
    "robot.velocity_limit_mps": "vec",
    "robot.angular_velocity_limit_radps": "vec",
    "environment.keep_in.*.corners": "corners",
    "environment.keep_out.*.center": "vec",
    "environment.keep_out.*.semi_axes_m": "vec",
    "environment.keep_out.*.quaternion": "quat",
    "environment.keep_out.*.shape_matrix": "matrix",
    "waypoints.*.position": "vec",
    "waypoints.*.quaternion": "quat",
}
ELEMENT_KINDS = {  # vectors whose single elements can also be corrupted
    "robot.inertia_kgm2": "elem_pos",
    "robot.force_limit_N": "elem_pos",
    "robot.torque_limit_Nm": "elem_pos",
    "robot.velocity_limit_mps": "elem_pos",
    "robot.angular_velocity_limit_radps": "elem_pos",
    "simulation.initial_offset_m": "elem_real",
    "environment.keep_out.*.center": "elem_real",
    "environment.keep_out.*.semi_axes_m": "elem_pos",
    "waypoints.*.position": "elem_real",
}
REQUIRED = ["robot", "robot.mass_kg", "robot.inertia_kgm2", "robot.force_limit_N", "robot.torque_limit_Nm"]
REQUIRED_PATTERNS = ["waypoints.*.position", "environment.keep_in.*.corners", "environment.keep_out.*.center"]


def _walk(node: Any, path: tuple = ()):
    """Yield (path, value) for every node of a YAML tree."""
    yield path, node
    if isinstance(node, dict):
        for key, value in node.items():
            yield from _walk(value, (*path, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield from _walk(value, (*path, i))


def _matches(path: tuple, pattern: str) -> bool:
    parts = pattern.split(".")
    return len(parts) == len(path) and all(p == "*" or p == str(k) for p, k in zip(parts, path, strict=True))


def _kind(path: tuple, table: dict[str, str]) -> str | None:
    return next((kind for pattern, kind in table.items() if _matches(path, pattern)), None)


def _corruptions(data: dict) -> list[tuple[str, tuple, str | None]]:
    """Every (operation, path, kind) that can be applied to ``data``."""
    ops: list[tuple[str, tuple, str | None]] = []
    for path, node in _walk(data):
        if isinstance(node, dict) and path != ("waypoints",):  # waypoints' keys are names, any name is allowed
            ops.append(("add_key", path, None))
        if (kind := _kind(path, FIELD_KINDS)) is not None:
            ops.append(("replace", path, kind))
        if (kind := _kind(path, ELEMENT_KINDS)) is not None:
            ops.extend(("replace", (*path, i), kind) for i in range(len(node)))
        if ".".join(map(str, path)) in REQUIRED or any(_matches(path, p) for p in REQUIRED_PATTERNS):
            ops.append(("delete", path, None))
    return ops


OPS = {name: _corruptions(data) for name, data in PRESET_DATA.items()}


def _parent(data: Any, path: tuple) -> Any:
    for key in path[:-1]:
        data = data[key]
    return data


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_any_single_corruption_is_reported_at_its_path(draw):
    preset = draw.draw(st.sampled_from(PRESET_NAMES), label="preset")
    data = copy.deepcopy(PRESET_DATA[preset])
    op, path, kind = draw.draw(st.sampled_from(OPS[preset]), label="operation")
    if op == "add_key":
        key = "zz_" + draw.draw(st.text("abcdefghij_", min_size=1, max_size=8), label="key")
        node = _parent(data, (*path, None))
        node[key] = draw.draw(st.integers() | st.text(max_size=5) | st.none(), label="value")
        expected = (*path, key)
    elif op == "replace":
        value = draw.draw(st.sampled_from(INVALID[kind]), label="value")
        _parent(data, path)[path[-1]] = copy.deepcopy(value)
        expected = path
    else:
        del _parent(data, path)[path[-1]]
        expected = path
    expected_path = ".".join(str(k) for k in expected)

    with tempfile.TemporaryDirectory() as folder:
        file = Path(folder) / "corrupted.yaml"
        file.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
        with pytest.raises(ConfigError) as info:
            load_config(file)
    lines = info.value.problems
    assert lines, "a ConfigError without problems"
    prefix = f"{file}: "
    for line in lines:
        assert line.startswith(prefix), line
        assert "\n" not in line
    assert len(lines) == 1, lines
    rest = lines[0][len(prefix) :]
    assert rest.startswith(expected_path + ": ") or rest.startswith(expected_path + "."), (expected_path, rest)


def test_corruption_catalogue_covers_every_kind():
    kinds = {kind for ops in OPS.values() for op, _, kind in ops if op == "replace"}
    assert kinds == set(INVALID)
    assert {op for ops in OPS.values() for op, _, _ in ops} == {"add_key", "replace", "delete"}


def test_ellipsoid_type_is_the_geometry_one():
    cfg = load_config(CONFIGS / "doerr2021.yaml")
    assert all(isinstance(e, Ellipsoid) for e in cfg.scene().keep_out)
    assert isinstance(cfg, OacliConfig)


YAML_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=4) | st.integers(), inner, max_size=3),
    max_leaves=12,
)
ALL_PATHS = {name: [p for p, _ in _walk(data) if p] for name, data in PRESET_DATA.items()}


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_arbitrary_values_only_ever_raise_config_error(draw):
    """Whatever YAML-like value lands anywhere in a preset, the result is a config or a ConfigError."""
    preset = draw.draw(st.sampled_from(PRESET_NAMES), label="preset")
    data = copy.deepcopy(PRESET_DATA[preset])
    path = draw.draw(st.sampled_from(ALL_PATHS[preset]), label="path")
    _parent(data, path)[path[-1]] = draw.draw(YAML_VALUES, label="value")
    try:
        cfg = config_from_dict(data, source="fuzz")
    except ConfigError as exc:
        assert exc.problems and all(line.startswith("fuzz: ") and "\n" not in line for line in exc.problems)
    else:
        assert config_from_dict(yaml.safe_load(dump_config(cfg)), source="again") == cfg
