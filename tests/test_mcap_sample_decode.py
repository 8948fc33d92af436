"""The reader's one-pass decode of sample records in the writer's template (``oacli.io.mcap_read.FAST_SAMPLES``)
gives exactly what decoding every record with ``json.loads`` gives, and records in any other JSON form are still read
(through ``json.loads``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import Writer

import oacli.io.mcap_read as mcap_read
from oacli.io import mcap_schema as ms
from oacli.io.mcap_io import StageMcapWriter, read_stage, read_telemetry
from tests.test_mcap_io import CONFIG, random_trajectory


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=float).view(np.uint64)


def _read_both(path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple:
    monkeypatch.setattr(mcap_read, "FAST_SAMPLES", False)
    slow = read_stage(path)
    monkeypatch.setattr(mcap_read, "FAST_SAMPLES", True)
    calls = []
    real = mcap_read._json_messages
    monkeypatch.setattr(mcap_read, "_json_messages", lambda scan, topic: calls.append(topic) or real(scan, topic))
    fast = read_stage(path)
    return slow, fast, calls


def _assert_same(slow, fast) -> None:
    assert slow.trajectories.keys() == fast.trajectories.keys()
    for topic, a in slow.trajectories.items():
        b = fast.trajectories[topic]
        for field in ("t", "x", "u"):  # bit for bit: -0.0, subnormals, extremes
            np.testing.assert_array_equal(_bits(getattr(a, field)), _bits(getattr(b, field)))
        assert (a.name, a.frame) == (b.name, b.frame)
    assert slow.wrenches.keys() == fast.wrenches.keys()
    for topic, (t_a, w_a) in slow.wrenches.items():
        t_b, w_b = fast.wrenches[topic]
        np.testing.assert_array_equal(_bits(t_a), _bits(t_b))
        np.testing.assert_array_equal(_bits(w_a), _bits(w_b))
        assert not t_b.flags.writeable and not w_b.flags.writeable
    for field in ("json_records", "metadata", "attachments", "topics", "message_counts", "log", "truncated"):
        assert getattr(slow, field) == getattr(fast, field)


def test_template_records_decode_bit_for_bit_as_json_does(tmp_path, monkeypatch):
    rng = np.random.default_rng(11)
    traj = random_trajectory(rng, n=300)
    x = traj.x.copy()
    # Values whose text forms differ: -0.0, the smallest subnormal, the largest float, integral values (repr
    # "3.0", "1e+16"), many digits.
    x[0, 0:6] = [-0.0, 5e-324, 1.7976931348623157e308, 3.0, 1e16, 0.1 + 0.2]
    t_w = np.arange(50) * 0.1
    wrench = rng.normal(size=(50, 6)) * 1e-7
    wrench[3] = [0.0, -0.0, 1e-310, -2.5e-5, 7.0, -1e22]
    path = tmp_path / "plan.mcap"
    with StageMcapWriter(path, stage="track", config_yaml=CONFIG) as w:
        w.write_states("/state/true", traj.t, x, traj.u, name="flown", frame="iss")
        w.write_states("/state/true", traj.t[-1] + 1.0 + t_w, rng.normal(size=(50, 13)), frame="iss")  # a second call
        w.write_wrenches("/disturbance", t_w, wrench)
        w.write_log(0.0, "info", "hello")
    slow, fast, calls = _read_both(path, monkeypatch)
    _assert_same(slow, fast)
    assert calls == []  # both sample topics took the one-pass decode
    assert fast.trajectories["/state/true"].x[0, 0] == 0.0 and np.signbit(fast.trajectories["/state/true"].x[0, 0])
    assert fast.trajectories["/state/true"].x[0, 1] == 5e-324
    np.testing.assert_array_equal(fast.trajectories["/state/true"].x[:300], x)  # what was written


def _raw_file(path: Path, payloads: dict[str, list[bytes]]) -> None:
    """A stage MCAP written with the ``mcap`` package: sample topics with hand-made JSON payloads."""
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start()
        writer.add_metadata("oacli", {"stage": "track"})
        for k, (topic, messages) in enumerate(payloads.items(), start=1):
            schema_name = ms.WRENCH if topic == "/disturbance" else ms.TRAJECTORY_SAMPLE
            schema = writer.register_schema(schema_name, "jsonschema",
                                            json.dumps({"title": schema_name, "type": "object"}).encode())
            channel = writer.register_channel(topic, "json", schema, {"frame": "world", "name": topic.strip("/")})
            for i, data in enumerate(messages):
                writer.add_message(channel, log_time=i * 1000 + k, data=data, publish_time=i * 1000 + k)
        writer.finish()


def _sample(t: float, **override: object) -> dict:
    record = {"t": t, "position": [1.0, 2.0, 3.0], "velocity": [0.0, 0.0, 0.0], "quaternion": [0.0, 0.0, 0.0, 1.0],
              "angular_velocity": [0.0, 0.0, 0.0], "force": [0.0, 0.0, 0.0], "torque": [0.0, 0.0, 0.0]}
    record.update(override)
    return record


@pytest.mark.parametrize("odd", [
    json.dumps(_sample(0.5)).encode(),  # json.dumps' spaces
    json.dumps(_sample(0.5, position=[1, -0, 3])).encode(),  # integers, "-0" (JSON reads it as the integer 0)
    json.dumps({"position": [1.0, 2.0, 3.0], **_sample(0.5)}, separators=(",", ":")).encode(),  # another key order
    json.dumps(_sample(0.5), separators=(",", ":")).encode() + b"\n",  # a line break
    json.dumps(_sample(0.5, extra=1.0), separators=(",", ":")).encode(),  # an extra field
])
def test_records_in_another_json_form_are_read_through_json(tmp_path, monkeypatch, odd):
    template = [json.dumps(_sample(t), separators=(",", ":")).encode() for t in (0.0, 0.25)]
    wrench = [b'{"t":%r,"force":[1.0,2.0,3.0],"torque":[4.0,5.0,6.0]}' % t for t in (0.0, 0.25)]
    path = tmp_path / "track.mcap"
    _raw_file(path, {"/state/true": [*template, odd], "/disturbance": wrench})
    slow, fast, calls = _read_both(path, monkeypatch)
    _assert_same(slow, fast)
    assert calls == ["/state/true"]  # the odd record sends its topic through json.loads; the template one does not
    true = fast.trajectories["/state/true"]
    np.testing.assert_array_equal(true.t, [0.0, 0.25, 0.5])
    expected = np.array(json.loads(odd)["position"], dtype=float)
    np.testing.assert_array_equal(_bits(true.x[2, 0:3]), _bits(expected))
    assert not np.any(np.signbit(true.x[2, 0:3]))  # "-0" is the integer 0 for JSON, not -0.0


def test_a_malformed_record_is_still_reported_by_its_index(tmp_path):
    good = json.dumps(_sample(0.0), separators=(",", ":")).encode()
    path = tmp_path / "track.mcap"
    _raw_file(path, {"/state/true": [good, good[:-1] + b",", good]})
    with pytest.raises(Exception, match=r"message 1 on /state/true is not valid JSON"):
        read_stage(path)


def test_a_mission_track_file_reads_the_same_telemetry_both_ways(tmp_path, monkeypatch):
    rng = np.random.default_rng(3)
    n = 40
    t = np.arange(n) * 0.2
    x = rng.normal(size=(n, 13))
    u = rng.normal(size=(n, 6))
    path = tmp_path / "track.mcap"
    with StageMcapWriter(path, stage="track", config_yaml=CONFIG) as w:
        w.write_states(ms.TOPIC_STATE_TRUE, t, x)
        w.write_states(ms.TOPIC_STATE_MEASURED, t, x)
        w.write_states(ms.TOPIC_REFERENCE, t, x)
        w.write_wrenches(ms.TOPIC_CONTROL_COMMAND, t, u)
        w.write_wrenches(ms.TOPIC_CONTROL_APPLIED, t, u)
    monkeypatch.setattr(mcap_read, "FAST_SAMPLES", False)
    slow = read_telemetry(path)
    monkeypatch.setattr(mcap_read, "FAST_SAMPLES", True)
    fast = read_telemetry(path)
    for field in ("t_true", "x_true", "t_ctrl", "x_measured", "x_reference", "u_command", "u_applied"):
        np.testing.assert_array_equal(_bits(getattr(slow, field)), _bits(getattr(fast, field)))
    np.testing.assert_array_equal(fast.u_applied, u)
