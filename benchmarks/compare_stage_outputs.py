"""Fingerprint every stage's outputs on the presets, to show that a refactoring changed no behaviour.

Runs the stage chain of each preset through the CLI (plan → smooth → track on the smoothed plan; excite → track →
estimate) into a temporary folder and records, per stage: the summary (wall-clock figures removed) and, per MCAP
topic, the number of messages and a SHA-256 of their payloads (JSON records with their wall-clock fields removed;
Foxglove messages byte for byte). Two fingerprints taken before and after a change must be equal::

    python benchmarks/compare_stage_outputs.py --save before.json      # on the old commit
    python benchmarks/compare_stage_outputs.py --against before.json   # on the new one: exit 1 on any difference

Wall-clock figures (solve and step times, wall time) are the only values left out: they differ run to run.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import yaml
from mcap.reader import make_reader

REPO = Path(__file__).resolve().parents[1]
#: Keys whose values are wall-clock measurements (differ from run to run).
WALL_CLOCK = re.compile(
    r"(solve_time|step_time|wall_time|elapsed|_wall|time_ms|replan_time|planning_time|time_to_first_solution)")
#: Temporary folder of the current run, replaced by a placeholder in recorded paths.
_TMP_ROOT = ["<none>"]


def _strip(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _strip(v) for k, v in sorted(value.items()) if not WALL_CLOCK.search(k) and k != "run_dir"}
    if isinstance(value, list):
        return [_strip(v) for v in value]
    if isinstance(value, str):
        return value.replace(_TMP_ROOT[0], "<tmp>")
    return value


def _mcap_fingerprint(path: Path) -> dict[str, Any]:
    topics: dict[str, dict[str, Any]] = {}
    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            entry = topics.setdefault(channel.topic, {"messages": 0, "hash": hashlib.sha256()})
            entry["messages"] += 1
            data = message.data
            if channel.message_encoding == "json":
                data = json.dumps(_strip(json.loads(data)), sort_keys=True).encode()
            elif channel.topic == "/log":
                data = b""  # log lines carry wall-clock figures in their text; their number is still compared
            entry["hash"].update(data)
            del schema
    return {t: {"messages": e["messages"], "sha256": e["hash"].hexdigest()} for t, e in sorted(topics.items())}


def _run(args: list[str]) -> None:
    proc = subprocess.run([sys.executable, "-m", "oacli", *args, "--quiet"], cwd=REPO, capture_output=True, text=True)
    if proc.returncode not in (0, 4):
        raise SystemExit(f"oacli {' '.join(args)} failed ({proc.returncode}):\n{proc.stderr}")


def _stage(folder: Path, stage: str) -> dict[str, Any]:
    summary = json.loads((folder / "summary.json").read_text())
    return {"summary": _strip(summary), "mcap": _mcap_fingerprint(folder / f"{stage}.mcap")}


def _has_excitation(cfg: Path) -> bool:
    """True when the preset defines ``excitation.start`` (``oacli excite`` refuses it otherwise, exit 2)."""
    data = yaml.safe_load(cfg.read_text()) or {}
    return bool((data.get("excitation") or {}).get("start"))


def fingerprint(presets: list[str]) -> dict[str, Any]:
    """Run each preset's stage chain and return its fingerprint."""
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        _TMP_ROOT[0] = str(root)
        for preset in presets:
            cfg = REPO / "configs" / f"{preset}.yaml"
            d = root / preset
            steps = [
                ("plan", ["plan", str(cfg), "--out", str(d / "plan")]),
                ("smooth", ["smooth", str(cfg), "--input", str(d / "plan" / "plan.mcap"), "--out", str(d / "smooth")]),
                ("track", ["track", str(cfg), "--reference", str(d / "smooth" / "smooth.mcap"),
                           "--out", str(d / "track-smooth")]),
                ("excite", ["excite", str(cfg), "--out", str(d / "excite")]),
                ("track", ["track", str(cfg), "--reference", str(d / "excite" / "excite.mcap"),
                           "--out", str(d / "track-excite")]),
                ("estimate", ["estimate", str(cfg), "--telemetry", str(d / "track-excite" / "track.mcap"),
                              "--out", str(d / "estimate")]),
            ]
            if not _has_excitation(cfg):  # e.g. the tube preset: no excitation.start, no excite chain
                print(f"{preset}: no excitation.start: excite, track on it and estimate skipped", file=sys.stderr)
                steps = steps[:3]
            for stage, args in steps:
                print(f"{preset}: {' '.join(args[:1])} → {Path(args[args.index('--out') + 1]).name}", file=sys.stderr)
                _run(args)
                folder = Path(args[args.index("--out") + 1])
                out[f"{preset}/{folder.name}"] = _stage(folder, stage)
    return out


def _diff(a: Any, b: Any, path: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        lines = []
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                lines.append(f"{path}/{k}: only in {'after' if k not in a else 'before'}")
            else:
                lines.extend(_diff(a[k], b[k], f"{path}/{k}"))
        return lines
    return [] if a == b else [f"{path}: {a!r} → {b!r}"]


def main() -> None:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=["doerr2021", "iss_reswarm", "iss_reswarm_tube"])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--save", type=Path, help="write the fingerprint to this JSON file")
    group.add_argument("--against", type=Path, help="compare with a saved fingerprint; exit 1 on any difference")
    args = parser.parse_args()
    result = fingerprint(args.presets)
    if args.save:
        args.save.write_text(json.dumps(result, indent=1, sort_keys=True))
        print(f"saved {len(result)} stage fingerprints to {args.save}")
        return
    before = json.loads(args.against.read_text())
    diffs = _diff(before, json.loads(json.dumps(result)))
    for line in diffs:
        print(line)
    print(f"{len(result)} stage runs compared: {'identical' if not diffs else f'{len(diffs)} differences'}")
    raise SystemExit(1 if diffs else 0)


if __name__ == "__main__":
    main()
