"""Shared fixtures and helpers for the oacli test suite."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
MIT_ISS = SHARED_DATA / "rattle-iros-2022" / "MIT-ISS"
INFO_TRAJECTORIES = SHARED_DATA / "rattle-iros-2022" / "info-trajectories"


def require_shared(path: Path) -> Path:
    """Skip the calling test, with a reason, when the shared data set is absent (a user's clone)."""
    if not path.exists():
        pytest.skip(f"needs the RATTLE/ReSWARM data at {path} (present in CI, absent in a plain clone)")
    return path


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


def random_state(rng: np.random.Generator, spin_radps: float = 0.3) -> np.ndarray:
    """A random 13-state with a unit quaternion."""
    x = np.empty(13)
    x[0:3] = rng.uniform(-2, 2, 3)
    x[3:6] = rng.uniform(-0.2, 0.2, 3)
    q = rng.standard_normal(4)
    x[6:10] = q / np.linalg.norm(q)
    x[10:13] = rng.uniform(-spin_radps, spin_radps, 3)
    return x


ROOT = Path(__file__).resolve().parents[1]


def small_mission_config(folder: Path, name: str = "small-mission") -> Path:
    """configs/mission_iss.yaml with a shorter excitation, fewer shortcut tries and polish iterations."""
    import yaml

    data = yaml.safe_load((ROOT / "configs" / "mission_iss.yaml").read_text())
    data["name"] = name
    data["planner"]["shortcut"]["tries"] = 200
    data["planner"].setdefault("polish", {})["iterations"] = 5
    data["excitation"]["duration_s"] = 24.0
    data["excitation"]["steps"] = 48
    data["mission"]["settle_s"] = 2.0
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path



@pytest.fixture(scope="session")
def mission_run(tmp_path_factory):
    """One shrunk default mission through the CLI, shared by the mission tests: (run folder, config, output)."""
    from typer.testing import CliRunner

    from oacli.cli import app

    folder = tmp_path_factory.mktemp("mission")
    cfg = small_mission_config(folder)
    result = CliRunner().invoke(app, ["mission", str(cfg), "--out", str(folder / "run")])
    assert result.exit_code == 0, result.output
    return folder / "run", cfg, result.output


@contextlib.contextmanager
def memory_cap(extra_bytes: int):
    """Cap this process's data segment at its current size + ``extra_bytes`` for the block (soft RLIMIT_DATA,
    restored after): a command that regresses into reading ``/dev/zero`` whole fails with MemoryError instead of
    filling the machine's memory."""
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_DATA)
    used = 0
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmData:"):
                used = int(line.split()[1]) * 1024
    cap = used + extra_bytes if used else extra_bytes * 4
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    resource.setrlimit(resource.RLIMIT_DATA, (cap, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_DATA, (soft, hard))
