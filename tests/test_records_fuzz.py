"""A seeded fuzz of configs and ``--set`` values (slow suite): at least 300 cases -- huge, tiny, negative,
non-finite and ill-typed values of every numeric field a stage reads, config files and inputs that are FIFOs,
devices, folders, binary data -- run through the CLI (Typer's runner, in this process): never exit 1, never a
traceback (an exception escaping the command), never longer than 60 s (a SIGALRM turns a hang into a failure).
"""

from __future__ import annotations

import os
import random
import signal
import time
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from oacli.cli import app
from tests.conftest import REPO, memory_cap

ISS = REPO / "configs" / "iss_reswarm.yaml"
HANG_S = 60

FIELDS = [
    "robot.mass_kg", "robot.inertia_kgm2", "robot.force_limit_N", "robot.radius_m", "robot.velocity_limit_mps",
    "simulation.plant_rate_hz", "simulation.settle_time_s", "simulation.initial_offset_m",
    "controller.rate_hz", "controller.horizon", "controller.max_consecutive_failures", "controller.weights.position",
    "controller.weights.torque", "reference.cruise_speed_mps", "reference.acceleration_mps2",
    "reference.angular_rate_radps", "reference.angular_acceleration_radps2", "reference.hold_s",
    "reference.sample_period_s", "sensors.position_std_m", "sensors.attitude_std_rad", "seed",
    "excitation.duration_s", "excitation.steps", "excitation.rattle.duration_s", "excitation.rattle.horizon",
    "environment.safety_factor", "faults.controller_stall.start_s", "faults.controller_stall.duration_s",
    "truth.com_offset_m", "truth.actuator_scale",
]
VALUES = ["0", "-1", "1e-300", "1e300", "-1e300", "1e-12", "1e12", ".nan", ".inf", "-.inf", "''", "abc", "[]",
          "{}", "true", "null", "9223372036854775808", "1", "0.5", "[1e308, 1e308, 1e308]", "[0, 0, 0]"]


class Hang(BaseException):
    """The command ran longer than :data:`HANG_S`."""


def _fast_config(folder: Path) -> Path:
    data = yaml.safe_load(ISS.read_text())
    data["simulation"]["settle_time_s"] = 0.5
    data["outputs"] = {**(data.get("outputs") or {}), "plots": "none"}
    path = folder / "fast.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _special_files(folder: Path) -> dict[str, Path]:
    fifo = folder / "fifo.yaml"
    os.mkfifo(fifo)
    binary = folder / "binary.yaml"
    binary.write_bytes(bytes(random.Random(1).randrange(256) for _ in range(4096)))
    deep = folder / "deep.yaml"
    deep.write_text("a: " + "[" * 5000 + "]" * 5000 + "\n")
    zero_link = folder / "zero.mcap"
    zero_link.symlink_to("/dev/zero")
    run = folder / "fifo-run"
    run.mkdir()
    os.mkfifo(run / "summary.json")
    return {"fifo": fifo, "binary": binary, "deep": deep, "zero": zero_link, "dir": folder, "fifo_run": run,
            "devzero": Path("/dev/zero"), "urandom": Path("/dev/urandom"), "null": Path("/dev/null")}


def _cases(folder: Path) -> list[list[str]]:
    rng = random.Random(32)
    cfg = str(_fast_config(folder))
    files = _special_files(folder)
    cases: list[list[str]] = []
    for field in FIELDS:  # every field with 8 of the values: 248 cases
        for value in rng.sample(VALUES, 8):
            cases.append(["track", cfg, "--set", f"{field}={value}"])
    for _ in range(30):  # pairs of extreme values
        a, b = rng.sample(FIELDS, 2)
        cases.append(["track", cfg, "--set", f"{a}={rng.choice(VALUES)}", "--set", f"{b}={rng.choice(VALUES)}"])
    for name in ("fifo", "binary", "deep", "devzero", "urandom", "null", "dir"):
        target = str(files[name])
        cases += [["track", target], ["config", "show", target], ["campaign", target, "--dry-run"],
                  ["mission", target]]
    for name in ("fifo", "zero", "devzero", "dir", "binary", "null"):
        target = str(files[name])
        cases += [["track", cfg, "--set", "reference.source=file", "--set", f"reference.file={target}"],
                  ["track", cfg, "--reference", target], ["smooth", cfg, "--input", target],
                  ["estimate", cfg, "--telemetry", target], ["info", target], ["logs", "verify", target],
                  ["logs", "recover", target, str(folder / "recovered.mcap")]]
    cases += [["info", str(files["fifo_run"])], ["plots", str(files["fifo_run"])],
              ["mission", str(files["fifo_run"]), "--resume"], ["campaign", str(files["fifo_run"]), "--resume"]]
    return cases


@pytest.mark.slow
def test_fuzzed_configs_and_inputs_never_exit_1_hang_or_trace(tmp_path):
    runner = CliRunner()
    cases = _cases(tmp_path)
    assert len(cases) >= 300

    def hang(signum, frame):
        raise Hang

    previous = signal.signal(signal.SIGALRM, hang)
    failures: list[str] = []
    codes: dict[int, int] = {}
    try:
        for i, args in enumerate(cases):
            needs_out = args[0] in ("track", "smooth", "estimate", "campaign") and "--resume" not in args
            full = [*args, "--out", str(tmp_path / f"out-{i}")] if needs_out else args
            if args[0] in ("track", "smooth", "estimate", "mission", "campaign"):
                full = [*full, "-q"]
            start = time.monotonic()
            signal.alarm(HANG_S)
            try:
                with memory_cap(3 << 30):  # a regression reading /dev/zero whole fails here, not the machine
                    result = runner.invoke(app, full)
            except Hang:
                failures.append(f"hang over {HANG_S} s: {args}")
                continue
            finally:
                signal.alarm(0)
            codes[result.exit_code] = codes.get(result.exit_code, 0) + 1
            escaped = result.exception is not None and not isinstance(result.exception, SystemExit)
            if result.exit_code == 1 or escaped or "internal error" in result.output or "Traceback" in result.output:
                failures.append(f"exit {result.exit_code} ({time.monotonic() - start:.1f} s) {args}: "
                                f"{result.output.strip()[-300:]!r} {result.exception!r}")
    finally:
        signal.signal(signal.SIGALRM, previous)
    assert not failures, f"{len(failures)} of {len(cases)} cases:\n" + "\n".join(failures)
    assert codes.get(2, 0) > len(cases) // 2, codes  # most of them are bad input, refused with exit 2
