"""Benchmark: the default mission (``configs/mission_iss.yaml``) end to end, logging included, against real time.

Runs ``oacli mission`` in-process ``--repeats`` times into temporary folders with BLAS pinned to one thread (one
core), and prints the wall time, the robot time flown (the three segments on the mission timeline, and all
simulated tracking including the baselines), the speed-up over real time (target of issue 9: >= 10x), and where
the time goes: per stage (median over repeats) and, with ``--profile``, the top functions by cumulative time.

The mission runs as ``oacli mission`` runs it: on a machine with two or more cores the stages the flight does not
wait for run beside it in a second process (:mod:`oacli.mission.background`); ``--in-line`` runs every stage in
line. The CPU time counts both processes.

``--vs TREE`` times the same mission in another checkout of oacli (e.g. ``git archive 76ea728 | tar -x -C /tmp/old``)
in the same run: each repeat runs both sides in fresh processes, alternating which goes first, and prints the ratio
of the medians (wall and CPU). Each side runs the way its own ``oacli mission`` does.

Run: ``python benchmarks/bench_mission.py [--repeats 1] [--profile] [--config configs/mission_iss.yaml]
[--vs TREE] [--in-line]``
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import cProfile  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import pstats  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from oacli.config import load_config  # noqa: E402
from oacli.config.outputs import PlotSet  # noqa: E402
from oacli.mission.run import run_mission, start_mission, validate_mission  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def steal_s() -> float | None:
    """Time the hypervisor ran other guests instead of this VM's CPUs [s], summed over CPUs (Linux ``/proc/stat``
    ``steal`` column; None elsewhere). A rise during a run explains a wall time its CPU time does not."""
    try:
        with open("/proc/stat", encoding="ascii") as fh:
            fields = fh.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _background_default() -> bool:
    try:
        from oacli.mission.background import background_workers_default
    except ImportError:  # an older checkout (--vs): its missions ran every stage in line
        return False
    return background_workers_default() > 0


def one_mission(config: Path, profile: bool, plots: bool = True, in_line: bool = False
                ) -> tuple[float, dict, str, float]:
    cfg = load_config(config)
    if not plots:
        cfg = cfg.model_copy(update={"outputs": cfg.outputs.model_copy(update={"plots": PlotSet.NONE})})
    validate_mission(cfg)
    with tempfile.TemporaryDirectory() as tmp:
        background = _background_default() and not in_line
        start, cpu_start, children_start = time.perf_counter(), time.process_time(), _children_cpu_s()
        profiler = cProfile.Profile() if profile else None
        if profiler:
            profiler.enable()
        mission_dir = start_mission(cfg, out=Path(tmp) / "run", runs_root=Path(tmp))
        result = (run_mission(cfg, mission_dir, background=True) if background else run_mission(cfg, mission_dir))
        if profiler:
            profiler.disable()
        wall = time.perf_counter() - start
        cpu = time.process_time() - cpu_start + _children_cpu_s() - children_start
        text = ""
        if profiler:
            buf = io.StringIO()
            pstats.Stats(profiler, stream=buf).sort_stats("cumulative").print_stats(25)
            text = buf.getvalue()
        return wall, result.summary, text, cpu


def _side(tree: Path, config: Path, in_line: bool) -> dict:
    """One mission in a fresh process with ``tree`` first on the path: its wall and CPU time [s] and status."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child-json", "--config", str(config)]
    if in_line:
        cmd.append("--in-line")
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run(cmd, env=env, cwd=tree, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def compare(other: Path, config_name: str, repeats: int, in_line: bool) -> None:
    """This checkout against ``other``, alternating which runs first (module docstring)."""
    import statistics as st

    sides: dict[str, list[dict]] = {"this": [], "other": []}
    for k in range(repeats):
        order = [("this", ROOT), ("other", other)] if k % 2 == 0 else [("other", other), ("this", ROOT)]
        for name, tree in order:
            sides[name].append(_side(tree, tree / "configs" / config_name, in_line and name == "this"))
            last = sides[name][-1]
            last = sides[name][-1]
            print(f"repeat {k + 1} {name:<5}: wall {last['wall_s']:6.1f} s, CPU {last['cpu_s']:6.1f} s, "
                  f"status {last['status']}", flush=True)
    for what in ("wall_s", "cpu_s"):
        a = st.median(r[what] for r in sides["this"])
        b = st.median(r[what] for r in sides["other"])
        print(f"median {what[:-2]:<4}: this {a:6.1f} s, other ({other}) {b:6.1f} s -> ratio {a / b:5.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=ROOT / "configs" / "mission_iss.yaml")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--profile", action="store_true", help="cProfile the last repeat")
    parser.add_argument("--no-plots", action="store_true",
                        help="also time the mission with outputs.plots false (no PNGs), alternating with the default")
    parser.add_argument("--in-line", action="store_true", help="every stage in line (oacli mission --in-line)")
    parser.add_argument("--vs", type=Path, default=None, metavar="TREE",
                        help="also time the mission in this checkout, alternating, and print the ratios")
    parser.add_argument("--child-json", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child_json:
        wall, summary, _, cpu = one_mission(args.config, False, in_line=args.in_line)
        print(json.dumps({"wall_s": wall, "cpu_s": cpu, "status": summary["status"]}))
        return
    if args.vs is not None:
        compare(args.vs.resolve(), args.config.name, args.repeats, args.in_line)
        return
    walls, cpus, per_stage, walls_no_plots = [], [], {}, []
    steal_before = steal_s()
    summary, profile_text = {}, ""
    for k in range(args.repeats):
        if args.no_plots and k % 2 == 1:      # alternate which variant runs first
            walls_no_plots.append(one_mission(args.config, False, plots=False)[0])
        wall, summary, text, cpu = one_mission(args.config, args.profile and k == args.repeats - 1,
                                               in_line=args.in_line)
        if args.no_plots and k % 2 == 0:
            walls_no_plots.append(one_mission(args.config, False, plots=False)[0])
        walls.append(wall)
        cpus.append(cpu)
        profile_text = text or profile_text
        for key, entry in summary["stages"].items():
            per_stage.setdefault(key, []).append(entry["wall_time_s"])
    mission_s = summary["mission_time_s"]
    flown = mission_s + sum(row["duration_s"] for key, row in summary["comparison"].items() if "baseline" in key)
    wall = statistics.median(walls)
    steal_after = steal_s()
    print(f"config {args.config.name}: status {summary['status']}, {args.repeats} repeat(s), BLAS threads 1")
    print(f"wall time (median)            {wall:8.1f} s")
    print(f"mission time (3 segments)     {mission_s:8.1f} s   -> {mission_s / wall:5.2f}x real time (target >= 10x)")
    cpu = statistics.median(cpus)
    print(f"CPU time (with the background){cpu:8.1f} s   -> {mission_s / cpu:5.2f}x (both processes)")
    if steal_before is not None and steal_after is not None:
        print(f"hypervisor steal, all CPUs    {steal_after - steal_before:8.1f} s   over the whole benchmark "
              "(/proc/stat: time this VM's CPUs waited for the host)")
    print(f"all simulated tracking        {flown:8.1f} s   -> {flown / wall:5.2f}x real time (with the baselines)")
    if walls_no_plots:
        bare = statistics.median(walls_no_plots)
        print(f"without PNGs (outputs.plots false) {bare:5.1f} s   -> {mission_s / bare:5.2f}x real time; the PNGs "
              f"cost {wall - bare:.1f} s ({100 * (wall - bare) / wall:.0f} %)")
    print("where the time goes (median wall per stage):")
    total = sum(statistics.median(v) for v in per_stage.values())
    for key, values in sorted(per_stage.items(), key=lambda kv: -statistics.median(kv[1])):
        med = statistics.median(values)
        print(f"  {key:<32} {med:7.2f} s  {100 * med / wall:5.1f} %")
    print(f"  {'mission outputs and overhead':<32} {wall - total:7.2f} s  {100 * (wall - total) / wall:5.1f} %")
    if profile_text:
        print(profile_text)


if __name__ == "__main__":
    main()
