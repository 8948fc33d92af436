"""Shared fixtures and helpers for the oacli test suite."""

from __future__ import annotations

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
