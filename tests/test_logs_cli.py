"""``oacli logs verify`` and ``oacli logs recover`` on sound, cut and corrupted MCAP files, checked
against what the ``mcap`` package itself reads."""

from __future__ import annotations

import io
import re

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from typer.testing import CliRunner

from oacli.cli import app
from oacli.io.mcap_write import StageMcapWriter

runner = CliRunner()


@pytest.fixture(scope="module")
def sound(tmp_path_factory):
    """A small stage file: two interleaved topics, a log, metadata and two attachments, in 4 KiB chunks."""
    path = tmp_path_factory.mktemp("logs") / "stage.mcap"
    rng = np.random.default_rng(11)
    n = 400
    x = rng.normal(size=(n, 13))
    with StageMcapWriter(path, stage="track", config_yaml="seed: 11\n", chunk_size=4096, time_ordered=True) as w:
        w.write_states("/state/true", np.arange(n) * 0.016, x)
        w.write_states("/state/measured", np.arange(n // 4) * 0.064 + 0.001, x[: n // 4])
        w.write_log(1.0, "info", "half way")
        w.write_metadata("oacli.timing", {"wall_s": 1.5})
        w.attach("notes.txt", b"hello", "text/plain")
    return path


def mcap_package_count(data: bytes) -> int:
    """Messages the ``mcap`` package's stream reader (CRCs checked) yields before it stops."""
    count = 0
    try:
        for record in StreamReader(io.BytesIO(data), validate_crcs=True, emit_chunks=True).records:
            records = breakup_chunk(record, validate_crc=True) if isinstance(record, Chunk) else [record]
            count += sum(isinstance(r, Message) for r in records)
    except Exception:  # the reader raises at the cut
        pass
    return count


def chunk_offsets(path) -> list[tuple[int, int]]:
    with open(path, "rb") as f:
        return [(c.chunk_start_offset, c.chunk_length) for c in make_reader(f).get_summary().chunk_indexes]


def test_a_sound_file_verifies_and_recovers_unchanged(sound, tmp_path):
    result = runner.invoke(app, ["logs", "verify", str(sound)])
    assert result.exit_code == 0, result.output
    with open(sound, "rb") as f:
        whole = list(make_reader(f, validate_crcs=True).iter_messages(log_time_order=False))
    assert f"ok ({len(whole)} messages" in result.output
    out = tmp_path / "copy.mcap"
    result = runner.invoke(app, ["logs", "recover", str(sound), str(out)])
    assert result.exit_code == 0, result.output
    assert f"{len(whole)} messages saved" in result.output
    with open(out, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        copy = list(reader.iter_messages(log_time_order=False))
        assert {m.name for m in reader.iter_metadata()} == {"oacli", "oacli.timing"}
        assert {a.name: a.data for a in reader.iter_attachments()}["notes.txt"] == b"hello"
    assert [(c.topic, c.metadata, s.name, m.log_time, m.data) for s, c, m in copy] == [
        (c.topic, c.metadata, s.name, m.log_time, m.data) for s, c, m in whole]


@pytest.mark.parametrize("where", ["header", "metadata", "mid_chunk", "chunk_end", "after_data_end", "magic"])
def test_a_cut_file_is_named_truncated_and_recovers_what_the_mcap_package_reads(sound, tmp_path, where):
    full = sound.read_bytes()
    chunks = chunk_offsets(sound)
    start, length = chunks[len(chunks) // 2]
    cut_at = {"header": 12, "metadata": 40, "mid_chunk": start + length // 2, "chunk_end": start + length,
              "after_data_end": len(full) - 60, "magic": len(full) - 3}[where]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full[:cut_at])
    result = runner.invoke(app, ["logs", "verify", str(cut)])
    assert result.exit_code == 3, result.output
    assert f"truncated at byte {cut_at}" in result.output
    out = tmp_path / "rec.mcap"
    result = runner.invoke(app, ["logs", "recover", str(cut), str(out)])
    expected = mcap_package_count(full[:cut_at])
    saved = int(re.search(r"(\d+) messages saved", result.output).group(1))
    assert saved == expected
    # Only a cut after the data end record (in the summary) loses nothing.
    assert result.exit_code == (0 if where in ("after_data_end", "magic") else 3), result.output
    if where in ("mid_chunk", "chunk_end"):
        assert 0 < saved < mcap_package_count(full)
    with open(out, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        assert sum(1 for _ in reader.iter_messages()) == saved
    assert runner.invoke(app, ["logs", "verify", str(out)]).exit_code == 0


@pytest.mark.parametrize("target", ["crc_field", "compressed_data"])
def test_a_flipped_byte_in_a_chunk_is_named_a_crc_failure(sound, tmp_path, target):
    data = bytearray(sound.read_bytes())
    start, length = chunk_offsets(sound)[1]
    # Chunk record: opcode (1), length (8), start/end time (8 + 8), uncompressed size (8), CRC (4), ...
    at = start + 9 + 24 if target == "crc_field" else start + length - 20
    data[at] ^= 0x5A
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    result = runner.invoke(app, ["logs", "verify", str(bad)])
    assert result.exit_code == 3, result.output
    assert f"chunk at byte {start} failed its CRC check" in result.output
    # recover skips the bad chunk and keeps the others (data lost: exit 3)
    out = tmp_path / "rec.mcap"
    result = runner.invoke(app, ["logs", "recover", str(bad), str(out)])
    assert result.exit_code == 3, result.output
    with open(out, "rb") as f:
        saved = sum(1 for _ in make_reader(f, validate_crcs=True).iter_messages())
    with open(sound, "rb") as f:
        reader = make_reader(f)
        total = sum(1 for _ in reader.iter_messages())
    assert 0 < saved < total


def test_not_an_mcap_file_exits_2(tmp_path):
    (tmp_path / "a.mcap").write_text("hello")
    for args in (["verify", str(tmp_path / "a.mcap")], ["verify", str(tmp_path / "none.mcap")],
                 ["recover", str(tmp_path / "a.mcap"), str(tmp_path / "b.mcap")]):
        result = runner.invoke(app, ["logs", *args])
        assert result.exit_code == 2 and "error:" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "b.mcap").exists()


def test_channels_survive_recovery_with_their_metadata(sound, tmp_path):
    full = sound.read_bytes()
    start, _ = chunk_offsets(sound)[-1]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full[: start + 5])
    out = tmp_path / "rec.mcap"
    runner.invoke(app, ["logs", "recover", str(cut), str(out)])
    with open(out, "rb") as f:
        channels = make_reader(f).get_summary().channels.values()
    assert {c.topic: c.metadata.get("name") for c in channels if c.topic.startswith("/state")} == {
        "/state/true": "state/true", "/state/measured": "state/measured"}
