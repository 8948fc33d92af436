"""Foxglove users start from a layout: every shipped layout names only topics and message paths
that exist in the MCAP it is for (a stage of the shrunk default mission, or its ``mission.mcap``); the mission-level
MCAP validates like the stage files and puts each stage on the mission clock; ``/scene`` holds the tube
cross-sections and the planner tree."""

from __future__ import annotations

import json
import re
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from scipy.optimize import linprog

from oacli.io import mcap_schema as ms
from oacli.io.foxglove_layouts import LAYOUT_FILES
from oacli.mission.foxglove import write_layouts
from oacli.mission.layout import MISSION_STAGES, OPTIONAL_STAGES, stage_by_key
from tests.mcap_checks import check_json_records, scene_updates

DOCS = Path(__file__).resolve().parents[1] / "docs" / "foxglove"
_INDEX = re.compile(r"^\.(\w+)((?:\[\d+\])*)")


@pytest.fixture(scope="module")
def mission_dir(mission_run) -> Path:
    return mission_run[0]


def _target(mission_dir: Path, name: str) -> Path:
    key = LAYOUT_FILES[name]
    return mission_dir / "mission.mcap" if key == "mission" else stage_by_key(key).mcap(mission_dir)


def _first_messages(path: Path) -> dict[str, tuple[str, str, tuple]]:
    """Per topic: schema name, encoding and its first three messages decoded (JSON as dicts, protobuf as messages)."""
    from mcap_protobuf.decoder import DecoderFactory

    out: dict[str, tuple[str, str, tuple]] = {}
    factory = DecoderFactory()
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f, validate_crcs=True).iter_messages(log_time_order=False):
            if len(out.get(channel.topic, (0, 0, ()))[2]) >= 3:
                continue
            if channel.message_encoding == "json":
                value = json.loads(message.data)
            else:
                value = factory.decoder_for(channel.message_encoding, schema)(message.data)
            kept = out.get(channel.topic, (schema.name, channel.message_encoding, ()))[2]
            out[channel.topic] = (schema.name, channel.message_encoding, (*kept, value))
    return out


def _names(layout: dict) -> tuple[set[str], set[str], list[str]]:
    """Scene-panel topics, other topics and message paths a layout names."""
    scene_topics, topics, paths = set(), set(), []
    for panel_id, config in layout["configById"].items():
        kind = panel_id.split("!")[0]
        if kind == "3D":
            scene_topics |= set(config["topics"])
            assert config["followTf"] == "iss"
        elif kind == "Plot":
            paths += [p["value"] for p in config["paths"]]
            if "xAxisPath" in config:
                paths.append(config["xAxisPath"]["value"])
        elif kind == "RawMessages":
            topics.add(config["topicPath"])
        elif kind == "RosOut":
            topics.add(config["topicToRender"])
        else:
            raise AssertionError(f"unexpected panel {panel_id}")
    return scene_topics, topics, paths


def _resolve(path: str, messages: dict[str, tuple[str, str, tuple]]) -> float:
    """The number a message path points at in the first of its topic's messages where it is a number (every message
    tried must have each part of the path)."""
    topic = max((t for t in messages if path.startswith(t + ".")), key=len, default=None)
    assert topic is not None, f"{path}: no topic of the file is a prefix"
    values = [_walk(path, message, path[len(topic):]) for message in messages[topic][2]]
    numbers = [v for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)]
    assert numbers, f"{path}: {values!r} holds no number"
    return float(numbers[0])


def _walk(path: str, value: object, rest: str) -> object:
    while rest:
        match = _INDEX.match(rest)
        assert match, f"{path}: cannot parse {rest!r}"
        field, indexes = match.group(1), [int(i) for i in re.findall(r"\d+", match.group(2))]
        value = value[field] if isinstance(value, dict) else getattr(value, field)
        for i in indexes:
            value = value[i]
        rest = rest[match.end():]
    return value


def test_shipped_layouts_are_the_generated_ones(tmp_path):
    written = write_layouts(tmp_path)
    assert sorted(p.name for p in DOCS.glob("*.json")) == sorted(p.name for p in written)
    assert {p.stem for p in written} == set(LAYOUT_FILES)
    for p in written:
        assert json.loads((DOCS / p.name).read_text()) == json.loads(p.read_text()), p.name


@pytest.mark.parametrize("name", sorted(LAYOUT_FILES))
def test_every_topic_and_message_path_of_a_layout_exists_in_its_mcap(mission_dir, name):
    layout = json.loads((DOCS / f"{name}.json").read_text())
    messages = _first_messages(_target(mission_dir, name))
    check_layout(name, layout, messages, skip=tuple(f"/{s.key}/" for s in OPTIONAL_STAGES))


def check_layout(name: str, layout: dict, messages: dict, skip: tuple[str, ...] = ()) -> None:
    """Every topic and message path ``layout`` names is in ``messages`` (of its MCAP), but those starting with one of
    ``skip`` (an optional stage the mission did not fly: ``tests/test_mission_unconstrained_outputs.py`` checks its
    names in a mission that did)."""
    scene_topics, topics, paths = _names(layout)
    scene_topics = {t for t in scene_topics if not t.startswith(skip)}
    topics = {t for t in topics if not t.startswith(skip)}
    paths = [p for p in paths if not p.startswith(skip)]
    assert scene_topics and paths
    for topic in scene_topics:
        assert topic in messages, f"{name}: 3D topic {topic} not in the file"
        assert messages[topic][0] in ("foxglove.SceneUpdate", "foxglove.PoseInFrame"), topic
    for topic in topics:
        assert topic in messages, f"{name}: topic {topic} not in the file"
    for path in paths:
        assert np.isfinite(_resolve(path, messages)), path


def _first_log_times(path: Path) -> dict[str, int]:
    out: dict[str, int] = {}
    with path.open("rb") as f:
        for _, channel, message in make_reader(f, validate_crcs=True).iter_messages(log_time_order=False):
            out[channel.topic] = min(out.get(channel.topic, message.log_time), message.log_time)
    return out


def test_mission_mcap_validates_and_runs_on_the_mission_clock(mission_dir):
    summary = json.loads((mission_dir / "summary.json").read_text())
    mission = mission_dir / "mission.mcap"
    counts = check_json_records(mission)
    expected: Counter[str] = Counter()
    mission_first = _first_log_times(mission)
    for stage in MISSION_STAGES:
        expected += check_json_records(stage.mcap(mission_dir))
        start_ns = round(summary["segments"][stage.segment]["start_time_s"] * 1e9)
        for topic, t0 in _first_log_times(stage.mcap(mission_dir)).items():
            if topic != ms.TOPIC_LOG:
                assert mission_first[f"/{stage.key}{topic}"] == t0 + start_ns, (stage.key, topic)
    assert counts == expected  # every JSON record of every stage, each valid against the contract
    assert summary["segments"]["segment-3"]["start_time_s"] > 0
    with mission.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        info = next(m.metadata for m in reader.iter_metadata() if m.name == "oacli")
        assert info["stage"] == "mission" and info["frame"] == "iss"
        times = [m.log_time for _, _, m in reader.iter_messages(log_time_order=False)]
        assert times == sorted(times)  # written merged by time


def _support(normals: np.ndarray, offsets: np.ndarray, direction: np.ndarray) -> float:
    """max dᵀe over {e : H e <= h} (an LP, independent of the tube code)."""
    res = linprog(-direction, A_ub=normals, b_ub=offsets, bounds=[(None, None)] * len(direction))
    assert res.status == 0
    return float(-res.fun)


def test_scene_holds_the_tube_cross_sections_and_the_planner_tree(mission_dir):
    track = stage_by_key("segment-2/track").mcap(mission_dir)
    with track.open("rb") as f:
        reader = make_reader(f)
        designs = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=[ms.TOPIC_TUBE_DESIGN])]
        nominal = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=[ms.TOPIC_STATE_NOMINAL])]
        steps = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=[ms.TOPIC_TUBE_DISTURBANCE])]
    updates = scene_updates(track)
    sections = [e for _, u in updates for e in u.entities if e.id == "tube/sections"]
    now = [(t, e) for t, u in updates for e in u.entities if e.id == "tube/now"]
    assert len(sections) == 1 and len(now) == len(nominal) == len(steps)
    (lines,) = sections[0].lines
    assert len(lines.points) == 24 * len(nominal)  # 12 edges of one box per step
    for k in (0, len(nominal) // 2, len(nominal) - 1):
        axes = designs[steps[k]["design"]]["axes"]
        z = np.asarray(nominal[k]["position"])
        # The tube promised for the true state (Z; T with the default mission's observer), drawn around z.
        lo = np.array([-_support(np.asarray(a["promise_normals"]), np.asarray(a["promise_offsets"]),
                                 np.array([-1.0, 0.0])) for a in axes])
        hi = np.array([_support(np.asarray(a["promise_normals"]), np.asarray(a["promise_offsets"]),
                                np.array([1.0, 0.0])) for a in axes])
        t_ns, entity = now[k]
        assert t_ns == round(nominal[k]["t"] * 1e9)
        (cube,) = entity.cubes
        c, s = cube.pose.position, cube.size
        np.testing.assert_allclose([c.x, c.y, c.z], z + 0.5 * (lo + hi), atol=1e-7)
        np.testing.assert_allclose([s.x, s.y, s.z], hi - lo, atol=1e-7)
        box = np.array([[p.x, p.y, p.z] for p in lines.points[24 * k: 24 * (k + 1)]])
        np.testing.assert_allclose(box.min(axis=0), z + lo, atol=1e-7)
        np.testing.assert_allclose(box.max(axis=0), z + hi, atol=1e-7)

    plan = stage_by_key("segment-1/plan").mcap(mission_dir)
    with plan.open("rb") as f:
        nodes = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=[ms.TOPIC_PLAN_TREE])]
    trees = [e for _, u in scene_updates(plan) for e in u.entities if e.id == "plan/tree"]
    assert len(trees) == 1
    points = np.array([[p.x, p.y, p.z] for line in trees[0].lines for p in line.points])
    on_path = np.array([[p.x, p.y, p.z] for line in trees[0].lines if line.thickness > 1.0 for p in line.points])
    for node in nodes:
        if node["parent"] < 0:
            continue
        pos = np.asarray(node["position"])  # each edge ends at its node
        assert np.min(np.linalg.norm(points - pos, axis=1)) < 1e-9, node["node"]
        if node["in_path"]:
            assert np.min(np.linalg.norm(on_path - pos, axis=1)) < 1e-9, node["node"]
