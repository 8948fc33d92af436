"""Tests of the MCAP contract: oacli.io.mcap_io writer and readers."""

from __future__ import annotations

import io
import json
import zlib
from pathlib import Path

import numpy as np
import pytest
import zstandard
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Chunk, DataEnd
from mcap.stream_reader import StreamReader
from mcap_protobuf.decoder import DecoderFactory

from oacli.errors import InputError
from oacli.geometry import Box, Ellipsoid, Scene
from oacli.io.mcap_io import (
    StageMcapWriter,
    read_stage,
    read_telemetry,
    read_trajectory,
)
from oacli.model.quaternion import from_rotation_matrix
from oacli.types import SolveInfo, Trajectory

CONFIG = "robot:\n  mass_kg: 9.58\nseed: 7\n"


def random_trajectory(rng: np.random.Generator, n: int = 200, name: str = "plan", frame: str = "iss") -> Trajectory:
    t = np.cumsum(rng.uniform(0.001, 0.2, n)) + rng.uniform(0.0, 3.0)
    x = rng.normal(size=(n, 13)) * rng.choice([1e-12, 1.0, 1e6], size=(n, 13))
    q = rng.normal(size=(n, 4))
    x[:, 6:10] = q / np.linalg.norm(q, axis=1, keepdims=True)
    u = rng.normal(size=(n, 6)) / 3.0
    return Trajectory(t=t, x=x, u=u, name=name, frame=frame)


def writer(path: Path, **kwargs) -> StageMcapWriter:
    return StageMcapWriter(
        path,
        stage="plan",
        config_yaml=CONFIG,
        metadata={"seed": 7, "git_commit": "abc123"},
        **kwargs,
    )


def top_level_records(data: bytes) -> list[tuple[int, int, int]]:
    """``(opcode, offset, length)`` of every top-level record after the magic."""
    out, pos = [], 8
    while pos + 9 <= len(data):
        length = int.from_bytes(data[pos + 1 : pos + 9], "little")
        out.append((data[pos], pos, length))
        pos += 9 + length
    return out


def decoded(path: Path, topic: str) -> list:
    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        return [(m.log_time, proto) for _, _, m, proto in reader.iter_decoded_messages(topics=[topic])]


def bits(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype=np.float64).tobytes()


# ----------------------------------------------------------------------------------------------------------
# Round trips
# ----------------------------------------------------------------------------------------------------------


def test_trajectory_round_trip_is_bit_exact(tmp_path, rng):
    traj = random_trajectory(rng)
    # awkward floats: shortest repr, tiny, huge, subnormal, negative zero
    x = traj.x.copy()
    x[0, :6] = [0.1, 1e-300, 1.7976931348623157e308, 5e-324, -0.0, 1 / 3]
    traj = Trajectory(t=traj.t, x=x, u=traj.u, name=traj.name, frame=traj.frame)
    path = tmp_path / "plan.mcap"
    with writer(path) as w:
        w.write_trajectory("/trajectory", traj)
    back = read_trajectory(path)
    assert bits(back.t) == bits(traj.t)
    assert bits(back.x) == bits(traj.x)
    assert bits(back.u) == bits(traj.u)
    assert (back.name, back.frame) == ("plan", "iss")
    record = read_stage(path, validate_crcs=True)
    assert not record.truncated
    assert record.topics == {"/trajectory": "oacli.TrajectorySample"}
    assert bits(record.trajectories["/trajectory"].x) == bits(traj.x)


def test_message_times_and_interop_with_mcap_reader(tmp_path, rng):
    traj = random_trajectory(rng, n=50)
    path = tmp_path / "plan.mcap"
    with writer(path) as w:
        w.write_trajectory("/trajectory", traj)
    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        messages = list(reader.iter_messages(topics=["/trajectory"]))
    schema, channel, _ = messages[0]
    assert schema.name == "oacli.TrajectorySample"
    assert schema.encoding == "jsonschema"
    assert channel.message_encoding == "json"
    assert channel.metadata == {"frame": "iss", "name": "plan"}
    assert json.loads(schema.data)["properties"]["position"]["maxItems"] == 3
    expected_ns = [round(t * 1e9) for t in traj.t.tolist()]
    assert [m.log_time for _, _, m in messages] == expected_ns
    assert [m.publish_time for _, _, m in messages] == expected_ns
    first = json.loads(messages[0][2].data)
    assert set(first) == {"t", "position", "velocity", "quaternion", "angular_velocity", "force", "torque"}
    assert first["quaternion"] == traj.x[0, 6:10].tolist()
    assert summary.statistics.message_count == len(traj)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    values=st.lists(st.floats(allow_nan=False, allow_infinity=False, width=64), min_size=19 * 3, max_size=19 * 3),
    t0=st.floats(min_value=0.0, max_value=1e6, allow_nan=False),
)
def test_any_finite_float_round_trips_exactly(tmp_path, values, t0):
    arr = np.array(values).reshape(3, 19)
    t = t0 + np.array([0.0, 0.5, 1.25])
    path = tmp_path / "prop.mcap"
    with writer(path, overwrite=True) as w:
        w.write_states("/s", t, arr[:, :13], arr[:, 13:])
    back = read_stage(path).trajectories["/s"]
    assert bits(back.t) == bits(t)
    assert bits(back.x) == bits(arr[:, :13])
    assert bits(back.u) == bits(arr[:, 13:])


def test_states_without_input_write_zero_wrench_and_topic_continues(tmp_path, rng):
    x = rng.normal(size=(20, 13))
    path = tmp_path / "a.mcap"
    with writer(path) as w:
        w.write_states("/state/true", np.arange(10) * 0.1, x[:10])
        w.write_states("/state/true", 1.0 + np.arange(10) * 0.1, x[10:])
        with pytest.raises(ValueError, match="continue after"):
            w.write_states("/state/true", [1.5], x[:1])
    traj = read_stage(path).trajectories["/state/true"]
    assert np.array_equal(traj.x, x)
    assert np.array_equal(traj.u, np.zeros((20, 6)))
    assert traj.name == "state/true"


def test_times_must_be_non_negative_and_increasing(tmp_path, rng):
    x = rng.normal(size=(3, 13))
    with writer(tmp_path / "a.mcap") as w:
        with pytest.raises(ValueError, match=">= 0"):
            w.write_states("/s", [-0.1, 0.0, 0.1], x)
        with pytest.raises(ValueError, match="strictly increasing"):
            w.write_states("/s", [0.0, 0.2, 0.2], x)
        with pytest.raises(ValueError, match=">= 0"):
            w.write_json("/j", "oacli.Thing", {"type": "object"}, -1.0, {})
        with pytest.raises(ValueError, match="NaN"):
            w.write_states("/s", [0.0, 0.1, 0.2], np.full((3, 13), np.nan))
        w.write_states("/s", [0.0], x[:1])
        with pytest.raises(ValueError, match=r"carries oacli\.TrajectorySample"):
            w.write_json("/s", "oacli.Thing", {"type": "object"}, 1.0, {})


def test_solver_stats_json_records_and_log_round_trip(tmp_path):
    infos = [
        SolveInfo("optimal", True, 12.5, 7, 0.0021, 0.0034),
        SolveInfo("infeasible", False),  # NaN objective and times -> null
    ]
    path = tmp_path / "track.mcap"
    with writer(path) as w:
        w.write_solver_stats(np.array([0.0, 0.2]), infos)
        w.write_json(
            "/estimate",
            "oacli.ParameterEstimate",
            {"type": "object", "properties": {"mass_kg": {"type": "number"}}},
            3.5,
            {"mass_kg": np.float64(9.6), "cov": np.eye(2), "bad": float("nan")},
        )
        w.write_log(0.5, "info", "tracking started")
        w.write_log(2.0, "WARNING", "solver infeasible; fallback")
        with pytest.raises(ValueError, match="unknown log level"):
            w.write_log(2.0, "loud", "x")
    rec = read_stage(path)
    assert rec.solver_stats == (
        {
            "t": 0.0,
            "status": "optimal",
            "success": True,
            "objective": 12.5,
            "iterations": 7,
            "solve_time_ms": 2.1,
            "step_time_ms": 3.4,
        },
        {
            "t": 0.2,
            "status": "infeasible",
            "success": False,
            "objective": None,
            "iterations": -1,
            "solve_time_ms": None,
            "step_time_ms": None,
        },
    )
    assert rec.json_records["/estimate"] == ({"t": 3.5, "mass_kg": 9.6, "cov": [[1.0, 0.0], [0.0, 1.0]], "bad": None},)
    assert rec.topics["/estimate"] == "oacli.ParameterEstimate"
    assert rec.log == ((0.5, "info", "tracking started"), (2.0, "warning", "solver infeasible; fallback"))
    # cross-check the hand-rolled Log decoding against the protobuf decoder
    logs = decoded(path, "/log")
    assert [(p.level, p.message, p.name) for _, p in logs] == [
        (2, "tracking started", "plan"),
        (3, "solver infeasible; fallback", "plan"),
    ]
    assert logs[1][1].timestamp.seconds == 2 and logs[1][1].timestamp.nanos == 0


def test_telemetry_round_trip(tmp_path, rng):
    m, k = 40, 10
    t_true = np.arange(m) * 0.016
    t_ctrl = t_true[::4]
    x_true, x_meas, x_ref = rng.normal(size=(m, 13)), rng.normal(size=(k, 13)), rng.normal(size=(k, 13))
    u_cmd, u_app, dist = rng.normal(size=(k, 6)), rng.normal(size=(k, 6)), rng.normal(size=(k, 6))
    infos = [SolveInfo("optimal", True, float(i), i, 1e-3, 2e-3) for i in range(k)]
    path = tmp_path / "track.mcap"
    with writer(path) as w:
        w.write_states("/state/true", t_true, x_true)
        w.write_states("/state/measured", t_ctrl, x_meas)
        w.write_states("/reference", t_ctrl, x_ref)
        w.write_states("/control/command", t_ctrl, x_meas, u_cmd)
        w.write_wrenches("/control/applied", t_ctrl, u_app)  # a wrench topic is accepted too
        w.write_wrenches("/disturbance", t_ctrl, dist)
        w.write_solver_stats(t_ctrl, infos)
        w.write_poses(t_true, x_true)
    tel = read_telemetry(path)
    assert np.array_equal(tel.t_true, t_true) and np.array_equal(tel.x_true, x_true)
    assert np.array_equal(tel.t_ctrl, t_ctrl) and np.array_equal(tel.x_measured, x_meas)
    assert np.array_equal(tel.x_reference, x_ref)
    assert np.array_equal(tel.u_command, u_cmd) and np.array_equal(tel.u_applied, u_app)
    assert np.array_equal(tel.disturbance, dist)
    assert [s.objective for s in tel.solve_info] == list(range(k))
    assert tel.solve_info[3].solve_time_s == pytest.approx(1e-3, rel=1e-15)

    bad = tmp_path / "bad.mcap"
    with writer(bad) as w:
        w.write_states("/state/true", t_true, x_true)
        w.write_states("/state/measured", t_ctrl, x_meas)
        w.write_states("/reference", t_ctrl + 0.001, x_ref)
        w.write_states("/control/command", t_ctrl, x_meas, u_cmd)
        w.write_states("/control/applied", t_ctrl, x_meas, u_app)
    with pytest.raises(InputError, match="times of /reference differ"):
        read_telemetry(bad)


# ----------------------------------------------------------------------------------------------------------
# File integrity
# ----------------------------------------------------------------------------------------------------------


def test_file_has_small_zstd_chunks_with_crcs_and_a_data_section_crc(tmp_path, rng):
    path = tmp_path / "track.mcap"
    with writer(path, chunk_size=64 * 1024) as w:
        w.write_trajectory("/trajectory", random_trajectory(rng, n=2000))
    data = path.read_bytes()
    records = list(StreamReader(io.BytesIO(data), emit_chunks=True, validate_crcs=True).records)
    chunks = [r for r in records if isinstance(r, Chunk)]
    assert len(chunks) >= 5
    for chunk in chunks:
        assert chunk.compression == "zstd"
        assert chunk.uncompressed_crc != 0
        assert chunk.uncompressed_size <= 64 * 1024 + 1024
        assert zlib.crc32(zstandard.decompress(chunk.data, chunk.uncompressed_size)) == chunk.uncompressed_crc
    (data_end,) = [r for r in records if isinstance(r, DataEnd)]
    assert data_end.data_section_crc != 0
    (end_offset,) = [off for op, off, _ in top_level_records(data) if op == Opcode.DATA_END]
    assert data_end.data_section_crc == zlib.crc32(data[:end_offset])


def _chunk_payload_range(data: bytes) -> tuple[int, int, int]:
    """Byte range of the compressed records of the first chunk, and their uncompressed size."""
    for opcode, offset, length in top_level_records(data):
        if opcode == Opcode.CHUNK:
            body = offset + 9
            # start, end times, uncompressed size (8 bytes each), CRC (4), compression (4 + n), length (8)
            compression_len = int.from_bytes(data[body + 28 : body + 32], "little")
            start = body + 32 + compression_len + 8
            assert data[body + 32 : body + 32 + compression_len] == b"zstd"
            size = int.from_bytes(data[body + 16 : body + 24], "little")
            return start, offset + 9 + length, size
    raise AssertionError("no chunk")


def test_corrupt_byte_in_a_chunk_is_detected(tmp_path, rng):
    path = tmp_path / "plan.mcap"
    with writer(path) as w:
        w.write_trajectory("/trajectory", random_trajectory(rng, n=500))
    data = path.read_bytes()
    start, end, size = _chunk_payload_range(data)
    ok_flip = bad_flip = None
    for pos in range(start + 64, end, 97):
        corrupt = bytearray(data)
        corrupt[pos] ^= 0x01
        try:
            zstandard.decompress(bytes(corrupt[start:end]), size)
            ok_flip = ok_flip or bytes(corrupt)  # decompresses to wrong bytes: only the CRC can tell
        except zstandard.ZstdError:
            bad_flip = bad_flip or bytes(corrupt)
        if ok_flip and bad_flip:
            break
    assert ok_flip is not None and bad_flip is not None
    (tmp_path / "crc.mcap").write_bytes(ok_flip)
    with pytest.raises(InputError, match=r"CRC check .*corrupt") as err:
        read_stage(tmp_path / "crc.mcap", validate_crcs=True)
    assert "crc.mcap" in str(err.value)
    with pytest.raises(InputError, match="CRC"):
        read_trajectory(tmp_path / "crc.mcap")
    (tmp_path / "zstd.mcap").write_bytes(bad_flip)
    with pytest.raises(InputError, match="corrupt"):
        read_stage(tmp_path / "zstd.mcap")


def test_corruption_outside_chunks_is_caught_by_data_section_and_attachment_crcs(tmp_path, rng):
    path = tmp_path / "plan.mcap"
    with writer(path) as w:
        w.write_trajectory("/trajectory", random_trajectory(rng, n=300))
    data = path.read_bytes()
    frames = top_level_records(data)
    # a message index record (after a chunk) is covered only by the data-section CRC
    _, offset, length = next(f for f in frames if f[0] == Opcode.MESSAGE_INDEX)
    corrupt = bytearray(data)
    corrupt[offset + 9 + length - 1] ^= 0xFF
    (tmp_path / "index.mcap").write_bytes(bytes(corrupt))
    with pytest.raises(InputError, match="data section CRC mismatch"):
        read_stage(tmp_path / "index.mcap")
    assert not read_stage(tmp_path / "index.mcap", validate_crcs=False).truncated
    # the configuration attachment has its own CRC
    pos = data.index(CONFIG.encode())
    corrupt = bytearray(data)
    corrupt[pos] ^= 0x20
    (tmp_path / "att.mcap").write_bytes(bytes(corrupt))
    with pytest.raises(InputError, match=r"attachment .* CRC"):
        read_stage(tmp_path / "att.mcap")


def test_exception_inside_with_leaves_no_file(tmp_path, rng):
    path = tmp_path / "track.mcap"
    with pytest.raises(RuntimeError, match="boom"), writer(path) as w:
        w.write_trajectory("/trajectory", random_trajectory(rng))
        raise RuntimeError("boom")
    assert not path.exists()
    assert list(tmp_path.iterdir()) == []


def test_existing_file_is_not_overwritten_by_default(tmp_path):
    path = tmp_path / "plan.mcap"
    path.write_bytes(b"previous run")
    with pytest.raises(FileExistsError), writer(path):
        pass
    assert path.read_bytes() == b"previous run"
    with writer(path, overwrite=True) as w:
        w.write_log(0.0, "info", "replaced")
    assert read_stage(path).log == ((0.0, "info", "replaced"),)


def test_truncated_file_yields_a_prefix(tmp_path, rng):
    traj = random_trajectory(rng, n=3000)
    path = tmp_path / "plan.mcap"
    with writer(path, chunk_size=16 * 1024) as w:
        w.write_trajectory("/trajectory", traj)
    data = path.read_bytes()
    with path.open("rb") as f:
        data_start = next(c.chunk_start_offset for c in make_reader(f).get_summary().chunk_indexes)
    lengths = []
    for fraction in (0.3, 0.5, 0.77):
        cut = tmp_path / f".plan.mcap.{fraction}.partial"
        cut.write_bytes(data[: int(len(data) * fraction)])
        rec = read_stage(cut, validate_crcs=True)
        assert rec.truncated
        got = rec.trajectories["/trajectory"]
        k = len(got)
        assert 0 < k < len(traj)
        assert bits(got.t) == bits(traj.t[:k]) and bits(got.x) == bits(traj.x[:k])
        assert rec.attachments["config.yaml"] == CONFIG.encode()
        assert rec.metadata["oacli"]["stage"] == "plan"
        lengths.append(k)
        with pytest.raises(InputError, match="truncated"):
            read_trajectory(cut)
        assert len(read_trajectory(cut, allow_truncated=True)) == k
    assert lengths == sorted(lengths) and len(set(lengths)) == 3
    # cut before the first chunk: metadata survive, no samples
    head = tmp_path / "head.mcap"
    head.write_bytes(data[:data_start])
    rec = read_stage(head)
    assert rec.truncated and rec.trajectories == {} and rec.config_yaml == CONFIG


def test_reader_errors_are_input_errors(tmp_path, rng):
    with pytest.raises(InputError, match="file not found"):
        read_stage(tmp_path / "missing.mcap")
    (tmp_path / "text.mcap").write_text("hello")
    with pytest.raises(InputError, match="not an MCAP file"):
        read_trajectory(tmp_path / "text.mcap")
    path = tmp_path / "plan.mcap"
    with writer(path) as w:
        w.write_trajectory("/trajectory", random_trajectory(rng, n=5))
        w.write_poses(np.arange(3.0), np.tile([0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0], (3, 1)))
    with pytest.raises(InputError, match="no topic /smooth") as err:
        read_trajectory(path, "/smooth")
    assert "/trajectory (oacli.TrajectorySample)" in str(err.value)
    assert "/robot/pose (foxglove.PoseInFrame)" in str(err.value)
    with pytest.raises(InputError, match=r"carries foxglove\.PoseInFrame"):
        read_trajectory(path, "/robot/pose")
    with pytest.raises(InputError, match="no topic /state/true"):
        read_telemetry(path)


# ----------------------------------------------------------------------------------------------------------
# Metadata, attachments, Foxglove messages
# ----------------------------------------------------------------------------------------------------------


def test_config_attachment_and_metadata(tmp_path):
    path = tmp_path / "plan.mcap"
    with writer(path) as w:
        w.write_metadata("oacli.timing", {"plan_s": 1.25})
        w.attach("extra.json", b"{}", "application/json", t=2.0)
    rec = read_stage(path)
    assert rec.attachments == {"config.yaml": CONFIG.encode(), "extra.json": b"{}"}
    assert rec.config_yaml == CONFIG
    info = rec.metadata["oacli"]
    assert info["stage"] == "plan" and info["seed"] == "7" and info["git_commit"] == "abc123"
    assert info["version"] and info["created_utc"].endswith("Z") and info["frame"] == "world"
    assert rec.metadata["oacli.timing"] == {"plan_s": "1.25"}
    with path.open("rb") as f:
        attachments = {a.name: a for a in make_reader(f).iter_attachments()}
    assert attachments["config.yaml"].media_type == "application/yaml"
    assert attachments["extra.json"].log_time == 2_000_000_000


def test_scene_update_decodes_to_cubes_spheres_and_lines(tmp_path, rng):
    rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    rotation *= np.sign(np.linalg.det(rotation))
    axis_aligned = Ellipsoid.from_semi_axes([1.0, 2.0, 3.0], [0.5, 0.3, 0.2])  # eigen order = identity
    rotated = Ellipsoid.from_semi_axes([-1.0, 0.5, 4.0], [0.25, 0.4, 0.1], rotation)
    boxes = (Box([0, 0, 0], [2, 3, 4]), Box([-1, -1, -1], [0.5, 0.5, 0.5]))
    scene = Scene(keep_in=boxes, keep_out=(axis_aligned, rotated), frame="iss")
    reference = rng.normal(size=(30, 3))
    actual = rng.normal(size=(25, 3))
    path = tmp_path / "plan.mcap"
    with writer(path) as w:
        w.write_scene(scene, {"reference": reference, "actual": actual}, t=1.5)
    ((log_time, update),) = decoded(path, "/scene")
    assert log_time == 1_500_000_000
    cubes = [(e, c) for e in update.entities for c in e.cubes]
    spheres = [(e, s) for e in update.entities for s in e.spheres]
    lines = {e.id: ln for e in update.entities for ln in e.lines}
    assert len(cubes) == 2 and len(spheres) == 2 and set(lines) == {"path/reference", "path/actual"}
    assert {e.frame_id for e in update.entities} == {"iss"}
    for (_, cube), box in zip(cubes, boxes, strict=True):
        p, q = cube.pose.position, cube.pose.orientation
        assert [p.x, p.y, p.z] == box.center.tolist()
        assert [cube.size.x, cube.size.y, cube.size.z] == box.size.tolist()
        assert (q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 1.0)
        assert 0.0 < cube.color.a < 0.5
    (_, s0), (_, s1) = spheres
    q0 = s0.pose.orientation
    assert (q0.x, q0.y, q0.z, q0.w) == pytest.approx((0.0, 0.0, 0.0, 1.0), abs=1e-12)
    assert [s0.size.x, s0.size.y, s0.size.z] == pytest.approx([1.0, 0.6, 0.4], rel=1e-12)
    assert [s0.pose.position.x, s0.pose.position.y, s0.pose.position.z] == [1.0, 2.0, 3.0]
    # the rotated ellipsoid: R(q) diag((size/2)^-2) R(q)^T reproduces the shape matrix
    q1 = np.array([s1.pose.orientation.x, s1.pose.orientation.y, s1.pose.orientation.z, s1.pose.orientation.w])
    assert np.linalg.norm(q1) == pytest.approx(1.0, abs=1e-12)
    half = np.array([s1.size.x, s1.size.y, s1.size.z]) / 2.0
    r1 = rotation_matrix(q1)
    assert np.allclose(r1 @ np.diag(half**-2) @ r1.T, rotated.shape, rtol=1e-9, atol=1e-9)
    assert sorted(half) == pytest.approx([0.1, 0.25, 0.4], rel=1e-12)
    ref_line, act_line = lines["path/reference"], lines["path/actual"]
    assert ref_line.type == 0  # LINE_STRIP
    assert [[p.x, p.y, p.z] for p in ref_line.points] == reference.tolist()
    assert len(act_line.points) == 25
    ref_color = (ref_line.color.r, ref_line.color.g, ref_line.color.b)
    assert ref_color != (act_line.color.r, act_line.color.g, act_line.color.b)
    assert ref_line.pose.orientation.w == 1.0


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_quaternion_from_matrix_round_trips(rng):
    for _ in range(200):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q = -q if q[3] < 0 else q
        assert np.allclose(from_rotation_matrix(rotation_matrix(q)), q, atol=1e-12)
    # 180° turns exercise the non-trace branches
    for r in (np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])):
        assert np.allclose(rotation_matrix(from_rotation_matrix(r)), r, atol=1e-12)


def test_pose_in_frame_decodes(tmp_path, rng):
    traj = random_trajectory(rng, n=20)
    path = tmp_path / "plan.mcap"
    with writer(path, frame="iss") as w:
        w.write_poses(traj.t, traj.x)
    poses = decoded(path, "/robot/pose")
    assert len(poses) == 20
    for (log_time, msg), t, x in zip(poses, traj.t, traj.x, strict=True):
        ns = round(float(t) * 1e9)
        assert log_time == ns
        assert msg.timestamp.seconds * 10**9 + msg.timestamp.nanos == ns
        assert msg.frame_id == "iss"
        p, q = msg.pose.position, msg.pose.orientation
        assert [p.x, p.y, p.z] == x[0:3].tolist()
        assert [q.x, q.y, q.z, q.w] == x[6:10].tolist()


def test_each_file_gets_only_its_own_channels(tmp_path, rng):
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    x = rng.normal(size=(5, 13))
    with writer(a) as wa, writer(b) as wb:
        wa.write_states("/state/true", np.arange(5.0), x)
        wb.write_states("/state/true", np.arange(3.0), x[:3])
        wb.write_log(0.0, "info", "only in b")
    assert read_stage(a).message_counts == {"/state/true": 5}
    assert read_stage(b).message_counts == {"/log": 1, "/state/true": 3}


def test_robot_body_follows_the_pose_thinned_to_the_rate(tmp_path, rng):
    from tests.mcap_checks import robot_body_samples, scene_updates

    traj = random_trajectory(rng, n=60)
    t = np.arange(60) * 0.0625 + 0.5  # 16 Hz (dyadic steps: exact in floating point) over 3.6875 s
    path = tmp_path / "track.mcap"
    scene = Scene(keep_in=(Box([-5, -5, -5], [5, 5, 5]),), frame="iss")
    with writer(path, frame="iss") as w:
        w.write_scene(scene, t=0.0)
        w.write_robot_body(t, traj.x, edge_m=0.3, radius_m=0.25, rate_hz=10.0)
    times, positions, quats, edges = robot_body_samples(path)
    # The first sample of each 0.1 s interval after t[0] (interval of sample i: floor(0.625 i) = (5 i) // 8), then
    # the last sample.
    expected = [i for i in range(60) if i == 0 or (5 * i) // 8 != (5 * (i - 1)) // 8]
    expected += [] if expected[-1] == 59 else [59]
    assert times == [round((0.5 + i * 0.0625) * 1e9) for i in expected]
    idx = expected
    assert np.all(np.diff(np.asarray(times)[:-1]) >= 0.0625e9)  # never faster than 10 Hz up to the sample grid
    np.testing.assert_array_equal(positions, traj.x[idx, 0:3])
    np.testing.assert_array_equal(quats, traj.x[idx, 6:10])
    assert edges == [0.3] * len(times)
    # the workspace update stays first and alone; the collision sphere rides with the body
    (t0, first), (_, body) = scene_updates(path)[:2]
    assert t0 == 0 and [e.id for e in first.entities] == ["keep_in/0"]
    (sphere,) = body.entities[0].spheres
    assert [sphere.size.x, sphere.size.y, sphere.size.z] == [0.5, 0.5, 0.5] and sphere.color.a < 0.5
    assert body.entities[0].frame_id == "iss"
    with writer(tmp_path / "bad.mcap") as w, pytest.raises(ValueError, match="increasing"):
        w.write_robot_body(t[::-1], traj.x)


def _raw_messages(path: Path) -> list[tuple[str, int, bytes]]:
    with path.open("rb") as f:
        return [(c.topic, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages(log_time_order=False)]


def test_a_second_file_reuses_kept_payloads_only_for_exactly_the_same_rows(tmp_path, rng):
    """``keep_encoded`` / ``reuse_encoded`` (the track journal and its complete file): a topic whose rows equal the
    kept ones, written in two parts before, takes the kept payloads; the file equals one encoded from scratch,
    message for message. A topic whose rows differ in one value is encoded anew (its new value is in the file)."""
    traj = random_trajectory(rng, n=120)
    wrench = rng.normal(size=(120, 6))
    with writer(tmp_path / "journal.mcap", time_ordered=True) as first:
        kept = first.keep_encoded()
        for part in (slice(0, 50), slice(50, 120)):
            first.write_states("/state/true", traj.t[part], traj.x[part], traj.u[part])
            first.write_wrenches("/control/applied", traj.t[part], wrench[part])
            first.flush()
    changed = wrench.copy()
    changed[77, 4] += 1e-9
    calls: list[str] = []
    original = type(kept).payloads

    def spy(self, topic, template, rows):
        out = original(self, topic, template, rows)
        calls.append(f"{topic}:{out is not None}")
        return out

    type(kept).payloads = spy
    try:
        with writer(tmp_path / "reused.mcap", time_ordered=True) as second:
            second.reuse_encoded(kept)
            second.write_states("/state/true", traj.t, traj.x, traj.u)
            second.write_wrenches("/control/applied", traj.t, changed)
    finally:
        type(kept).payloads = original
    assert calls == ["/state/true:True", "/control/applied:False"]
    with writer(tmp_path / "fresh.mcap", time_ordered=True) as third:
        third.write_states("/state/true", traj.t, traj.x, traj.u)
        third.write_wrenches("/control/applied", traj.t, changed)
    assert _raw_messages(tmp_path / "reused.mcap") == _raw_messages(tmp_path / "fresh.mcap")
    applied = [json.loads(d) for topic, _, d in _raw_messages(tmp_path / "reused.mcap") if topic == "/control/applied"]
    assert applied[77]["torque"][1] == changed[77, 4]
