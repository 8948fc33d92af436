"""``excite`` and ``plan`` journal their MCAP while they compute, so a SIGKILL mid-run leaves a file the
``mcap`` package reads up to its last complete chunk, ``oacli logs recover`` saves, and a run folder that does not
look complete."""

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
import yaml
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from typer.testing import CliRunner

from oacli.cli import app
from oacli.io.runfolder import is_complete
from oacli.planning.tree import Tree
from oacli.stages.excite_journal import TOPIC_SCP
from oacli.stages.plan_journal import MAX_NODES_PER_RECORD, TOPIC_PLAN_GROWTH, PlanJournal
from tests.conftest import REPO
from tests.plan_checks import S1

ISS = REPO / "configs" / "iss_reswarm.yaml"
runner = CliRunner()


def stream_messages(data: bytes) -> tuple[list[tuple[str, int, bytes]], int, bool]:
    """``(topic, log_time, data)`` of every message the ``mcap`` package's stream reader (CRCs checked) yields,
    the number of chunks, and whether it stopped at a cut."""
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
                chunks += 1
                for inner in breakup_chunk(record, validate_crc=True):
                    take(inner)
            else:
                take(record)
    except Exception:  # the reader raises at the cut
        return out, chunks, True
    return out, chunks, False


def _journal(out: Path, stage: str) -> Path | None:
    for path in out.glob(f".{stage}.mcap.*.partial") if out.exists() else ():
        return path
    return None


def _run_and_kill(args: list[str], out: Path, stage: str, chunks: int, timeout_s: float = 120.0) -> tuple[Path, bytes]:
    """Start ``oacli <args>``, wait until its journal holds ``chunks`` complete chunks, SIGKILL it; return the
    journal's path and its bytes after the kill."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", "oacli", *args, "--out", str(out), "--quiet"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + timeout_s
    try:
        while True:
            assert proc.poll() is None, f"the run ended before it was killed: {proc.communicate()}"
            assert time.monotonic() < deadline, "timed out waiting for the journal"
            path = _journal(out, stage)
            if path is not None:
                try:
                    _, n, _ = stream_messages(path.read_bytes())
                except FileNotFoundError:
                    n = 0
                if n >= chunks:
                    break
            time.sleep(0.02)
        proc.kill()
        proc.communicate()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    return path, path.read_bytes()


def _check_recover(path: Path, messages: int, tmp_path: Path, config: bytes) -> None:
    fixed = tmp_path / "fixed.mcap"
    result = runner.invoke(app, ["logs", "recover", str(path), str(fixed)])
    assert result.exit_code == 3, result.output  # data were lost at the cut
    assert f"{messages} messages saved" in result.output
    with open(fixed, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        assert sum(1 for _ in reader.iter_messages()) == messages
        assert next(a for a in reader.iter_attachments() if a.name == "config.yaml").data == config


def _not_complete(out: Path, stage: str) -> None:
    assert not (out / f"{stage}.mcap").exists()
    assert not (out / "summary.json").exists() and not is_complete(out)


def test_sigkill_during_the_planner_search_leaves_its_growth_so_far(tmp_path):
    data = yaml.safe_load(S1.read_text())
    data["planner"].update({"max_iterations": 10_000_000, "time_budget_s": 600.0, "anytime": True})
    cfg = tmp_path / "s1_long.yaml"
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    out = tmp_path / "run"
    path, raw = _run_and_kill(["plan", str(cfg)], out, "plan", chunks=3)
    messages, _, stopped = stream_messages(raw)
    growth = [json.loads(d) for topic, _, d in messages if topic == TOPIC_PLAN_GROWTH]
    assert len(growth) >= 3
    # time order, the tree growing record by record, nodes numbered without gaps, best cost never rising
    assert [t for _, t, _ in messages] == sorted(t for _, t, _ in messages)
    nodes = np.concatenate([g["node"] for g in growth])
    np.testing.assert_array_equal(nodes, np.arange(nodes.size))
    assert [g["nodes"] for g in growth] == sorted(g["nodes"] for g in growth) and growth[-1]["nodes"] == nodes.size
    # parents are nodes of the tree at the record (a rewire may give an old node a newer parent)
    assert all(-1 <= p < g["nodes"] and (p == -1) == (n == 0) for g in growth
               for p, n in zip(g["parent"], g["node"], strict=True))
    assert sum(len(g["rewired"]) for g in growth) > 0  # LQR-RRT* rewires, and the journal reports it
    costs = [g["best_cost"] for g in growth if g["best_cost"] is not None]
    assert costs == sorted(costs, reverse=True)
    assert all(np.all(np.isfinite(np.asarray(g["position"], dtype=float))) for g in growth)
    _check_recover(path, len(messages), tmp_path, (out / "config.yaml").read_bytes())
    _not_complete(out, "plan")
    # killed mid-write or between chunks: either way no record is half-read
    assert stopped or raw[-8:] != b"\x89MCAP0\r\n"


def test_sigkill_during_the_excitation_design_leaves_its_scp_iterations(tmp_path):
    data = yaml.safe_load(ISS.read_text())
    data["excitation"]["steps"] = 40  # a smaller design: its first iterations come sooner
    cfg = tmp_path / "excite.yaml"
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    out = tmp_path / "run"
    path, raw = _run_and_kill(["excite", str(cfg)], out, "excite", chunks=3)
    messages, _, _ = stream_messages(raw)
    scp = [json.loads(d) for topic, _, d in messages if topic == TOPIC_SCP]
    assert len(scp) >= 2
    assert [t for _, t, _ in messages] == sorted(t for _, t, _ in messages)
    first = scp[0]
    assert first["iteration"] == 1 and first["position"] is not None
    steps = 40
    assert np.asarray(first["input"]).shape == (steps, 6) and np.asarray(first["position"]).shape == (steps + 1, 3)
    for rec in scp:
        assert rec["trust_region_force"] > 0 and rec["trust_region_torque"] > 0
        assert (rec["position"] is not None) == (rec["accepted"] or rec is first or rec["iteration"] == 1)
    # within one start the merit never rises (only decreasing steps are accepted)
    merits = [r["merit"] for r in scp if r["start"] == first["start"]]
    assert merits == sorted(merits, reverse=True)
    _check_recover(path, len(messages), tmp_path, (out / "config.yaml").read_bytes())
    _not_complete(out, "excite")


# -- the plan journal's bounds, without a process ------------------------------------------------------------------


class _Writer:
    """Collects what a journal writes (stands for the MCAP writer)."""

    def __init__(self) -> None:
        self.records: list[dict] = []
        self.flushes = 0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None

    def write_json(self, topic, schema_name, schema, t, record) -> None:
        self.records.append({"t": t, **record})

    def flush(self) -> None:
        self.flushes += 1


def test_plan_journal_splits_large_growth_and_reports_rewires():
    writer = _Writer()
    journal = PlanJournal(lambda: writer)  # type: ignore[arg-type, return-value]
    tree = Tree(np.zeros(6))
    n_new = 2 * MAX_NODES_PER_RECORD + 7
    for i in range(n_new):
        tree.add(np.full(6, 0.001 * i), i, float(i), 1, steps=10, iteration=i + 1, wall_time_s=0.0)
    journal.record(n_new, tree, float("inf"))
    assert [len(r["node"]) for r in writer.records] == [MAX_NODES_PER_RECORD, MAX_NODES_PER_RECORD, 8]
    assert writer.flushes == 3 and all(r["best_cost"] is None for r in writer.records)
    tree.rewire(5, 0, 0.5, steps=12, iteration=n_new + 1)
    journal.record(n_new + 1, tree, 3.0)
    last = writer.records[-1]
    assert list(last["rewired"]) == [5] and list(last["new_parent"]) == [0] and len(last["node"]) == 0
    assert last["best_cost"] == 3.0
    journal.discard()
    journal.record(n_new + 2, tree, 2.0)  # closed: writes nothing
    assert len(writer.records) == 4


@pytest.mark.parametrize("kind", ["lqr-rrt-star", "kino-rrt"])
def test_planners_call_on_iteration_with_their_growing_tree(kind):
    from oacli.planning.kino_rrt import KinoRrtSettings, plan_kino_rrt
    from oacli.planning.lqr_rrt_star import LqrRrtStarSettings, plan_lqr_rrt_star
    from tests.plan_checks import scene_problem

    problem = scene_problem()
    seen: list[tuple[int, int, float]] = []

    def on_iteration(iteration, tree, best_cost):
        seen.append((iteration, tree.n, best_cost))

    rng = np.random.default_rng(3)
    if kind == "lqr-rrt-star":
        result = plan_lqr_rrt_star(problem, LqrRrtStarSettings(max_iterations=150, anytime=True), rng,
                                   on_iteration=on_iteration)
    else:
        result = plan_kino_rrt(problem, KinoRrtSettings(max_iterations=150), rng, on_iteration=on_iteration)
    iterations = [s[0] for s in seen]
    assert iterations == list(range(iterations[0], iterations[0] + len(seen)))  # every iteration, in order
    assert [s[1] for s in seen] == sorted(s[1] for s in seen) and seen[-1][1] <= len(result.tree)
    finite = [s[2] for s in seen if np.isfinite(s[2])]
    assert finite == sorted(finite, reverse=True)
    if kind == "lqr-rrt-star" and result.solved:
        assert finite and finite[-1] == pytest.approx(result.solutions[-1].cost)


def test_a_design_failing_its_final_check_keeps_its_journal_as_the_record(tmp_path):
    """A goal tolerance no design meets: exit 3 after the SCP; the folder holds the journal as a complete
    ``excite.mcap`` (every iteration, readable by the seeking reader) next to a ``failed`` summary."""
    data = yaml.safe_load(ISS.read_text())
    data["excitation"].update({"steps": 40, "scp": {"max_iterations": 2},
                               "terminal_tolerance": {"position_m": 1e-15, "velocity_mps": 1e-15,
                                                      "attitude_rad": 1e-15, "angular_velocity_radps": 1e-15}})
    cfg = tmp_path / "tight.yaml"
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    out = tmp_path / "run"
    result = runner.invoke(app, ["excite", str(cfg), "--out", str(out), "--quiet"])
    assert result.exit_code == 3, result.output
    assert "excitation.terminal_tolerance" in result.output and "Traceback" not in result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and not is_complete(out) and summary["files"]["mcap"] == "excite.mcap"
    with open(out / "excite.mcap", "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        records = [json.loads(m.data) for _, c, m in reader.iter_messages() if c.topic == TOPIC_SCP]
    assert 1 <= len(records) and records[-1]["iteration"] >= 1
    assert not list(out.glob(".*.partial"))
