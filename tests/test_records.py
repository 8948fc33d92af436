"""Records that survive faults — time-ordered, chunked MCAP readable up to a cut by the ``mcap``
package and by oacli's reader."""

from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from typer.testing import CliRunner

from oacli.cli import app
from oacli.io.mcap_io import read_stage
from oacli.io.mcap_write import StageMcapWriter
from oacli.io.telemetry_streams import read_telemetry_streams
from tests.conftest import REPO

ISS = REPO / "configs" / "iss_reswarm.yaml"
runner = CliRunner()


@pytest.fixture(scope="module")
def track_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("records") / "run"
    result = runner.invoke(app, ["track", str(ISS), "--out", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    return out


def mcap_package_messages(data: bytes) -> tuple[list[tuple[str, int]], bool]:
    """``(topic, log_time)`` of every message the ``mcap`` package's stream reader (CRCs checked) yields from
    ``data``, and whether it stopped at a cut (an exception after the last complete record)."""
    channels: dict[int, str] = {}
    out: list[tuple[str, int]] = []

    def take(record) -> None:
        if isinstance(record, Channel):
            channels[record.id] = record.topic
        elif isinstance(record, Message):
            out.append((channels[record.channel_id], record.log_time))

    try:
        for record in StreamReader(io.BytesIO(data), validate_crcs=True, emit_chunks=True).records:
            if isinstance(record, Chunk):
                for inner in breakup_chunk(record, validate_crc=True):
                    take(inner)
            else:
                take(record)
    except (McapError, EOFError, ValueError, Exception) as exc:  # the reader raises at the cut
        if len(data) >= 8 and data[-8:] == b"\x89MCAP0\r\n":
            raise AssertionError(f"complete file failed to read: {exc!r}") from exc
        return out, True
    return out, False


def test_track_mcap_is_written_in_time_order_in_bounded_chunks(track_run):
    with open(track_run / "track.mcap", "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        times = [m.log_time for _, _, m in reader.iter_messages(log_time_order=False)]
        summary = reader.get_summary()
    assert len(times) > 1000
    assert np.all(np.diff(times) >= 0), "messages are not in time order in the file"
    chunks = summary.chunk_indexes
    assert len(chunks) >= 3  # several chunks, so a crash loses only the last one
    # Chunks are bounded: the writer's target (256 KiB uncompressed) plus at most one message.
    assert max(c.uncompressed_size for c in chunks) < 256 * 1024 + 64 * 1024
    # Interleaved: every chunk but the last spans a short time, and the topics of the run share chunks.
    assert all(c.message_start_time <= c.message_end_time for c in chunks)


@pytest.mark.parametrize("fraction", [0.15, 0.3, 0.45, 0.6, 0.75, 0.9, 0.99])
def test_cut_track_mcap_reads_with_the_mcap_package_and_oacli(track_run, fraction, tmp_path):
    full = (track_run / "track.mcap").read_bytes()
    with open(track_run / "track.mcap", "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    span_ns = max(c.message_end_time - c.message_start_time for c in chunks)
    cut = full[: int(len(full) * fraction)]
    messages, stopped = mcap_package_messages(cut)
    assert stopped
    complete_chunks = [c for c in chunks if c.chunk_start_offset + c.chunk_length <= len(cut)]
    assert complete_chunks, "cut before the first chunk ended; choose larger fractions"
    # The mcap package reads every complete chunk: a prefix of the whole file's messages.
    whole, whole_stopped = mcap_package_messages(full)
    assert not whole_stopped and 0 < len(messages) <= len(whole)
    assert messages == whole[: len(messages)]
    last_complete_ns = max(c.message_end_time for c in complete_chunks)
    by_topic: dict[str, int] = {}
    for topic, t in messages:
        by_topic[topic] = max(t, by_topic.get(topic, 0))
    # ... and /state/true (with the measured state and the commands) reaches up to the last complete chunk.
    for topic in ("/state/true", "/state/measured", "/control/applied"):
        assert topic in by_topic, topic
        assert by_topic[topic] >= last_complete_ns - span_ns, (topic, by_topic[topic], last_complete_ns)
    assert max(by_topic.values()) == last_complete_ns
    # oacli's reader sees the same messages of the cut file (and says it is cut).
    path = tmp_path / "cut.mcap"
    path.write_bytes(cut)
    record = read_stage(path)
    assert record.truncated
    counts = {topic: sum(1 for tp, _ in messages if tp == topic) for topic in by_topic}
    for topic, n in counts.items():
        assert record.message_counts.get(topic) == n, topic
    streams = read_telemetry_streams(path)
    assert streams.truncated and streams.t_measured[-1] * 1e9 == pytest.approx(by_topic["/state/measured"], abs=1)


def test_time_ordered_block_merges_topics_and_drops_on_error(tmp_path):
    x = np.zeros((5, 13))
    x[:, 9] = 1.0
    path = tmp_path / "a.mcap"
    with StageMcapWriter(path, stage="t", config_yaml="a: 1\n") as w, w.time_ordered():
        w.write_states("/a", np.arange(5) * 1.0, x)
        w.write_states("/b", np.arange(5) * 1.0 + 0.5, x)
        w.write_log(2.2, "info", "between")
    with open(path, "rb") as f:
        order = [(c.topic, m.log_time) for _, c, m in make_reader(f).iter_messages(log_time_order=False)]
    assert [t for _, t in order] == sorted(t for _, t in order)
    assert [tp for tp, _ in order][:4] == ["/a", "/b", "/a", "/b"]
    assert ("/log", 2_200_000_000) in order
    with pytest.raises(RuntimeError), StageMcapWriter(tmp_path / "b.mcap", stage="t", config_yaml="") as w:
        with w.time_ordered():
            w.write_states("/a", np.arange(5) * 1.0, x)
            raise RuntimeError("boom")
    assert not (tmp_path / "b.mcap").exists()
    assert list(tmp_path.iterdir()) == [path]


# -- faults: signals during a real run ------------------------------------------------------------------------

def _start_track(out: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.Popen([sys.executable, "-m", "oacli", "track", str(ISS), "--out", str(out), "--quiet"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for(proc: subprocess.Popen, predicate, timeout_s: float = 240.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert proc.poll() is None, f"the run ended before the moment to signal it: {proc.communicate()}"
        assert time.monotonic() < deadline, "timed out waiting for the run"
        time.sleep(0.002)


def _partial_mcap(out: Path, min_bytes: int) -> Path | None:
    for path in out.glob(".track.mcap.*.partial") if out.exists() else ():
        try:
            if path.stat().st_size >= min_bytes:
                return path
        except FileNotFoundError:
            pass
    return None


def test_sigkill_while_the_mcap_is_written_leaves_a_file_the_mcap_package_reads(tmp_path):
    out = tmp_path / "run"
    proc = _start_track(out)
    found: list[Path] = []
    _wait_for(proc, lambda: bool(found.append(p) or True) if (p := _partial_mcap(out, 200_000)) else False)
    proc.kill()
    proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    data = found[0].read_bytes()
    messages, stopped = mcap_package_messages(data)
    assert stopped and len(messages) > 100
    true_times = [t for topic, t in messages if topic == "/state/true"]
    assert true_times and max(true_times) >= max(t for _, t in messages) - 2_000_000_000  # within 2 s of the cut
    record = read_stage(found[0])
    assert record.truncated and record.trajectories["/state/true"].t[-1] * 1e9 == pytest.approx(max(true_times))
    assert not (out / "track.mcap").exists() and not (out / "summary.json").exists()


def test_sigkill_during_the_simulation_leaves_the_run_so_far(tmp_path):
    """The per-step topics are written while the simulation runs: a SIGKILL mid-simulation leaves a ``.partial``
    MCAP the ``mcap`` package reads to its last complete chunk, with ``/state/true`` up to near the kill, and
    ``oacli logs recover`` makes a valid file of it."""
    cfg = _config_with(tmp_path, simulation__settle_time_s=300.0)  # a long run: killed well before its end
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", "oacli", "track", str(cfg), "--out", str(out), "--quiet"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    sizes: list[int] = []

    def grown() -> bool:
        path = _partial_mcap(out, 1)
        if path is not None:
            sizes.append(path.stat().st_size)
        return len(set(sizes)) >= 3  # appeared, then grew twice: written while the simulation runs

    _wait_for(proc, grown)
    first = _partial_mcap(out, 1)
    snapshot = first.read_bytes()
    time.sleep(1.5)
    proc.kill()
    proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    data = first.read_bytes()
    assert len(data) > len(snapshot) and not (out / "track.mcap").exists()
    messages, stopped = mcap_package_messages(data)
    early, _ = mcap_package_messages(snapshot)
    true_times = [t for topic, t in messages if topic == "/state/true"]
    ctrl_times = [t for topic, t in messages if topic == "/state/measured"]
    assert stopped and true_times and ctrl_times
    # Written while running: the file killed 1.5 s later reaches further than the snapshot (which, on a loaded
    # machine, may not hold a complete chunk yet).
    early_true = [t for topic, t in early if topic == "/state/true"]
    assert not early_true or max(true_times) > max(early_true)
    assert len(messages) > len(early)
    # The journal is far from the end of the run (300 s of settling) ...
    assert max(true_times) < 250e9
    # ... in time order, with /state/true abreast of the controller topics (a control period apart at most).
    assert [t for _, t in messages] == sorted(t for _, t in messages)
    assert abs(max(true_times) - max(ctrl_times)) <= 0.2e9 + 1
    # recover: a valid file with every message the mcap package read; data were lost (exit 3).
    fixed = tmp_path / "fixed.mcap"
    result = runner.invoke(app, ["logs", "recover", str(first), str(fixed)])
    assert result.exit_code == 3, result.output
    assert f"{len(messages)} messages saved" in result.output
    with open(fixed, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        assert sum(1 for _ in reader.iter_messages()) == len(messages)
        config = next(a for a in reader.iter_attachments() if a.name == "config.yaml").data
    assert config == (out / "config.yaml").read_bytes()


def test_sigterm_while_the_mcap_is_written_is_an_interruption(tmp_path):
    out = tmp_path / "run"
    proc = _start_track(out)
    _wait_for(proc, lambda: _partial_mcap(out, 200_000) is not None)  # the simulation is under way
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert "terminated by SIGTERM" in err and "Traceback" not in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and "SIGTERM" in summary["error"]
    # The journal is kept as a valid track.mcap (no .partial left): the simulation so far and a closing warning.
    assert sorted(p.name for p in out.iterdir()) == ["config.yaml", "summary.json", "track.mcap"]
    assert summary["files"].get("mcap") == "track.mcap"
    _assert_kept_journal(out / "track.mcap", "SIGTERM")


def _assert_kept_journal(path: Path, signal_name: str) -> None:
    """An interrupted track's MCAP: valid for the mcap package with CRCs, /state/true in time order abreast of
    the controller topics, and the closing /log warning naming the signal."""
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        assert reader.get_summary() is not None  # closed properly: summary section written
        rows = [(channel.topic, message.log_time, message.data) for _, channel, message in reader.iter_messages()]
    true_times = [t for topic, t, _ in rows if topic == "/state/true"]
    ctrl_times = [t for topic, t, _ in rows if topic == "/state/measured"]
    assert true_times and ctrl_times and true_times == sorted(true_times)
    assert abs(max(true_times) - max(ctrl_times)) <= 0.2e9 + 1
    logs = [data for topic, _, data in rows if topic == "/log"]  # foxglove.Log (protobuf): the text is in it
    assert any(signal_name.encode() in log and b"journal of the simulation so far is kept" in log for log in logs)


@pytest.mark.slow
def test_sigint_during_the_simulation_is_an_interruption(tmp_path):
    out = tmp_path / "run"
    proc = _start_track(out)
    _wait_for(proc, lambda: (out / "config.yaml").exists())
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted"
    names = sorted(p.name for p in out.iterdir())
    # Before the simulation's journal opens there is nothing to keep; after, it is kept as track.mcap.
    assert names in (["config.yaml", "summary.json"], ["config.yaml", "summary.json", "track.mcap"]), names
    if "track.mcap" in names:
        _assert_kept_journal(out / "track.mcap", "interrupted by the user")


def test_ctrl_c_while_the_recording_is_written_is_not_ok(tmp_path, monkeypatch):
    from oacli.io.rerun.writer import StageRecording

    def interrupted(self, path, blueprint=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(StageRecording, "save", interrupted)
    out = tmp_path / "run"
    result = runner.invoke(app, ["track", str(ISS), "--out", str(out), "--quiet"])
    assert result.exit_code == 130
    assert json.loads((out / "summary.json").read_text())["status"] == "interrupted"
    assert sorted(p.name for p in out.iterdir()) == ["config.yaml", "summary.json", "track.mcap"]


# -- full disk ------------------------------------------------------------------------------------------------

@pytest.fixture
def small_tmpfs(tmp_path):
    """A folder on a fresh tmpfs whose size the test sets (skips where mounting is not allowed)."""
    mount_point = tmp_path / "tmpfs"
    mount_point.mkdir()
    mounted: list[Path] = []

    def mount(size_bytes: int) -> Path:
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_bytes}", "tmpfs", str(mount_point)],
                              capture_output=True, text=True, check=False)
        if done.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here (needs root/CAP_SYS_ADMIN): {done.stderr.strip()}")
        mounted.append(mount_point)
        return mount_point

    yield mount
    for point in mounted:
        subprocess.run(["umount", str(point)], check=False)


@pytest.mark.parametrize("fails", ["track.mcap", "final track.mcap"])
def test_full_disk_fails_fast_with_one_line_naming_the_cause(track_run, small_tmpfs, fails):
    """The journal does not fit (200 kB), or it does but the complete file beside it does not: one line
    naming track.mcap and ENOSPC; in the second case the journal stays the record."""
    sizes = {p.name: p.stat().st_size for p in track_run.iterdir()}
    room = 200_000 if fails == "track.mcap" else sizes["track.mcap"] + 100_000
    assert room < sizes["track.mcap"] or room < 2 * sizes["track.mcap"]
    kept = fails.startswith("final")
    fails = "track.mcap"
    out = small_tmpfs(room) / "run"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, "-m", "oacli", "track", str(ISS), "--out", str(out), "--quiet"],
                          env=env, capture_output=True, text=True, timeout=240)  # no hang
    assert done.returncode == 1, done.stderr
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert errors == [f"error: cannot write {out / fails}: no space left on device (ENOSPC)"], done.stderr
    assert "Traceback" not in done.stderr
    names = sorted(p.name for p in out.iterdir())
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and "ENOSPC" in summary["error"]
    if not kept:
        assert not any(name.endswith(".partial") for name in names), names
        assert not (out / fails).exists()
        return
    record = summary["records"]["mcap"]  # the whole simulation, kept: closed valid, or its .partial to recover
    assert record in ("journal", "journal-partial"), summary
    partial = out / summary["files"]["journal"] if record == "journal-partial" else out / "track.mcap"
    messages, _ = mcap_package_messages(partial.read_bytes())
    assert sum(1 for topic, _ in messages if topic == "/state/true") > 1000


# -- planted symlinks -----------------------------------------------------------------------------------------

def test_temporary_names_are_unpredictable_and_never_follow_a_planted_symlink(tmp_path):
    from oacli.io.atomic import write_text_atomic

    folder = tmp_path / "run"
    folder.mkdir()
    outside = tmp_path / "outside.txt"
    outside.write_text("keep")
    # Every name the old code used, planted as symlinks to a file outside.
    for name in (".summary.json.partial", ".track.rrd.partial", ".track.mcap.partial"):
        (folder / name).symlink_to(outside)
    write_text_atomic(folder / "summary.json", "{}\n")
    assert (folder / "summary.json").read_text() == "{}\n" and not (folder / "summary.json").is_symlink()
    assert outside.read_text() == "keep"
    assert sorted(p.name for p in folder.iterdir() if not p.is_symlink()) == ["summary.json"]


def test_a_run_folder_that_becomes_a_symlink_is_refused(tmp_path):
    from oacli.io.atomic import WriteError, write_text_atomic

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    run = tmp_path / "run"
    run.symlink_to(elsewhere)
    with pytest.raises(WriteError, match="is a symlink"):
        write_text_atomic(run / "summary.json", "{}\n")
    assert list(elsewhere.iterdir()) == []


@pytest.mark.parametrize("kind", ["dangling", "file-runs-dir", "file-parent"])
def test_out_and_runs_dir_problems_exit_2_with_a_clear_line(tmp_path, kind):
    if kind == "dangling":
        (tmp_path / "out").symlink_to(tmp_path / "nowhere")
        args, expected = ["--out", str(tmp_path / "out")], "is a symlink (dangling)"
    elif kind == "file-runs-dir":
        (tmp_path / "runs").write_text("x")
        args, expected = ["--runs-dir", str(tmp_path / "runs")], "exists and is not a folder"
    else:
        (tmp_path / "f").write_text("x")
        args, expected = ["--out", str(tmp_path / "f" / "run")], "cannot create the folder"
    result = runner.invoke(app, ["track", str(ISS), *args, "--quiet"])
    assert result.exit_code == 2, result.output
    assert expected in result.output and "Traceback" not in result.output
    assert not (tmp_path / "nowhere").exists()


# -- configs that would exhaust the machine -------------------------------------------------------------------

def _config_with(tmp_path: Path, text_edit=None, **sets) -> Path:
    import yaml

    data = yaml.safe_load(ISS.read_text())
    for dotted, value in sets.items():
        *parents, last = dotted.split("__")
        node = data
        for key in parents:
            node = node[int(key)] if isinstance(node, list) else node.setdefault(key, {})
        node[last] = value
    text = yaml.safe_dump(data, sort_keys=False)
    if text_edit is not None:
        text = text_edit(text)
    path = tmp_path / "cfg.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(("sets", "field"), [
    ({"waypoints__A__position": [1e30, 0.0, 0.0]}, "waypoints.A.position"),
    ({"environment__keep_in__0__corners": [[-1e30, 0, 0], [1, 1, 1]]}, "environment.keep_in.0.corners"),
    ({"reference__cruise_speed_mps": 1e-9}, "reference.cruise_speed_mps"),
    ({"reference__hold_s": 1e9}, "reference.hold_s"),
    ({"simulation__settle_time_s": 1e7}, "simulation.settle_time_s"),
    ({"simulation__plant_rate_hz": 1e7}, "simulation.plant_rate_hz"),
])
def test_configs_that_would_exhaust_the_machine_exit_2_naming_the_field(tmp_path, sets, field):
    path = _config_with(tmp_path, **sets)
    start = time.monotonic()
    result = runner.invoke(app, ["track", str(path), "--out", str(tmp_path / "run"), "--quiet"])
    assert time.monotonic() - start < 20
    assert result.exit_code == 2, result.output
    assert f"{path}: {field}" in result.output, result.output
    assert not (tmp_path / "run").exists()


def test_config_size_and_kind_are_bounded(tmp_path):
    from oacli.config import MAX_CONFIG_BYTES, load_config
    from oacli.errors import ConfigError

    big = tmp_path / "big.yaml"
    big.write_text("name: x\nlist: [" + "1, " * (MAX_CONFIG_BYTES // 3) + "1]\n")
    start = time.monotonic()
    with pytest.raises(ConfigError, match="too large"):
        load_config(big)
    with pytest.raises(ConfigError, match="a device"):
        load_config("/dev/zero")
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    with pytest.raises(ConfigError, match="a FIFO"):
        load_config(fifo)  # no writer: must not block
    assert time.monotonic() - start < 5


def test_yaml_1_1_surprises_are_refused_and_exponents_are_numbers(tmp_path):
    from oacli.config import load_config
    from oacli.errors import ConfigError

    sexagesimal = _config_with(tmp_path, text_edit=lambda t: t.replace("seed: 1\n", "seed: 1:30\n"))
    assert "seed: 1:30" in sexagesimal.read_text()
    with pytest.raises(ConfigError, match=r"seed: '1:30': must be an integer"):
        load_config(sexagesimal)
    for spelled in ("1.0e3", "1e3", "1.0e+3"):
        path = _config_with(tmp_path, text_edit=lambda t, s=spelled: t.replace("plant_rate_hz: 62.5",
                                                                              f"plant_rate_hz: {s}"))
        assert f"plant_rate_hz: {spelled}" in path.read_text()
        assert load_config(path).simulation.plant_rate_hz == 1000.0
    quoted = _config_with(tmp_path, text_edit=lambda t: t.replace("plant_rate_hz: 62.5", "plant_rate_hz: '1e3'"))
    with pytest.raises(ConfigError, match="must be a number, not text"):
        load_config(quoted)


# -- hostile input files --------------------------------------------------------------------------------------

def _reference_mcap(path: Path, t: np.ndarray, frame: str = "world") -> Path:
    from oacli.types import Trajectory

    x = np.zeros((len(t), 13))
    x[:, 0:3] = [10.8, -9.6, 4.8]
    x[:, 9] = 1.0
    with StageMcapWriter(path, stage="smooth", config_yaml="a: 1\n", frame=frame) as w:
        w.write_trajectory("/trajectory", Trajectory(t=t, x=x, u=np.zeros((len(t), 6)), name="ref", frame=frame))
    return path


def test_track_refuses_a_reference_spanning_a_million_seconds_and_one_in_another_frame(tmp_path):
    import yaml

    frame = yaml.safe_load(ISS.read_text())["environment"]["frame"]
    long_ref = _reference_mcap(tmp_path / "long.mcap", np.array([0.0, 1.0, 1e6]), frame)
    result = runner.invoke(app, ["track", str(ISS), "--reference", str(long_ref), "--out", str(tmp_path / "a"), "-q"])
    assert result.exit_code == 2, result.output
    assert "spans 1e+06 s" in result.output and "simulation steps" in result.output
    other = _reference_mcap(tmp_path / "other.mcap", np.array([0.0, 1.0, 2.0]), "elsewhere")
    result = runner.invoke(app, ["track", str(ISS), "--reference", str(other), "--out", str(tmp_path / "b"), "-q"])
    assert result.exit_code == 2, result.output
    assert "in frame 'elsewhere'" in result.output and f"environment.frame is {frame!r}" in result.output


def _raw_mcap(path: Path, chunks: list, extra_records: bytes = b"") -> Path:
    from mcap.data_stream import RecordBuilder

    builder = RecordBuilder()
    for chunk in chunks:
        chunk.write(builder)
    path.write_bytes(b"\x89MCAP0\r\n" + builder.end() + extra_records)
    return path


def test_decompression_bombs_are_refused_within_seconds(tmp_path):
    import lz4.frame
    import zstandard
    from mcap.records import Chunk as ChunkRecord

    from oacli.errors import InputError
    from oacli.io.mcap_read import MAX_CHUNK_BYTES, MIN_DECOMPRESSED_BUDGET

    size = 40 * 1024 * 1024
    # One record of an unknown opcode padded with zeros: 40 MiB that compress to a few KiB.
    body = bytes([0x7F]) + (size - 9).to_bytes(8, "little") + bytes(size - 9)
    zeros = zstandard.ZstdCompressor().compress(body)
    assert len(zeros) < 100_000
    cases = {
        "declares": [ChunkRecord("zstd", b"", 0, 0, 0, MAX_CHUNK_BYTES + 1)],
        "lies": [ChunkRecord("zstd", zeros, 0, 0, 0, 1000)],
        "lz4 lies": [ChunkRecord("lz4", lz4.frame.compress(body), 0, 0, 0, 1000)],
        "total": [ChunkRecord("zstd", zeros, 0, 0, 0, size)] * (MIN_DECOMPRESSED_BUDGET // size + 1),
    }
    expected = {"declares": "decompression bomb", "lies": "not the 1000 it declares",
                "lz4 lies": "not the 1000 it declares", "total": "decompression bomb"}
    for name, chunks in cases.items():
        path = _raw_mcap(tmp_path / f"{name}.mcap", chunks)
        start = time.monotonic()
        with pytest.raises(InputError, match=expected[name]):
            read_stage(path)
        assert time.monotonic() - start < 5, name
    # Through the CLI: exit 2 with one line.
    result = runner.invoke(app, ["smooth", str(ISS), "--input", str(tmp_path / "total.mcap"), "--out",
                                 str(tmp_path / "run"), "-q"])
    assert result.exit_code == 2 and "decompression bomb" in result.output, result.output


def test_deeply_nested_json_in_an_mcap_exits_2(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "deep.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("oacli.TrajectorySample", "jsonschema", b"{}")
        channel = writer.register_channel("/trajectory", "json", schema, {"frame": "world", "name": "x"})
        writer.add_message(channel, 0, b"[" * 100_000 + b"]" * 100_000, 0)
        writer.finish()
    start = time.monotonic()
    result = runner.invoke(app, ["smooth", str(ISS), "--input", str(path), "--out", str(tmp_path / "run"), "-q"])
    assert time.monotonic() - start < 10
    assert result.exit_code == 2, result.output
    assert "nested too deeply" in result.output and "RecursionError" not in result.output


# -- every stage reruns from its config.yaml ------------------------------------------------------------------

def test_smooth_reruns_from_its_config_yaml(tmp_path):
    from tests.test_cli_plan_smooth import small_config

    cfg = small_config(tmp_path)
    assert runner.invoke(app, ["plan", str(cfg), "--out", str(tmp_path / "plan"), "-q", "--seed", "4"]).exit_code == 0
    first = runner.invoke(app, ["smooth", str(cfg), "--input", str(tmp_path / "plan" / "plan.mcap"),
                                "--out", str(tmp_path / "s1"), "-q", "--seed", "4"])
    assert first.exit_code == 0, first.output
    saved = (tmp_path / "s1" / "config.yaml").read_text()
    assert f"smooth_input: {tmp_path / 'plan' / 'plan.mcap'}" in saved
    again = runner.invoke(app, ["smooth", str(tmp_path / "s1" / "config.yaml"), "--out", str(tmp_path / "s2"), "-q"])
    assert again.exit_code == 0, again.output
    a, b = (json.loads((tmp_path / d / "summary.json").read_text()) for d in ("s1", "s2"))
    for key in ("cost_before", "cost_after", "path_length_after_m", "shortcuts_accepted", "duration_after_s"):
        assert a[key] == b[key], key
    missing = runner.invoke(app, ["smooth", str(cfg), "--out", str(tmp_path / "s3"), "-q"])
    assert missing.exit_code == 2 and "--input: missing" in missing.output


def test_recorded_inputs_survive_the_config_round_trip(tmp_path):
    from oacli.config import dump_config, load_config
    from oacli.config.inputs import with_input
    from oacli.errors import ConfigError

    cfg = load_config(ISS)
    with pytest.raises(ConfigError, match="--telemetry: missing"):
        with_input(cfg, "estimate_telemetry", None, "--telemetry")
    cfg, path = with_input(cfg, "estimate_telemetry", Path("runs/x/track.mcap"), "--telemetry")
    assert path == Path.cwd() / "runs/x/track.mcap"
    saved = tmp_path / "config.yaml"
    saved.write_text(dump_config(cfg))
    again = load_config(saved)
    assert again == cfg and with_input(again, "estimate_telemetry", None, "--telemetry")[1] == path


@pytest.mark.slow
def test_estimate_reruns_from_its_config_yaml(tmp_path):
    from tests.test_cli_estimate import payload_config

    cfg = payload_config(tmp_path / "payload.yaml")
    assert runner.invoke(app, ["track", str(cfg), "--out", str(tmp_path / "track"), "-q"]).exit_code == 0
    telemetry = tmp_path / "track" / "track.mcap"
    first = runner.invoke(app, ["estimate", str(cfg), "--telemetry", str(telemetry), "--method", "sequential",
                                "--out", str(tmp_path / "e1"), "-q"])
    assert first.exit_code == 0, first.output
    again = runner.invoke(app, ["estimate", str(tmp_path / "e1" / "config.yaml"), "--out", str(tmp_path / "e2"), "-q"])
    assert again.exit_code == 0, again.output
    a, b = (json.loads((tmp_path / d / "summary.json").read_text()) for d in ("e1", "e2"))
    assert a["method"] == b["method"] == "sequential"
    assert a["mass_kg"] == b["mass_kg"] and a["inertia_kgm2"] == b["inertia_kgm2"]
