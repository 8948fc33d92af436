"""Files written while ``oacli.io.mcap_memo.remembering()`` is active read back (``read_stage``) from what their
writer kept, equal to reading the file; a changed file, or a summary that disagrees, is read from disk."""

from __future__ import annotations

import contextvars
import os
import threading
from pathlib import Path

import numpy as np
import pytest

import oacli.io.mcap_read as mcap_read
from oacli.geometry import Box, Ellipsoid, Scene
from oacli.io import mcap_memo
from oacli.io import mcap_schema as ms
from oacli.io.mcap_io import StageMcapWriter, read_stage
from oacli.types import SolveInfo
from tests.test_mcap_io import CONFIG, random_trajectory


def _write(path: Path, seed: int = 5) -> None:
    rng = np.random.default_rng(seed)
    traj = random_trajectory(rng, n=120, frame="iss")
    scene = Scene(frame="iss", keep_in=(Box(lower=(-1.0, -1.0, -1.0), upper=(1.0, 1.0, 1.0)),),
                  keep_out=(Ellipsoid(center=(0.2, 0.0, 0.0), shape=np.eye(3) * 25.0),))
    with StageMcapWriter(path, stage="track", config_yaml=CONFIG, metadata={"seed": seed}, frame="iss") as w:
        w.write_trajectory("/trajectory", traj)
        w.write_wrenches("/disturbance", traj.t, traj.u * 0.1)
        w.write_poses(traj.t, traj.x)
        w.write_scene(scene, {"plan": traj.x[:, 0:3]})
        w.write_solver_stats(traj.t[:3], [SolveInfo("optimal", True, 1.5, 7, 0.01)] * 3)
        w.write_json(ms.TOPIC_ESTIMATE_PARAMS, "oacli.Test", {"type": "object"}, 1.0,
                     {"mass_kg": np.float64(9.5), "inertia": np.array([0.1, 0.2, 0.3]), "bad": float("nan"),
                      "pair": (1, 2)})
        w.write_log(0.5, "warning", "a warning")
        w.write_log(0.7, "info", "done")
        w.attach("extra.txt", b"hello", "text/plain")


def _assert_equal(a, b) -> None:
    assert a.trajectories.keys() == b.trajectories.keys()
    for topic, ta in a.trajectories.items():
        tb = b.trajectories[topic]
        for field in ("t", "x", "u"):
            np.testing.assert_array_equal(getattr(ta, field), getattr(tb, field))
        assert (ta.name, ta.frame) == (tb.name, tb.frame)
    assert a.wrenches.keys() == b.wrenches.keys()
    for topic, (t_a, w_a) in a.wrenches.items():
        np.testing.assert_array_equal(t_a, b.wrenches[topic][0])
        np.testing.assert_array_equal(w_a, b.wrenches[topic][1])
    for field in ("path", "json_records", "metadata", "attachments", "topics", "message_counts", "log",
                  "truncated", "bytes_read", "bytes_total"):
        assert getattr(a, field) == getattr(b, field), field


def _from_disk(path: Path, topics=None):
    """Read ``path`` in a fresh context (no remembering block active there: a new thread's view)."""
    return contextvars.Context().run(read_stage, path, topics=topics)


def _no_walk(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(self):
        raise AssertionError("the file was walked")

    monkeypatch.setattr(mcap_read._Scan, "run", refuse)


@pytest.mark.parametrize("topics", [None, ["/trajectory", "/log"], [ms.TOPIC_ESTIMATE_PARAMS, "/disturbance"]])
def test_a_remembered_file_reads_back_equal_to_the_file(tmp_path, monkeypatch, topics):
    path = tmp_path / "track.mcap"
    with mcap_memo.remembering():
        _write(path)
        disk = _from_disk(path, topics)
        with monkeypatch.context() as m:
            _no_walk(m)
            memo = read_stage(path, topics=topics)
        _assert_equal(disk, memo)
    assert memo.log == disk.log and ((topics is not None and "/log" not in topics) or len(memo.log) == 2)
    assert memo.json_records.get(ms.TOPIC_ESTIMATE_PARAMS, ({},))[0].get("bad", None) is None
    assert memo.message_counts["/robot/pose"] == 120  # counted, as in the file, though not kept
    assert not mcap_memo.active() and mcap_memo.recall(path) is None  # forgotten when the block ends


def test_nothing_is_remembered_outside_the_block(tmp_path):
    _write(tmp_path / "a.mcap")
    assert mcap_memo.recall(tmp_path / "a.mcap") is None


def test_a_file_changed_on_disk_is_read_from_disk(tmp_path):
    path, other = tmp_path / "track.mcap", tmp_path / "other.mcap"
    with mcap_memo.remembering():
        _write(path, seed=5)
        assert mcap_memo.recall(path) is not None
        _write(other, seed=6)
        os.replace(other, path)  # same name, another file (another size or modification time)
        got = read_stage(path)
    with mcap_memo.remembering():
        pass
    _assert_equal(got, read_stage(path))
    assert got.metadata["oacli"]["seed"] == "6"


def test_a_summary_that_disagrees_with_what_was_kept_falls_back_to_the_file(tmp_path):
    path = tmp_path / "track.mcap"
    with mcap_memo.remembering():
        _write(path)
        written = mcap_memo.recall(path)
        written.messages["/trajectory"].pop()  # one message short of the file's count
        got = read_stage(path)
        assert len(got.trajectories["/trajectory"].t) == 120  # the file's, not the memo's 119
        written.messages["/trajectory"].clear()
        written.metadata["another"] = {"a": "b"}  # a metadata record the file does not hold
        assert not mcap_read._WrittenScan(path, None, written).run_from_memory()


def test_a_failed_write_is_not_remembered(tmp_path):
    path = tmp_path / "track.mcap"
    with mcap_memo.remembering():
        with pytest.raises(RuntimeError), StageMcapWriter(path, stage="track", config_yaml=CONFIG) as w:
            w.write_log(0.0, "info", "x")
            raise RuntimeError("stage failed")
        assert not path.exists()
        assert mcap_memo.active() and mcap_memo._FILES.get() == {}


def test_telemetry_streams_of_a_remembered_file_equal_the_files(tmp_path, monkeypatch):
    from oacli.io.telemetry_streams import read_telemetry_streams

    rng = np.random.default_rng(9)
    t = np.arange(30) * 0.2
    path = tmp_path / "track.mcap"
    with mcap_memo.remembering():
        with StageMcapWriter(path, stage="track", config_yaml=CONFIG) as w:
            w.write_states(ms.TOPIC_STATE_MEASURED, t, rng.normal(size=(30, 13)))
            w.write_wrenches(ms.TOPIC_CONTROL_APPLIED, t, rng.normal(size=(30, 6)))
            w.write_wrenches(ms.TOPIC_CONTROL_COMMAND, t, rng.normal(size=(30, 6)))
        disk = contextvars.Context().run(read_telemetry_streams, path)
        with monkeypatch.context() as m:
            _no_walk(m)
            memo = read_telemetry_streams(path)
    for field in ("t_measured", "x_measured", "t_applied", "u_applied", "t_command", "u_command"):
        np.testing.assert_array_equal(getattr(disk, field), getattr(memo, field))
    assert (disk.config_yaml, disk.truncated, disk.bytes_read, disk.bytes_total) == (
        memo.config_yaml, memo.truncated, memo.bytes_read, memo.bytes_total)
    assert memo.config_yaml == CONFIG


def test_each_thread_remembers_only_its_own_files(tmp_path):
    """Two missions in threads of one process (a campaign on Dask's threads): each remembering block sees only the
    files its own thread wrote, and the main thread's block is not visible from a thread started inside it."""
    barrier = threading.Barrier(2, timeout=30)
    seen: dict[str, tuple[bool, bool]] = {}

    def mission(name: str, other: str) -> None:
        with mcap_memo.remembering():
            _write(tmp_path / f"{name}.mcap", seed=len(name))
            barrier.wait()  # both files are complete (and each stored) before either looks
            seen[name] = (mcap_memo.recall(tmp_path / f"{name}.mcap") is not None,
                          mcap_memo.recall(tmp_path / f"{other}.mcap") is not None)
            barrier.wait()

    with mcap_memo.remembering():
        _write(tmp_path / "main.mcap")
        threads = [threading.Thread(target=mission, args=pair) for pair in (("a", "bb"), ("bb", "a"))]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        with mcap_memo.remembering():  # a nested block shares the outer block's files
            assert mcap_memo.recall(tmp_path / "main.mcap") is not None
        assert mcap_memo.recall(tmp_path / "main.mcap") is not None  # the nested block's end forgets nothing
        assert mcap_memo.recall(tmp_path / "a.mcap") is None  # a thread's files stay in that thread
    assert seen == {"a": (True, False), "bb": (True, False)}
    assert mcap_memo.recall(tmp_path / "main.mcap") is None
