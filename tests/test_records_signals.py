"""``plan`` and ``excite`` (offline SCP and RATTLE closed loop) under SIGKILL, SIGTERM and SIGINT.

* SIGKILL at a random moment (seeded): every MCAP left in the run folder is read by the ``mcap`` package's stream
  reader (CRCs checked) up to its last complete chunk -- the chunks it yields are exactly the complete chunk records
  a plain walk of the file finds -- and no ``summary.json`` makes the folder look complete.
* SIGTERM and SIGINT: exit 143 / 130, one ``error: interrupted`` line, ``summary.json`` says ``interrupted``, and the
  computation so far is kept as the stage's MCAP, complete (summary section, CRCs) and listed in the summary, with a
  ``/log`` warning naming the signal; no ``.partial`` file is left.
* Without processes: a signal arriving while the native MCAP writer calls back into Python is held and raised after
  it (the writer is not broken; the run ends ``interrupted``, not ``failed``), and an interrupted plan journal writes
  its last growth before it is kept.
"""

from __future__ import annotations

import io
import json
import os
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk

from oacli.io.runfolder import is_complete
from oacli.stages.excite_journal import TOPIC_SCP
from oacli.stages.plan_journal import TOPIC_PLAN_GROWTH
from tests.conftest import REPO
from tests.plan_checks import S1
from tests.test_cli_excite import small_iss

ISS = REPO / "configs" / "iss_reswarm.yaml"
MAGIC = b"\x89MCAP0\r\n"
OP_CHUNK = 0x06


# -- configs: computations long enough to be stopped midway ---------------------------------------------------------


def _plan_config(tmp_path: Path) -> Path:
    data = yaml.safe_load(S1.read_text())
    data["planner"].update({"max_iterations": 10_000_000, "time_budget_s": 600.0, "anytime": True})
    path = tmp_path / "plan_long.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _offline_config(tmp_path: Path) -> Path:
    data = yaml.safe_load(ISS.read_text())
    # 20 starts screened for 50 iterations each: about 1000 SCP iterations (a minute), never converged early
    data["excitation"].update({"steps": 40, "scp": {"max_iterations": 1000, "tolerance": 1e-300, "starts": 20,
                                                    "screening_iterations": 50}})
    path = tmp_path / "excite_long.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _rattle_config(tmp_path: Path) -> Path:
    return small_iss(tmp_path / "rattle_long.yaml", method="rattle",
                     rattle={"duration_s": 600.0, "replan_period_s": 12.0,
                             "limits": {"force_N": [0.15] * 3, "torque_Nm": [0.015] * 3}})


CASES = {  # name: (config maker, command, stage, topic the journal must hold)
    "plan": (_plan_config, "plan", "plan", TOPIC_PLAN_GROWTH),
    "excite-offline": (_offline_config, "excite", "excite", TOPIC_SCP),
    "excite-rattle": (_rattle_config, "excite", "excite", "/state/true"),
}


# -- reading ------------------------------------------------------------------------------------------------------


def complete_chunks(data: bytes) -> int:
    """Chunk records wholly inside ``data``, by a plain walk of the records (opcode, u64 length, body)."""
    assert data[:8] == MAGIC
    pos, chunks = 8, 0
    while pos + 9 <= len(data):
        opcode = data[pos]
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        if pos + 9 + length > len(data):
            break
        chunks += opcode == OP_CHUNK
        pos += 9 + length
    return chunks


def stream_read(data: bytes) -> tuple[list[tuple[str, int, bytes]], int, bool]:
    """Messages ``(topic, log_time, data)`` the ``mcap`` package's stream reader yields (CRCs checked), the chunks
    it read, and whether it stopped at a cut."""
    channels: dict[int, str] = {}
    out: list[tuple[str, int, bytes]] = []
    chunks = 0

    def take(record) -> None:
        if isinstance(record, Channel):
            channels[record.id] = record.topic
        elif isinstance(record, Message):
            out.append((channels[record.channel_id], record.log_time, bytes(record.data)))

    try:
        for record in StreamReader(io.BytesIO(data), validate_crcs=True, emit_chunks=True).records:
            if isinstance(record, Chunk):
                for inner in breakup_chunk(record, validate_crc=True):
                    take(inner)
                chunks += 1  # counted once every message of it was read
            else:
                take(record)
    except Exception:  # the reader raises at the cut
        return out, chunks, True
    return out, chunks, False


def _mcaps(out: Path) -> list[Path]:
    return sorted(p for p in out.iterdir() if ".mcap" in p.name) if out.exists() else []


def _start(args: list[str], out: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO)}

    def default_sigint() -> None:  # a child of a shell's background job inherits SIGINT ignored
        signal.signal(signal.SIGINT, signal.SIG_DFL)

    return subprocess.Popen([sys.executable, "-m", "oacli", *args, "--out", str(out), "--quiet"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=default_sigint)


def _wait_for_journal(proc: subprocess.Popen, out: Path, stage: str, min_bytes: int, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        assert proc.poll() is None, f"the run ended before it was stopped: {proc.communicate()}"
        assert time.monotonic() < deadline, "timed out waiting for the journal"
        for path in out.glob(f".{stage}.mcap.*.partial") if out.exists() else ():
            try:
                if path.stat().st_size >= min_bytes:
                    return
            except FileNotFoundError:
                pass
        time.sleep(0.02)


def _stop(proc: subprocess.Popen, signum: int) -> tuple[str, str]:
    try:
        proc.send_signal(signum)
        return proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


# -- SIGKILL at random moments ---------------------------------------------------------------------------------------


def _kill_at_random_moment(case: str, tmp_path: Path, seed: int) -> None:
    make, command, stage, topic = CASES[case]
    cfg = make(tmp_path)
    rng = np.random.default_rng([seed, 0x4B494C4C])  # "KILL"
    out = tmp_path / f"run-{seed}"
    proc = _start([command, str(cfg)], out)
    _wait_for_journal(proc, out, stage, min_bytes=1)
    time.sleep(float(rng.uniform(0.0, 2.5)))  # a random moment of the computation (or of a write)
    _stop(proc, signal.SIGKILL)
    assert proc.returncode == -signal.SIGKILL
    files = _mcaps(out)
    assert files, "the killed run left no MCAP"
    seen_topic = False
    for path in files:
        data = path.read_bytes()
        messages, chunks, stopped = stream_read(data)
        # read up to its last complete chunk: every chunk record wholly on disk, no more
        assert chunks == complete_chunks(data), path.name
        assert [t for _, t, _ in messages] == sorted(t for _, t, _ in messages), path.name  # time order
        seen_topic |= any(tp == topic for tp, _, _ in messages)
        if not path.name.endswith(".partial"):  # a final name is only ever a complete file
            with open(path, "rb") as f:
                sum(1 for _ in make_reader(f, validate_crcs=True).iter_messages())
            assert not stopped
    if case == "excite-rattle":  # /state/true abreast of the controller topics, up to about the kill
        path = files[0]
        messages, _, _ = stream_read(path.read_bytes())
        true_t = [t for tp, t, _ in messages if tp == "/state/true"]
        ctrl_t = [t for tp, t, _ in messages if tp == "/control/applied"]
        if true_t:
            assert ctrl_t and abs(max(true_t) - max(ctrl_t)) <= 0.2e9 + 1
            assert max(true_t) >= max(t for _, t, _ in messages) - 0.2e9
    # the journal's own records whenever a chunk of messages was complete (not only the metadata)
    assert seen_topic or not any(stream_read(p.read_bytes())[0] for p in files)
    assert not is_complete(out) and not (out / "summary.json").exists()


def test_sigkill_at_a_random_moment_of_the_rattle_loop_leaves_mcaps_readable_to_their_last_chunk(tmp_path):
    """The fast variant: the RATTLE loop (plan and the offline design are killed at a fixed moment in the default
    run, tests/test_records_journal.py)."""
    _kill_at_random_moment("excite-rattle", tmp_path, seed=1)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3, 4])
@pytest.mark.parametrize("case", list(CASES))
def test_sigkill_at_random_moments(case, seed, tmp_path):
    _kill_at_random_moment(case, tmp_path, seed)


# -- SIGTERM and SIGINT: interrupted, exit code, the computation so far kept ------------------------------------------


def _interrupt(case: str, signum: int, tmp_path: Path) -> None:
    make, command, stage, topic = CASES[case]
    cfg = make(tmp_path)
    out = tmp_path / "run"
    proc = _start([command, str(cfg)], out)
    _wait_for_journal(proc, out, stage, min_bytes=20_000)  # some records on disk
    _, err = _stop(proc, signum)
    assert proc.returncode == 128 + signum, err
    name = signal.Signals(signum).name
    assert err.strip().splitlines() == (["error: interrupted"] if signum == signal.SIGINT
                                        else [f"error: interrupted (terminated by {name})"])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["stage"] == stage and not is_complete(out)
    assert (name in summary["error"]) == (signum != signal.SIGINT)
    assert summary["files"] == {"config": "config.yaml", "mcap": f"{stage}.mcap"}
    assert sorted(p.name for p in out.iterdir()) == ["config.yaml", f"{stage}.mcap", "summary.json"]
    with open(out / f"{stage}.mcap", "rb") as f:  # complete: the seeking reader, summary and CRCs
        reader = make_reader(f, validate_crcs=True)
        stats = reader.get_summary().statistics
        messages = [(c.topic, m) for _, c, m in reader.iter_messages()]
        config = next(a for a in reader.iter_attachments() if a.name == "config.yaml").data
    assert config == (out / "config.yaml").read_bytes()
    assert stats.message_count == len(messages)
    assert sum(1 for tp, _ in messages if tp == topic) >= 1
    log = [m for tp, m in messages if tp == "/log"]
    assert len(log) == 1 and b"journal of the computation so far is kept" in log[0].data
    assert (b"SIGTERM" in log[0].data) == (signum == signal.SIGTERM)
    times = [m.log_time for _, m in messages]
    assert times == sorted(times) and log[0].log_time == times[-1]
    if case == "plan":  # the last growth record holds every node numbered so far
        growth = [json.loads(m.data) for tp, m in messages if tp == TOPIC_PLAN_GROWTH]
        nodes = np.concatenate([g["node"] for g in growth])
        np.testing.assert_array_equal(nodes, np.arange(nodes.size))
        assert growth[-1]["nodes"] == nodes.size
    if case == "excite-rattle":
        true_t = [m.log_time for tp, m in messages if tp == "/state/true"]
        ctrl_t = [m.log_time for tp, m in messages if tp == "/control/applied"]
        assert abs(max(true_t) - max(ctrl_t)) <= 0.2e9 + 1  # the buffered steps were written before closing


@pytest.mark.parametrize(("case", "signum"), [("plan", signal.SIGINT), ("excite-offline", signal.SIGTERM),
                                              ("excite-rattle", signal.SIGINT)])
def test_an_interrupted_stage_keeps_its_journal_and_says_interrupted(case, signum, tmp_path):
    _interrupt(case, signum, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize(("case", "signum"), [("plan", signal.SIGTERM), ("excite-offline", signal.SIGINT),
                                              ("excite-rattle", signal.SIGTERM)])
def test_an_interrupted_stage_keeps_its_journal_other_signals(case, signum, tmp_path):
    _interrupt(case, signum, tmp_path)


# -- without processes ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_inside_the_native_writer_is_raised_after_it(signum, tmp_path, monkeypatch):
    """The signal arrives while foxglove's writer calls our file object: it is held, the writer stays sound, and
    the interruption is raised after the write -- the journal is kept, not lost to "I/O error from writing"."""
    from oacli.io import mcap_write
    from oacli.io.mcap_write import StageMcapWriter
    from oacli.signals import Terminated, terminate_like_interrupt
    from oacli.stages.stage_journal import StageJournal

    original = mcap_write._SpoolFile.write
    sent: list[bool] = []
    armed: list[bool] = []

    def write(self, data):
        if armed and not sent:  # a chunk being written by the native writer
            sent.append(True)
            signal.getsignal(signum)(signum, None)  # the handler runs here, inside the native call
        return original(self, data)

    monkeypatch.setattr(mcap_write._SpoolFile, "write", write)
    path = tmp_path / "stage.mcap"
    expected = KeyboardInterrupt if signum == signal.SIGINT else Terminated
    rows = 0
    with pytest.raises(expected), terminate_like_interrupt():
        with StageJournal(lambda: StageMcapWriter(path, stage="stage", config_yaml="a: 1\n",
                                                  time_ordered=True), flush_wall_s=0.0) as journal:
            for i in range(400):
                # 30 kB records, flushed every 20: a 256 KiB chunk fills (and is written) inside the native log call
                journal.writer().write_json("/x", "X", {"properties": {}}, float(i), {"i": i, "pad": "p" * 30_000})
                rows += 1
                if i == 50:
                    armed.append(True)
                if i % 20 == 19:
                    journal.flush()
    assert sent and 50 < rows < 400
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        got = [json.loads(m.data)["i"] for _, c, m in reader.iter_messages() if c.topic == "/x"]
        log = [m.data for _, c, m in reader.iter_messages() if c.topic == "/log"]
    # the records before the one whose write was interrupted (the rest of that batch is dropped)
    assert got == list(range(len(got))) and len(got) >= 40
    assert len(log) == 1
    assert not list(tmp_path.glob(".*.partial"))


def test_held_defers_a_termination_to_the_end_of_the_block():
    from oacli.signals import PENDING, Terminated, held, terminate_like_interrupt

    order = []
    with pytest.raises(Terminated) as info, terminate_like_interrupt():
        with held():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.01)
            order.append("after the signal, inside")
        order.append("never")
    assert order == ["after the signal, inside"] and info.value.signum == signal.SIGTERM and not PENDING
    # outside the block handlers are restored; Python's own SIGINT handler is back
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_an_interrupted_plan_journal_writes_its_last_growth(tmp_path):
    """Interrupted between two records, the journal first writes the nodes of the last finished iteration."""
    from oacli.io.mcap_write import StageMcapWriter
    from oacli.planning.tree import Tree
    from oacli.stages.plan_journal import PlanJournal

    path = tmp_path / "plan.mcap"
    tree = Tree(np.zeros(6))
    with pytest.raises(KeyboardInterrupt):
        with PlanJournal(lambda: StageMcapWriter(path, stage="plan", config_yaml="a: 1\n", time_ordered=True)) as j:
            for i in range(1, 31):
                tree.add(np.full(6, 0.01 * i), i - 1, float(i), 1, steps=10, iteration=i, wall_time_s=0.0)
                j.on_iteration(i, tree, float("inf") if i < 20 else 100.0 - i)
                if i == 1:
                    j.record(i, tree, float("inf"))
            tree.add(np.full(6, 9.0), 0, 1.0, 1, steps=10, iteration=31, wall_time_s=0.0)  # iteration 31 cut short
            raise KeyboardInterrupt
    with open(path, "rb") as f:
        growth = [json.loads(m.data) for _, c, m in make_reader(f, validate_crcs=True).iter_messages()
                  if c.topic == TOPIC_PLAN_GROWTH]
    assert [g["iteration"] for g in growth] == [1, 30]
    assert growth[-1]["nodes"] == 31 and growth[-1]["best_cost"] == 70.0  # root + 30 nodes; not the cut one
    np.testing.assert_array_equal(np.concatenate([g["node"] for g in growth]), np.arange(31))


def test_held_in_another_thread_does_not_hold_the_main_threads_signals():
    import threading

    from oacli.signals import Terminated, held, terminate_like_interrupt

    inside, release = threading.Event(), threading.Event()

    def worker() -> None:
        with held():
            inside.set()
            release.wait(5)

    thread = threading.Thread(target=worker)
    thread.start()
    try:
        inside.wait(5)
        with pytest.raises(Terminated), terminate_like_interrupt():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1.0)  # interrupted at once: the worker's block does not hold it
            pytest.fail("the signal was held by another thread's block")
    finally:
        release.set()
        thread.join()


def test_an_interruption_while_a_plan_record_is_flushed_keeps_every_node_once(tmp_path, monkeypatch):
    """The signal arrives while a growth record goes to disk: the record and its bookkeeping complete first (an
    atomic block), then the interruption; the kept file numbers every node once (it was lost: the journal's
    bookkeeping was half updated and keeping it failed)."""
    from oacli.io.mcap_write import StageMcapWriter
    from oacli.planning.tree import Tree
    from oacli.signals import terminate_like_interrupt
    from oacli.stages.plan_journal import PlanJournal

    original = StageMcapWriter.flush
    armed: list[bool] = []

    def flush(self):
        if armed:
            armed.clear()
            signal.getsignal(signal.SIGINT)(signal.SIGINT, None)  # Ctrl-C arrives here
        return original(self)

    monkeypatch.setattr(StageMcapWriter, "flush", flush)
    path = tmp_path / "plan.mcap"
    tree = Tree(np.zeros(6))
    done = []
    with pytest.raises(KeyboardInterrupt), terminate_like_interrupt():
        with PlanJournal(lambda: StageMcapWriter(path, stage="plan", config_yaml="a: 1\n", time_ordered=True)) as j:
            for i in range(1, 200):
                tree.add(np.full(6, 0.01 * i), i - 1, float(i), 1, steps=10, iteration=i, wall_time_s=0.0)
                j.on_iteration(i, tree, 100.0 - 0.1 * i)
                if i % 10 == 0:
                    armed.extend([True] if i == 50 else [])
                    j.record(i, tree, 100.0 - 0.1 * i)
                done.append(i)
    assert done[-1] == 49  # interrupted at the end of iteration 50's record, not inside it
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        growth = [json.loads(m.data) for _, c, m in reader.iter_messages() if c.topic == TOPIC_PLAN_GROWTH]
    assert [g["iteration"] for g in growth] == [10, 20, 30, 40, 50]
    np.testing.assert_array_equal(np.concatenate([g["node"] for g in growth]), np.arange(51))
    assert growth[-1]["nodes"] == 51 and growth[-1]["best_cost"] == pytest.approx(95.0)
