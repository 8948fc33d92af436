"""The mission's overhead paths: the in-place chunk parser of :mod:`oacli.io.mcap_walk` against the
``mcap`` package's stream reader, topic filtering that still counts and caps every message, stage configs derived
without the YAML text round trip, libyaml's emitter writing the same text, and stage configs remembered instead
of parsed again."""

from __future__ import annotations

import json
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.data_stream import RecordBuilder
from mcap.records import Channel, Chunk, Header, Schema
from mcap.writer import CompressionType, Writer

import oacli.config as config_module
from oacli.config import config_from_dict, dump_config, load_config
from oacli.errors import InputError
from oacli.io import mcap_walk
from oacli.io.mcap_read import read_stage, read_telemetry
from oacli.mission import records
from oacli.mission.configs import Handoff, stage_config
from oacli.mission.run import mission_stages
from tests.conftest import REPO

MAGIC = b"\x89MCAP0\r\n"
MISSION = REPO / "configs" / "mission_iss.yaml"


def _sample(t: float, rng: np.random.Generator) -> dict:
    return {"t": t, "position": rng.normal(size=3).tolist(), "velocity": rng.normal(size=3).tolist(),
            "quaternion": [0.0, 0.0, 0.0, 1.0], "angular_velocity": rng.normal(size=3).tolist(),
            "force": rng.normal(size=3).tolist(), "torque": rng.normal(size=3).tolist()}


def _three_topic_mcap(path: Path, n: int = 700, chunk_size: int = 4096) -> tuple[Path, np.ndarray]:
    """Two TrajectorySample topics and one plain JSON topic interleaved over many small zstd chunks."""
    rng = np.random.default_rng(7)
    positions = []
    with open(path, "wb") as f:
        writer = Writer(f, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        writer.start(profile="", library="oacli tests")
        sid = writer.register_schema("oacli.TrajectorySample", "jsonschema", b"{}")
        other = writer.register_schema("oacli.Stats", "jsonschema", b"{}")
        ch = {topic: writer.register_channel(topic, "json", sid) for topic in ("/state/true", "/reference")}
        stats = writer.register_channel("/solver/stats", "json", other)
        for i in range(n):
            sample = _sample(0.01 * i, rng)
            positions.append(sample["position"])
            t_ns = i * 10_000_000
            writer.add_message(ch["/state/true"], t_ns, json.dumps(sample).encode(), t_ns, sequence=i)
            if i % 3 == 0:
                writer.add_message(ch["/reference"], t_ns, json.dumps(_sample(0.01 * i, rng)).encode(), t_ns)
                writer.add_message(stats, t_ns, json.dumps({"t": 0.01 * i, "iterations": i}).encode(), t_ns)
        writer.finish()
    return path, np.array(positions)


def _records_equal(a, b) -> None:
    assert a.topics == b.topics and a.message_counts == b.message_counts and a.json_records == b.json_records
    assert a.truncated == b.truncated and a.bytes_read == b.bytes_read
    assert set(a.trajectories) == set(b.trajectories)
    for topic, traj in a.trajectories.items():
        np.testing.assert_array_equal(traj.t, b.trajectories[topic].t)
        np.testing.assert_array_equal(traj.x, b.trajectories[topic].x)


def test_in_place_chunk_parser_reads_what_the_stream_reader_reads(tmp_path, monkeypatch):
    path, positions = _three_topic_mcap(tmp_path / "three.mcap")
    fast = read_stage(path)
    monkeypatch.setattr(mcap_walk, "IN_PLACE_CHUNKS", False)
    slow = read_stage(path)
    _records_equal(fast, slow)
    assert fast.message_counts == {"/reference": 234, "/solver/stats": 234, "/state/true": 700}
    np.testing.assert_array_equal(fast.trajectories["/state/true"].x[:, 0:3], positions)
    assert mcap_walk.McapWalk(path).run().chunks > 10  # many chunks were parsed


def test_topic_filter_decodes_only_wanted_topics_and_still_counts_all(tmp_path):
    path, positions = _three_topic_mcap(tmp_path / "three.mcap")
    seen = []
    result = mcap_walk.McapWalk(path, seen.append, topics=["/solver/stats"]).run()
    assert result.ok and result.messages == 700 + 2 * 234
    assert sum(type(r).__name__ == "Message" for r in seen) == 234
    record = read_stage(path, topics=["/state/true"])
    assert set(record.trajectories) == {"/state/true"} and record.json_records == {}
    assert record.message_counts == {"/reference": 234, "/solver/stats": 234, "/state/true": 700}
    np.testing.assert_array_equal(record.trajectories["/state/true"].x[:, 0:3], positions)


def test_topic_filter_keeps_the_per_topic_cap(tmp_path, monkeypatch):
    path, _ = _three_topic_mcap(tmp_path / "three.mcap")
    monkeypatch.setattr(mcap_walk, "MAX_MESSAGES_PER_TOPIC", 500)
    monkeypatch.setattr(mcap_walk.McapWalk, "_statistics_too_large", lambda self: False)
    monkeypatch.setattr(mcap_walk.McapWalk, "_counted_too_large", lambda self: False)
    with pytest.raises(InputError, match="/state/true: more than 500 messages"):
        read_stage(path, topics=["/solver/stats"])  # the capped topic is not even wanted


def _chunk_file(path: Path, inner: bytes) -> Path:
    """A file of one uncompressed chunk holding a schema, a channel (id 1) and ``inner``, its CRC correct."""
    head = RecordBuilder()
    Schema(id=1, name="oacli.Stats", encoding="jsonschema", data=b"{}").write(head)
    Channel(id=1, topic="/x", message_encoding="json", schema_id=1, metadata={}).write(head)
    raw = head.end() + inner
    body = RecordBuilder()
    Header(profile="", library="oacli tests").write(body)
    Chunk(compression="", data=raw, message_start_time=0, message_end_time=0, uncompressed_crc=zlib.crc32(raw),
          uncompressed_size=len(raw)).write(body)
    path.write_bytes(MAGIC + body.end())
    return path


def _message(channel: int, data: bytes, length: int | None = None) -> bytes:
    body = channel.to_bytes(2, "little") + (0).to_bytes(4, "little") + (5).to_bytes(8, "little") * 2 + data
    return b"\x05" + (len(body) if length is None else length).to_bytes(8, "little") + body


@pytest.mark.parametrize("in_place", [True, False])
@pytest.mark.parametrize(("inner", "reason"), [
    (_message(1, b"{}", length=200), "ends inside a record"),
    (_message(1, b"{}") + b"\x05\x00", "ends inside a record"),
    (_message(1, b"", length=10) + b"\x00" * 10, "corrupt record"),
    (_message(9, b"{}"), "unknown channel id 9"),
])
def test_a_chunk_with_a_bad_inner_record_is_refused_naming_it(tmp_path, monkeypatch, inner, reason, in_place):
    monkeypatch.setattr(mcap_walk, "IN_PLACE_CHUNKS", in_place)
    path = _chunk_file(tmp_path / "bad.mcap", inner)
    with pytest.raises(InputError, match=reason if in_place else None):
        read_stage(path)  # (the former parser words these differently; a short message fails as bad JSON)


def test_a_good_hand_built_chunk_reads_its_message(tmp_path):
    path = _chunk_file(tmp_path / "good.mcap", _message(1, b'{"a": 1}'))
    record = read_stage(path)
    assert record.json_records == {"/x": ({"a": 1},)} and record.truncated


def _mission_stage_configs():
    cfg = load_config(MISSION)
    return cfg, [(s, stage_config(cfg, s, Handoff(reference=Path("/r.mcap") if s.command == "track" else None)))
                 for s in mission_stages(cfg)]


def test_stage_configs_equal_those_of_the_yaml_round_trip():
    """stage_config starts from ``cfg.model_dump(mode="json")``, formerly ``yaml.safe_load(dump_config(cfg))``."""
    cfg, stages = _mission_stage_configs()
    for c in [cfg, *(s for _, s in stages)]:
        assert c.model_dump(mode="json") == yaml.safe_load(dump_config(c))
    for _, derived in stages:
        assert derived.mission is None and derived.name.startswith(cfg.name)
        assert load_config_text(dump_config(derived)) == derived


def load_config_text(text: str):
    return config_from_dict(yaml.safe_load(text))


def test_libyaml_dumper_writes_the_same_text():
    cfg, stages = _mission_stage_configs()
    assert config_module._DUMPER is not config_module._FlowVectorDumper or not hasattr(yaml, "CSafeDumper")
    for c in [cfg, *(s for _, s in stages), load_config(REPO / "configs" / "iss_reswarm.yaml")]:
        fast = dump_config(c)
        pure = "# " + fast.split("\n", 1)[0][2:] + "\n" + yaml.dump(
            c.model_dump(mode="json"), Dumper=config_module._FlowVectorDumper, sort_keys=False,
            default_flow_style=False, allow_unicode=True)
        assert fast == pure


def test_remembered_config_is_returned_only_for_its_exact_text(tmp_path):
    _, stages = _mission_stage_configs()
    cfg = stages[-1][1]
    path = tmp_path / "config.yaml"
    path.write_text(dump_config(cfg), encoding="utf-8")
    records.clear_cache()
    try:
        assert records.remember_config(path, cfg)
        assert records.load_config_cached(path) is cfg
        assert load_config(path) == cfg  # what parsing would have given
        other = stages[0][1]
        assert not records.remember_config(path, other)  # text differs: not remembered
        path.write_text(dump_config(cfg) + "# edited\n", encoding="utf-8")  # new file: parsed again
        assert records.load_config_cached(path) is not cfg and records.load_config_cached(path) == cfg
    finally:
        records.clear_cache()


def test_telemetry_and_records_share_one_read_of_a_track(tmp_path, monkeypatch):
    path, _ = _three_topic_mcap(tmp_path / "three.mcap")
    calls = []
    real = records.read_stage
    monkeypatch.setattr(records, "read_stage", lambda p, **kw: calls.append(p) or real(p, **kw))
    records.clear_cache()
    try:
        with pytest.raises(InputError, match="/state/measured"):  # not a full track: the same error as uncached
            records.read_telemetry_cached(path)
        with pytest.raises(InputError, match="/state/measured"):
            read_telemetry(path)
        records.stage_record(path, "track")
        assert len(calls) == 1
    finally:
        records.clear_cache()
