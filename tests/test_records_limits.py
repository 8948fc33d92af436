"""Inputs that cannot exhaust the machine — MCAP files of millions of tiny messages and configs holding
huge lists are refused fast with one line naming the topic or field and the limit (exit 2)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Schema, Statistics
from typer.testing import CliRunner

from oacli.cli import app
from oacli.config import load_config
from oacli.config.sizes import (
    MAX_CONFIG_LIST_ITEMS,
    MAX_CONFIG_MAPPING_KEYS,
    MAX_CONFIG_NODES,
    MAX_MESSAGES_PER_TOPIC,
    ConfigSizeError,
)
from oacli.errors import InputError
from oacli.io import mcap_walk
from oacli.io.mcap_read import read_stage
from oacli.io.mcap_recover import verify
from tests.conftest import REPO

ISS = REPO / "configs" / "iss_reswarm.yaml"
MAGIC = b"\x89MCAP0\r\n"
runner = CliRunner()

_MESSAGE = np.dtype([("op", "u1"), ("len", "<u8"), ("ch", "<u2"), ("seq", "<u4"), ("log", "<u8"), ("pub", "<u8"),
                     ("data", "S2")])


def tiny_messages_mcap(path: Path, n: int, *, per_chunk: int = 500_000, complete: bool = True,
                       topic: str = "/trajectory") -> Path:
    """An MCAP of ``n`` messages of 2 bytes (``{}``) on one topic, 1 ms apart, in zstd chunks of ``per_chunk``
    messages (33-byte records built with numpy); ``complete`` adds the data end, a summary with the channel and
    the statistics, the footer and the closing magic."""
    body = RecordBuilder()
    Header(profile="", library="oacli tests").write(body)
    head = RecordBuilder()
    schema = Schema(id=1, name="oacli.TrajectorySample", encoding="jsonschema", data=b"{}")
    channel = Channel(id=1, topic=topic, message_encoding="json", schema_id=1, metadata={})
    schema.write(head)
    channel.write(head)
    head_bytes = head.end()
    compressor = zstandard.ZstdCompressor(level=1)
    for lo in range(0, n, per_chunk):
        k = min(per_chunk, n - lo)
        records = np.zeros(k, dtype=_MESSAGE)
        records["op"], records["len"], records["ch"], records["data"] = 0x05, 24, 1, b"{}"
        records["seq"] = np.arange(lo, lo + k)
        records["log"] = records["pub"] = np.arange(lo, lo + k, dtype=np.uint64) * 1_000_000
        raw = (head_bytes if lo == 0 else b"") + records.tobytes()
        Chunk(compression="zstd", data=compressor.compress(raw), message_start_time=lo * 1_000_000,
              message_end_time=(lo + k - 1) * 1_000_000, uncompressed_crc=zlib.crc32(raw),
              uncompressed_size=len(raw)).write(body)
    data = MAGIC + body.end()
    if complete:
        end = RecordBuilder()
        DataEnd(data_section_crc=0).write(end)
        data += end.end()
        summary = RecordBuilder()
        schema.write(summary)
        channel.write(summary)
        Statistics(message_count=n, schema_count=1, channel_count=1, attachment_count=0, metadata_count=0,
                   chunk_count=-(-n // per_chunk), message_start_time=0, message_end_time=(n - 1) * 1_000_000,
                   channel_message_counts={1: n}).write(summary)
        summary_start = len(data)
        data += summary.end()
        footer = RecordBuilder()
        Footer(summary_start=summary_start, summary_offset_start=0, summary_crc=0).write(footer)
        data += footer.end() + MAGIC
    path.write_bytes(data)
    return path


def test_the_builder_makes_files_the_mcap_package_reads(tmp_path):
    from mcap.reader import make_reader

    path = tiny_messages_mcap(tmp_path / "small.mcap", 1000, per_chunk=300)
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        times = [m.log_time for _, _, m in reader.iter_messages(log_time_order=False)]
        assert reader.get_summary().statistics.channel_message_counts == {1: 1000}
    assert times == [1_000_000 * i for i in range(1000)]
    assert verify(path).ok and verify(path).messages == 1000


@pytest.fixture
def small_caps(monkeypatch):
    """Caps of 5000 messages per topic and 12000 per file (the mechanism, fast; the real caps: the slow tests)."""
    monkeypatch.setattr(mcap_walk, "MAX_MESSAGES_PER_TOPIC", 5000)
    monkeypatch.setattr(mcap_walk, "MAX_MCAP_MESSAGES", 12_000)
    return 5000


@pytest.mark.parametrize("complete", [True, False])
def test_too_many_messages_on_a_topic_are_refused_naming_it(tmp_path, small_caps, complete):
    over = tiny_messages_mcap(tmp_path / "over.mcap", small_caps + 1, per_chunk=2000, complete=complete)
    with pytest.raises(InputError, match=rf"topic /trajectory: .*{small_caps}.*MAX_MESSAGES_PER_TOPIC") as err:
        read_stage(over)
    assert "\n" not in str(err.value)
    scan = verify(over)
    assert scan.problems[0].kind == "too_large" and "/trajectory" in scan.problems[0].message
    # at the cap: read (a cut file up to its intact part)
    at = tiny_messages_mcap(tmp_path / "at.mcap", small_caps, per_chunk=2000, complete=complete)
    record = read_stage(at, topics=[])
    assert record.message_counts == {"/trajectory": small_caps} and record.truncated is not complete


def test_a_lying_summary_does_not_let_too_many_messages_through(tmp_path, small_caps):
    path = tiny_messages_mcap(tmp_path / "lies.mcap", small_caps + 10, per_chunk=2000)
    data = bytearray(path.read_bytes())
    # the statistics say 10 messages: the count of the chunks' records still refuses the file
    from mcap.reader import make_reader
    old = (small_caps + 10).to_bytes(8, "little")
    for _ in range(2):  # the message count and the channel's
        at = data.index(old, len(data) - 200)
        data[at : at + 8] = (10).to_bytes(8, "little")
    lying = tmp_path / "lying.mcap"
    lying.write_bytes(bytes(data))
    with open(lying, "rb") as f:
        stats = make_reader(f).get_summary().statistics
    assert stats.message_count == 10 and stats.channel_message_counts == {1: 10}
    with pytest.raises(InputError, match="topic /trajectory: more than 5000 messages"):
        read_stage(lying)


def test_too_many_messages_in_a_file_are_refused(tmp_path, small_caps, monkeypatch):
    monkeypatch.setattr(mcap_walk, "MAX_MESSAGES_PER_TOPIC", 10**6)
    path = tiny_messages_mcap(tmp_path / "total.mcap", 12_001, per_chunk=4000, complete=False)
    with pytest.raises(InputError, match=r"more than 12000 messages.*MAX_MCAP_MESSAGES"):
        read_stage(path)


def test_smooth_refuses_a_reference_of_too_many_messages_with_exit_2(tmp_path, small_caps):
    path = tiny_messages_mcap(tmp_path / "ref.mcap", 3 * small_caps, per_chunk=4000, complete=False)
    result = runner.invoke(app, ["smooth", str(ISS), "--input", str(path), "--out", str(tmp_path / "run"), "-q"])
    assert result.exit_code == 2, result.output
    assert "topic /trajectory" in result.output and "MAX_MESSAGES_PER_TOPIC" in result.output
    assert "Traceback" not in result.output and not (tmp_path / "run").exists()


@pytest.mark.slow
@pytest.mark.parametrize("complete", [True, False])
def test_ten_million_tiny_messages_are_refused_fast_in_bounded_memory(tmp_path, complete):
    """1e7 messages of 2 bytes (330 MB of records, 70 MB of zstd chunks): refused from the summary's statistics
    when the file is complete, by counting record headers chunk by chunk when it is cut -- never parsing them."""
    path = tiny_messages_mcap(tmp_path / "tiny.mcap", 10_000_000, complete=complete)
    if not complete:
        path.write_bytes(path.read_bytes()[:-5000])
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    # The child's own peak memory: VmHWM of its process image, written by the child as it exits. (wait4's
    # ru_maxrss is no measure here: Linux carries the forking parent's high-water mark into it at exec, and this
    # pytest process may be 1 GB after the slow tests before it.)
    hwm = tmp_path / "vmhwm.txt"
    child = (
        "import atexit, runpy, sys\n"
        "def _hwm():\n"
        "    with open('/proc/self/status') as f:\n"
        "        line = next(x for x in f if x.startswith('VmHWM:'))\n"
        f"    open({str(hwm)!r}, 'w').write(line.split()[1])\n"
        "atexit.register(_hwm)\n"
        "sys.argv = ['oacli', *sys.argv[1:]]\n"
        "runpy.run_module('oacli', run_name='__main__')\n"
    )
    start = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", child, "smooth", str(ISS), "--input", str(path), "--out",
                           str(tmp_path / "run"), "-q"], env=env, capture_output=True, check=False)
    elapsed = time.monotonic() - start
    output = (proc.stdout + proc.stderr).decode()
    assert proc.returncode == 2, output
    assert "topic /trajectory" in output and str(MAX_MESSAGES_PER_TOPIC) in output and len(output.splitlines()) == 1
    assert elapsed < 30, elapsed
    # the file itself (read whole), one decompressed chunk at a time and the interpreter with oacli imported
    peak_bytes = int(hwm.read_text()) * 1024  # VmHWM is in kB
    assert peak_bytes < 2 * path.stat().st_size + 64 * 2**20 + 400 * 2**20, peak_bytes


# -- configs ------------------------------------------------------------------------------------------------------


def _config(tmp_path: Path, edit) -> Path:
    text = edit(ISS.read_text())
    path = tmp_path / "cfg.yaml"
    path.write_text(text)
    assert len(text.encode()) <= 1024 * 1024
    return path


@pytest.mark.parametrize(("edit", "field", "limit"), [
    # half a million items in a 1 MiB file (a minute of parsing before)
    (lambda t: t + "\nextra: [" + ",".join(["0"] * 500_000) + "]\n", "extra", MAX_CONFIG_LIST_ITEMS),
    (lambda t: t.replace("environment:\n", "environment:\n  keep_out: [" + ",".join(["{}"] * 200_000) + "]\n", 1),
     "environment.keep_out", MAX_CONFIG_LIST_ITEMS),
    (lambda t: t + "\nwide: {" + ",".join(f"k{i}: 0" for i in range(50_000)) + "}\n", "wide",
     MAX_CONFIG_MAPPING_KEYS),
    # aliases: 1000 × 1000 values from 2000 written
    (lambda t: t + "\na: &a [" + ",".join(["0"] * 999) + "]\nb: [" + ",".join(["*a"] * 999) + "]\n", "b.",
     MAX_CONFIG_NODES),
])
def test_configs_with_huge_lists_exit_2_naming_the_field_and_the_limit(tmp_path, edit, field, limit):
    path = _config(tmp_path, edit)
    start = time.monotonic()
    with pytest.raises(ConfigSizeError) as err:
        load_config(path)
    assert time.monotonic() - start < 10
    message = str(err.value)
    assert message.startswith(f"{path}: {field}") and str(limit) in message and "\n" not in message
    result = runner.invoke(app, ["track", str(path), "--out", str(tmp_path / "run"), "-q"])
    assert result.exit_code == 2 and f"{path}: {field}" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "run").exists()


def test_configs_at_the_limits_still_load(tmp_path):
    data = yaml.safe_load(ISS.read_text())
    data["notes"] = list(range(MAX_CONFIG_LIST_ITEMS))  # unknown key: refused by the schema, not by the size
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(Exception) as err:
        load_config(path)
    assert not isinstance(err.value, ConfigSizeError) and "notes" in str(err.value)
    assert load_config(ISS).name  # the shipped configs are far below every limit
