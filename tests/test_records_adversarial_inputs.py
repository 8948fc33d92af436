"""What the item-by-item review of the adversarial cases still found.

* a coordinate beyond the workspace bound named the bound as a literal ``{bound:g}`` (a message template with a
  format spec pydantic does not apply);
* ``oacli excite --method rattle`` recorded ``excitation.method: offline`` in the run's ``config.yaml``, so a rerun
  from the folder ran the other method;
* a full disk while the RATTLE loop journals its steps: one line, a ``failed`` summary, no hang, nothing left over.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from oacli.cli import app
from oacli.config import load_config
from oacli.config.fields import MAX_COORDINATE_M
from tests.conftest import REPO
from tests.test_cli_excite import small_iss

ISS = REPO / "configs" / "iss_reswarm.yaml"
runner = CliRunner()


def test_a_coordinate_beyond_the_workspace_names_the_bound(tmp_path):
    result = runner.invoke(app, ["track", str(ISS), "--set", "waypoints.A.position=[1e30, 0, 0]", "--out",
                                 str(tmp_path / "run"), "--quiet"])
    assert result.exit_code == 2, result.output
    line = result.output.strip()
    assert line.endswith(f"waypoints.A.position: [1e+30, 0, 0]: coordinate 1e+30 m is beyond the workspace bound "
                         f"of ±{MAX_COORDINATE_M:g} m"), line
    assert "{" not in line and not (tmp_path / "run").exists()


def test_excite_method_option_is_recorded_and_reruns_from_the_folder(tmp_path):
    cfg = small_iss(tmp_path / "short.yaml", rattle={"duration_s": 6.0, "replan_period_s": 6.0,
                                                     "limits": {"force_N": [0.15] * 3, "torque_Nm": [0.015] * 3}})
    assert load_config(cfg).excitation.method == "offline"
    first, again = tmp_path / "first", tmp_path / "again"
    result = runner.invoke(app, ["excite", str(cfg), "--method", "rattle", "--out", str(first), "--quiet"])
    assert result.exit_code == 0, result.output
    assert load_config(first / "config.yaml").excitation.method == "rattle"
    result = runner.invoke(app, ["excite", str(first / "config.yaml"), "--out", str(again), "--quiet"])
    assert result.exit_code == 0, result.output
    a, b = (json.loads((d / "summary.json").read_text()) for d in (first, again))
    assert b["method"] == "rattle" and b["replans"] == a["replans"] == 1
    assert b["estimate"] == a["estimate"] and b["criterion_final"] == a["criterion_final"]  # the same run again
    assert (first / "config.yaml").read_text() == (again / "config.yaml").read_text()


@pytest.fixture
def small_tmpfs(tmp_path):
    """A folder on a fresh tmpfs of the given size (skips where mounting is not allowed)."""
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


def test_full_disk_while_the_rattle_loop_journals_fails_fast_with_one_line(tmp_path, small_tmpfs):
    cfg = small_iss(tmp_path / "long.yaml", method="rattle",
                    rattle={"duration_s": 600.0, "replan_period_s": 12.0,
                            "limits": {"force_N": [0.15] * 3, "torque_Nm": [0.015] * 3}})
    out = small_tmpfs(60_000) / "run"  # the journal fills it within seconds of the loop
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    start = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "oacli", "excite", str(cfg), "--out", str(out), "--quiet"],
                          env=env, capture_output=True, text=True, timeout=240)  # no hang
    assert time.monotonic() - start < 120  # far from the 600 s loop: it stopped at the full disk
    assert done.returncode == 1, done.stderr
    assert done.stderr.strip().splitlines() == [f"error: cannot write {out / 'excite.mcap'}: no space left on "
                                                "device (ENOSPC)"], done.stderr
    assert sorted(p.name for p in out.iterdir()) == ["config.yaml", "summary.json"]  # no .partial left
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and "ENOSPC" in summary["error"]
