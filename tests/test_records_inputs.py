"""Final names never become symlinks; ``logs verify/recover`` refuse what is not a regular
file and read with bounded memory; the resource estimate refuses configs beyond the budget naming the field; no exit
1 for input a user can fix; messages that name the real cause."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

import oacli.io.atomic as atomic_module
from oacli.cli import app
from oacli.commands.common import load_config_with_seed
from oacli.errors import ConfigError
from oacli.io.atomic import WriteError, atomic_file, atomic_path, write_text_atomic
from tests.conftest import REPO, memory_cap

ISS = REPO / "configs" / "iss_reswarm.yaml"
runner = CliRunner()


def _run_subprocess(args: list[str], timeout_s: float = 60.0, **kwargs) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, "-m", "oacli", *args], env=env, capture_output=True, text=True,
                          timeout=timeout_s, check=False, **kwargs)


# -- 3: final names are never symlinks --------------------------------------------------------------------------

def _swap_for_symlink(path: Path, target: Path) -> None:
    path.unlink()
    path.symlink_to(target)


@pytest.mark.parametrize("how", ["file", "path"])
def test_a_temporary_swapped_for_a_symlink_before_the_rename_is_refused(tmp_path, how):
    outside = tmp_path / "outside.txt"
    outside.write_text("secret\n")
    run = tmp_path / "run"
    run.mkdir()
    final = run / "summary.json"
    with pytest.raises(WriteError, match="replaced"):
        if how == "file":
            with atomic_file(final) as handle:
                handle.write(b"{}")
                handle.flush()
                _swap_for_symlink(next(run.glob(".summary.json.*.partial")), outside)
        else:
            with atomic_path(final) as tmp:
                tmp.write_bytes(b"{}")
                _swap_for_symlink(tmp, outside)
    assert not final.exists() and not final.is_symlink()
    assert outside.read_text() == "secret\n"


def test_a_final_name_that_turns_out_a_symlink_after_the_rename_is_removed(tmp_path, monkeypatch):
    """The narrowest window: the temporary swapped between the check and the rename; the check after catches it."""
    outside = tmp_path / "outside.txt"
    outside.write_text("secret\n")
    real_replace = os.replace

    def racing_replace(src, dst, *, src_dir_fd=None, dst_dir_fd=None):
        os.unlink(src, dir_fd=src_dir_fd)
        os.symlink(outside, src, dir_fd=src_dir_fd)
        return real_replace(src, dst, src_dir_fd=src_dir_fd, dst_dir_fd=dst_dir_fd)

    monkeypatch.setattr(atomic_module.os, "replace", racing_replace)
    run = tmp_path / "run"
    run.mkdir()
    with pytest.raises(WriteError, match="symlink"):
        write_text_atomic(run / "track.mcap", "data")
    assert not (run / "track.mcap").is_symlink() and not (run / "track.mcap").exists()
    assert outside.read_text() == "secret\n"


def test_a_track_run_whose_temporaries_are_swapped_never_ends_with_symlinks(tmp_path, monkeypatch):
    outside = tmp_path / "outside.bin"
    outside.write_bytes(b"keep")
    real_replace = os.replace
    swapped: list[str] = []

    def racing_replace(src, dst, *, src_dir_fd=None, dst_dir_fd=None):
        if str(dst) in ("track.mcap", "summary.json") and str(dst) not in swapped:
            swapped.append(str(dst))
            os.unlink(src, dir_fd=src_dir_fd)
            os.symlink(outside, src, dir_fd=src_dir_fd)
        return real_replace(src, dst, src_dir_fd=src_dir_fd, dst_dir_fd=dst_dir_fd)

    monkeypatch.setattr(atomic_module.os, "replace", racing_replace)
    out = tmp_path / "run"
    result = runner.invoke(app, ["track", str(ISS), "--set", "simulation.settle_time_s=1", "--set",
                                 "outputs.plots=none", "--out", str(out), "--quiet"])
    assert result.exit_code != 0 and "symlink" in result.output, result.output
    assert swapped and not any(p.is_symlink() for p in out.iterdir())
    assert outside.read_bytes() == b"keep"


# -- 4: logs verify / recover --------------------------------------------------------------------------------------

def _capped_data() -> None:
    """A child's data segment capped at 700 MiB (reading /dev/zero whole fails fast instead of filling memory)."""
    limit = 700 * 2**20
    resource.setrlimit(resource.RLIMIT_DATA, (limit, limit))


def test_logs_refuse_devices_fifos_and_folders_without_blocking(tmp_path):
    fifo = tmp_path / "pipe.mcap"
    os.mkfifo(fifo)
    link = tmp_path / "zero.mcap"
    link.symlink_to("/dev/zero")
    result = runner.invoke(app, ["logs", "verify", str(tmp_path)])
    assert result.exit_code == 2 and "is a folder" in result.output, result.output
    # In child processes (main reads /dev/zero until memory runs out and blocks on a FIFO forever).
    for args, what in ((["verify", str(link)], "is a device"), (["verify", str(fifo)], "FIFO"),
                       (["recover", "/dev/zero", str(tmp_path / "o.mcap")], "is a device")):
        start = time.monotonic()
        done = _run_subprocess(["logs", *args], timeout_s=60, preexec_fn=_capped_data)
        assert done.returncode == 2 and what in done.stderr, (args, done.stderr)
        assert time.monotonic() - start < 60
    assert not (tmp_path / "o.mcap").exists()


def test_logs_verify_reads_a_large_file_with_bounded_memory(tmp_path):
    """A 1.5 GiB (sparse) file under a 700 MiB data limit: reading it whole fails; the mapped walk does not."""
    big = tmp_path / "big.mcap"
    with open(big, "wb") as f:
        f.write(b"\x89MCAP0\r\n")
        f.truncate(3 * 2**29)
    done = _run_subprocess(["logs", "verify", str(big)], timeout_s=120, preexec_fn=_capped_data)
    assert done.returncode == 3, done.stderr
    assert "opcode 0x00" in done.stderr and "Traceback" not in done.stderr


def _small_mcap(path: Path) -> Path:
    from mcap.writer import Writer

    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("s", "jsonschema", b"{}")
        channel = writer.register_channel("/a", "json", schema)
        for i in range(10):
            writer.add_message(channel, i, b"{}", i)
        writer.finish()
    return path


def test_logs_recover_refuses_an_existing_out_unless_force(tmp_path):
    src = _small_mcap(tmp_path / "in.mcap")
    out = tmp_path / "out.mcap"
    out.write_text("precious")
    result = runner.invoke(app, ["logs", "recover", str(src), str(out)])
    assert result.exit_code == 2 and "--force" in result.output
    assert out.read_text() == "precious"
    result = runner.invoke(app, ["logs", "recover", str(src), str(out), "--force"])
    assert result.exit_code == 0 and "10 messages saved" in result.output
    assert runner.invoke(app, ["logs", "verify", str(out)]).exit_code == 0
    os.mkfifo(tmp_path / "fifo.mcap")
    result = runner.invoke(app, ["logs", "recover", str(src), str(tmp_path / "fifo.mcap"), "--force"])
    assert result.exit_code == 2 and "not a regular file" in result.output


# -- 6: the resource estimate and its budget -----------------------------------------------------------------------

@pytest.mark.parametrize(("assignment", "field", "reason"), [
    ("controller.horizon=500", "controller.horizon", "MiB budget"),
    ("controller.rate_hz=1e-300", "controller.rate_hz", "plant steps"),
    ("excitation.duration_s=1e9", "excitation.duration_s", "simulation steps"),
    ("excitation.rattle.duration_s=1e9", "excitation.rattle.duration_s", "simulation steps"),
])
def test_configs_beyond_the_budget_exit_2_naming_the_field(tmp_path, assignment, field, reason):
    start = time.monotonic()
    result = runner.invoke(app, ["track", str(ISS), "--set", assignment, "--out", str(tmp_path / "run"), "-q"])
    assert result.exit_code == 2, result.output
    assert f"{field}:" in result.output and reason in result.output and "Traceback" not in result.output
    assert time.monotonic() - start < 10 and not (tmp_path / "run").exists()


def test_the_budget_is_overridable_and_checked(monkeypatch):
    monkeypatch.setenv("OACLI_MEMORY_BUDGET_MB", "8192")
    assert load_config_with_seed(ISS, None, ["controller.horizon=500"]).controller.horizon == 500
    monkeypatch.setenv("OACLI_DISK_BUDGET_MB", "0.5")  # the default run writes about 1.3 MB
    with pytest.raises(ConfigError, match=r"reference\.cruise_speed_mps.*MiB of recordings.*OACLI_DISK_BUDGET_MB"):
        load_config_with_seed(ISS, None, None)
    monkeypatch.setenv("OACLI_DISK_BUDGET_MB", "lots")
    with pytest.raises(ConfigError, match="OACLI_DISK_BUDGET_MB='lots': must be a positive number"):
        load_config_with_seed(ISS, None, None)


# -- 7: no exit 1 for input a user can fix -------------------------------------------------------------------------

def test_info_on_binary_device_and_fifo_summaries_exits_2(tmp_path):
    binary, device, fifo = (tmp_path / name for name in ("binary", "device", "fifo"))
    for folder in (binary, device, fifo):
        folder.mkdir()
    (binary / "summary.json").write_bytes(bytes(range(256)) * 4)
    (device / "summary.json").symlink_to("/dev/zero")
    os.mkfifo(fifo / "summary.json")
    for folder, what in ((binary, "not a JSON summary"), (device, "is a device"), (fifo, "FIFO")):
        for target in (folder, folder / "summary.json"):
            with memory_cap(1 << 30):  # main reads /dev/zero whole: a MemoryError here, not a full machine
                result = runner.invoke(app, ["info", str(target)])
            assert result.exit_code == 2 and "internal error" not in result.output, (target, result.output)
        assert what in runner.invoke(app, ["info", str(folder)]).output


def test_plots_on_a_mission_with_an_emptied_stage_folder_warns_and_exits_0(tmp_path):
    mission = tmp_path / "mission"
    (mission / "segment-1" / "track").mkdir(parents=True)
    (mission / "summary.json").write_text(json.dumps({
        "stage": "mission", "status": "ok", "stages": {"segment-1/track": {"status": "ok"}}, "files": {}}))
    result = runner.invoke(app, ["plots", str(mission)])
    assert result.exit_code == 0, result.output
    assert "segment-1/track is not complete" in result.output and "internal error" not in result.output


class _Blocked(BaseException):
    pass


def test_a_fifo_as_reference_file_exits_2_without_blocking(tmp_path):
    import signal

    fifo = tmp_path / "reference.csv"
    os.mkfifo(fifo)

    def blocked(signum, frame):
        raise _Blocked

    previous = signal.signal(signal.SIGALRM, blocked)
    signal.alarm(30)  # main blocks forever opening the FIFO: fail instead of hanging
    try:
        result = runner.invoke(app, ["track", str(ISS), "--set", "reference.source=file", "--set",
                                     f"reference.file={fifo}", "--out", str(tmp_path / "run"), "-q"])
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    assert result.exit_code == 2 and "FIFO" in result.output, result.output
    assert not (tmp_path / "run" / "track.mcap").exists()


# -- 8: messages that name the cause ---------------------------------------------------------------------------

def test_a_tiny_acceleration_is_named_not_the_cruise_speed(tmp_path):
    result = runner.invoke(app, ["track", str(ISS), "--set", "reference.acceleration_mps2=1e-12", "--out",
                                 str(tmp_path / "run"), "-q"])
    assert result.exit_code == 2 and "reference.acceleration_mps2" in result.output
    assert "cruise_speed_mps" not in result.output
    result = runner.invoke(app, ["track", str(ISS), "--set", "reference.cruise_speed_mps=1e-9", "--out",
                                 str(tmp_path / "run2"), "-q"])
    assert result.exit_code == 2 and "reference.cruise_speed_mps" in result.output


def test_a_chunk_decompressing_past_its_declared_size_is_named_a_bomb(tmp_path):
    import zlib

    import zstandard
    from mcap.data_stream import RecordBuilder
    from mcap.records import Chunk

    from oacli.errors import InputError
    from oacli.io.mcap_io import read_stage

    body = bytes([0x7F]) + (2**20 - 9).to_bytes(8, "little") + bytes(2**20 - 9)
    builder = RecordBuilder()
    Chunk("zstd", zstandard.ZstdCompressor().compress(body), 0, 0, zlib.crc32(body[:1000]), 1000).write(builder)
    path = tmp_path / "bomb.mcap"
    path.write_bytes(b"\x89MCAP0\r\n" + builder.end())
    result = runner.invoke(app, ["logs", "verify", str(path)])
    assert result.exit_code == 3 and "decompression bomb" in result.output and "corrupt" not in result.output
    with pytest.raises(InputError, match="decompression bomb"):
        read_stage(path)
