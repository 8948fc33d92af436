"""Benchmark: the mission's five ``track`` stages (closed loop, controller, journal, summary), PNGs left out.

Runs ``run_track`` in-process on the stage configs of a finished mission (``oacli mission configs/mission_iss.yaml
--out DIR`` first; the config.yaml of each ``segment-*/track`` and ``segment-*/baseline-*`` names its reference
file), with the PNG writer replaced by a no-op (another benchmark covers the plots), and prints per stage: control
steps, simulated time, the wall time of the closed-loop simulation (controller steps, plant integration, journal)
and of the whole stage without PNGs (wall and process CPU time), plus the sum over the stages (issue 9 target: <= 3
s for the five). ``--save FILE`` writes every stage's true trajectory and commands to an ``.npz`` and ``--compare
FILE`` prints the largest relative difference against such a file (same seed -> same trajectory).
``--fingerprint FILE`` writes, per stage, the summary (wall-clock figures removed) and a SHA-256 per MCAP topic
(``benchmarks/compare_stage_outputs.py``'s fingerprint) of the first repeat; ``--check-fingerprint FILE`` compares
with such a file and exits 1 on any difference (run it with ``PYTHONPATH`` on another tree to fingerprint that
tree: this script imports ``oacli`` from the path).

``--against SRC`` measures two source trees in the same run, alternating per repeat: each repeat runs this
benchmark once in a subprocess with ``PYTHONPATH=SRC`` (e.g. a worktree of main) and once with this file's tree,
and prints both sides' median totals and their ratio (the machine's load then weighs on both alike).

Run: ``python benchmarks/bench_track.py MISSION_DIR [--repeats 3] [--save base.npz | --compare base.npz]
[--fingerprint fp.json | --check-fingerprint fp.json] [--against /path/to/other/tree]``
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import oacli.stages.track as track_stage  # noqa: E402
from oacli.config import load_config  # noqa: E402


def stage_configs(mission_dir: Path) -> list[Path]:
    """The stage configs of the track stages under ``mission_dir`` (sorted)."""
    found = [*mission_dir.glob("segment-*/track/config.yaml"), *mission_dir.glob("segment-*/baseline-*/config.yaml")]
    return sorted(found)


ROOT = Path(__file__).resolve().parents[1]


def _fingerprint(run_dir: Path) -> dict[str, object]:
    """A finished stage's summary without wall-clock figures and its MCAP topics' hashes
    (``benchmarks/compare_stage_outputs.py``)."""
    import compare_stage_outputs as cso

    cso._TMP_ROOT[0] = str(run_dir)
    return cso._stage(run_dir, "track")
COLUMNS = ("loop wall", "loop CPU", "stage wall", "stage CPU")


def _one_run(src: Path, mission_dir: Path) -> dict[str, list[float]]:
    """Per stage and ``"total"``: (loop wall, loop CPU, stage wall, stage CPU) [s] of one run of this benchmark on
    the tree ``src``."""
    env = {**os.environ, "PYTHONPATH": str(src)}
    out = subprocess.run([sys.executable, __file__, str(mission_dir), "--totals-json"], env=env, check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def against(other: Path, mission_dir: Path, repeats: int) -> None:
    """Alternate runs of the tree ``other`` and of this file's tree; print both sides' medians (per stage and in
    total) and their ratio."""
    sides: dict[str, list[dict[str, list[float]]]] = {"other": [], "this": []}
    for rep in range(repeats):
        for side, src in (("other", other), ("this", ROOT)):
            sides[side].append(_one_run(src, mission_dir))
            print(f"repeat {rep + 1} {side:<5} " + "  ".join(f"{c} {v:.3f}" for c, v in
                                                           zip(COLUMNS, sides[side][-1]["total"], strict=True)),
                  flush=True)
    names = list(sides["this"][0])
    med = {side: {name: np.median(np.array([run[name] for run in runs]), axis=0) for name in names}
           for side, runs in sides.items()}
    print(f"medians over {repeats} alternating repeats [s]: other = {other}, this = {ROOT}")
    for i, col in enumerate(COLUMNS):
        print(f"  {col:<11} other {med['other']['total'][i]:7.3f}   this {med['this']['total'][i]:7.3f}   "
              f"this/other {med['this']['total'][i] / med['other']['total'][i]:.3f}")
    print("per stage, stage CPU and stage wall [s] (other -> this, ratio):")
    for name in names:
        o, t = med["other"][name], med["this"][name]
        print(f"  {name:<30} CPU {o[3]:6.3f} -> {t[3]:6.3f} ({t[3] / o[3]:.3f})   wall {o[2]:6.3f} -> {t[2]:6.3f} "
              f"({t[2] / o[2]:.3f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mission_dir", type=Path)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--save", type=Path)
    parser.add_argument("--compare", type=Path)
    parser.add_argument("--against", type=Path, help="another source tree, measured alternately with this one")
    parser.add_argument("--fingerprint", type=Path, help="write the stages' output fingerprint (JSON)")
    parser.add_argument("--check-fingerprint", type=Path, help="compare with a saved fingerprint (exit 1 if different)")
    parser.add_argument("--totals-json", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.against is not None:
        against(args.against, args.mission_dir, args.repeats)
        return
    configs = stage_configs(args.mission_dir)
    if not configs:
        raise SystemExit(f"no segment-*/track*/config.yaml under {args.mission_dir}")
    sim_wall: list[float] = []
    sim_cpu: list[float] = []
    runs: dict[str, object] = {}
    real_simulate = track_stage.simulate

    def timed_simulate(*a, **k):
        start, cpu = time.perf_counter(), time.process_time()
        tel = real_simulate(*a, **k)
        sim_wall.append(time.perf_counter() - start)
        sim_cpu.append(time.process_time() - cpu)
        runs["tel"] = tel
        return tel

    track_stage.simulate = timed_simulate
    track_stage.write_track_plots = lambda *a, **k: None
    table: dict[str, list[tuple[float, float]]] = {}
    saved: dict[str, np.ndarray] = {}
    info: dict[str, tuple[int, float]] = {}
    outcome: dict[str, str] = {}
    fingerprints: dict[str, object] = {}
    for rep in range(args.repeats):
        for path in configs:
            name = str(path.parent.relative_to(args.mission_dir))
            cfg = load_config(path)
            with tempfile.TemporaryDirectory() as tmp:
                start, cpu = time.perf_counter(), time.process_time()
                result = track_stage.run_track(cfg, out=Path(tmp) / "run")
                wall, cpu = time.perf_counter() - start, time.process_time() - cpu
                if rep == 0 and (args.fingerprint or args.check_fingerprint):
                    fingerprints[name] = _fingerprint(Path(tmp) / "run")
            tel = runs["tel"]
            table.setdefault(name, []).append((sim_wall[-1], wall, sim_cpu[-1], cpu))
            info[name] = (len(tel.t_ctrl), float(tel.t_true[-1]))
            summ = result.summary
            rms_mm = 1e3 * summ["rms_position_error_m"]
            outcome[name] = (f"{summ['status']}, {summ['constraint_violations']} violations, "
                             f"{summ.get('tube_violations', '-')} tube, rms {rms_mm:.4f} mm")
            if rep == 0:
                saved[f"{name}/x_true"] = tel.x_true
                saved[f"{name}/u_command"] = tel.u_command
    if args.fingerprint:
        args.fingerprint.write_text(json.dumps(fingerprints, indent=1, sort_keys=True))
    if args.check_fingerprint:
        import compare_stage_outputs as cso

        diffs = cso._diff(json.loads(args.check_fingerprint.read_text()), json.loads(json.dumps(fingerprints)))
        for line in diffs:
            print(line)
        print(f"{len(fingerprints)} stages against {args.check_fingerprint}: "
              f"{'identical' if not diffs else f'{len(diffs)} differences'}")
        if diffs:
            raise SystemExit(1)
    if args.totals_json:  # loop wall, loop CPU, stage wall, stage CPU per stage (medians) and their sum
        per_stage = {name: np.median(np.array(rows), axis=0)[[0, 2, 1, 3]] for name, rows in table.items()}
        per_stage["total"] = np.sum(list(per_stage.values()), axis=0)
        print(json.dumps({name: [float(v) for v in values] for name, values in per_stage.items()}))
        return
    print("wall and process CPU time [s] (CPU time is less sensitive to other load on the machine)")
    print(f"{'stage':<28} {'steps':>6} {'sim [s]':>8} {'loop wall':>10} {'loop CPU':>9} {'stage wall':>11} "
          f"{'stage CPU':>10}")
    totals = np.zeros(4)
    for name, rows in table.items():
        med = np.median(np.array(rows), axis=0)  # loop wall, stage wall, loop CPU, stage CPU
        totals += med
        print(f"{name:<28} {info[name][0]:>6} {info[name][1]:>8.1f} {med[0]:>10.3f} {med[2]:>9.3f} {med[1]:>11.3f} "
              f"{med[3]:>10.3f}")
    print(f"{'total':<28} {sum(i[0] for i in info.values()):>6} {sum(i[1] for i in info.values()):>8.1f} "
          f"{totals[0]:>10.3f} {totals[2]:>9.3f} {totals[1]:>11.3f} {totals[3]:>10.3f}   (medians over "
          f"{args.repeats} repeats; loop = closed-loop simulation, stage = run_track without PNGs)")
    for name, text in outcome.items():
        print(f"{name:<28} {text}")
    if args.save:
        np.savez(args.save, **saved)
    if args.compare:
        base = np.load(args.compare)
        for key in base.files:
            a, b = base[key], saved[key]
            if a.shape != b.shape:
                print(f"{key}: shape {a.shape} -> {b.shape}")
                continue
            rel = np.max(np.abs(a - b)) / max(np.max(np.abs(a)), 1e-300)
            print(f"{key:<40} max |diff| / max |value| = {rel:.2e}")


if __name__ == "__main__":
    main()
