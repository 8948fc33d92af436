"""Campaign executor benchmark: throughput from 1 to 2 workers, and the executor's per-run overhead.

Targets (issue 15): throughput with 2 workers >= 1.8x that with 1 worker on a 2-core machine; per-run overhead of
the executor <= 5 % of a short run.

- Throughput: the same campaign of ``--runs`` short closed-loop runs (``tests/test_campaign.py``'s tiny campaign,
  longer hop) on ``local`` with 1 and with 2 workers, each pool warmed by one run first; runs per second of the
  driver loop (:func:`oacli.campaign.driver.run_campaign`). The two sides alternate per repeat.
- Overhead: the mean wall time of a run through ``local`` with 1 worker (driver loop ÷ runs) against the mean time
  the worker itself measured for the job (``wall_time_s`` of each manifest line, same runs, same moment): the
  difference is what the executor costs (pickling, the worker round trip, result.json, the manifest line). Also
  printed against the same runs' job in the driver process (:func:`oacli.campaign.jobs.run_job`, warm), which a
  loaded machine makes noisy.

Usage::

    python benchmarks/bench_campaign.py [--runs 8] [--repeats 2]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

from test_campaign import tiny_campaign  # noqa: E402

from oacli.campaign import manifest  # noqa: E402
from oacli.campaign.driver import load_campaign, prepare, read_spec, run_campaign  # noqa: E402
from oacli.campaign.executors import make_executor  # noqa: E402
from oacli.campaign.jobs import pin_threads, run_job  # noqa: E402


def _campaign(folder: Path, runs: int) -> Path:
    path = tiny_campaign(folder, runs=runs, name="bench")
    return path


def timed_campaign(path: Path, out: Path, workers: int) -> tuple[float, float]:
    """Wall time [s] of the driver loop over every run, on a warmed ``local`` pool of ``workers``, and the sum of
    the runs' own wall times as the workers measured them [s]."""
    handle = make_executor("local", workers)
    try:
        warm = handle.executor.submit(pin_threads)  # start the fork server and the workers
        warm.result()
        folder = prepare(load_campaign(path), out=out, runs_root=out.parent)
        start = time.perf_counter()
        run_campaign(folder, handle)
        wall = time.perf_counter() - start
    finally:
        handle.close()
    final = manifest.final_states(manifest.read(folder))
    bad = [k for k, r in final.items() if r["status"] not in manifest.COMPLETED]
    if bad:
        raise SystemExit(f"runs {bad} did not complete")
    return wall, sum(float(r["wall_time_s"]) for r in final.values())


def in_process_job_time(folder: Path, runs: int) -> float:
    """Mean wall time [s] of the runs' job in this process (warm: the first run is done twice)."""
    pin_threads()
    specs = [read_spec(folder, k) for k in range(runs)]
    with tempfile.TemporaryDirectory() as tmp:
        run_job(specs[0], Path(tmp))
        times = []
        for spec in specs:
            start = time.perf_counter()
            run_job(spec, Path(tmp))
            times.append(time.perf_counter() - start)
    return statistics.mean(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    results: dict[str, list[float]] = {"wall_1": [], "wall_2": [], "job_s": [], "worker_job_s": []}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        path = _campaign(root, args.runs)
        for rep in range(args.repeats):
            order = (1, 2) if rep % 2 == 0 else (2, 1)
            for workers in order:
                wall, in_workers = timed_campaign(path, root / f"w{workers}-{rep}", workers)
                results[f"wall_{workers}"].append(wall)
                if workers == 1:
                    results["worker_job_s"].append(in_workers / args.runs)
                print(f"repeat {rep}: {workers} worker(s): {args.runs} runs in {wall:.2f} s", flush=True)
            job = in_process_job_time(root / f"w1-{rep}", args.runs)
            results["job_s"].append(job)
            print(f"repeat {rep}: in-process job {job:.3f} s per run", flush=True)
    w1, w2 = statistics.median(results["wall_1"]), statistics.median(results["wall_2"])
    job = statistics.median(results["job_s"])
    worker_job = statistics.median(results["worker_job_s"])
    per_run = w1 / args.runs
    report = {
        "runs": args.runs, "repeats": args.repeats,
        "throughput_1_worker_runs_per_s": args.runs / w1, "throughput_2_workers_runs_per_s": args.runs / w2,
        "speedup_2_vs_1": w1 / w2, "speedup_target": 1.8,
        "per_run_wall_1_worker_s": per_run, "in_process_job_s": job,
        "worker_job_s": worker_job,
        "executor_overhead_pct": 100.0 * (per_run - worker_job) / worker_job,
        "overhead_vs_in_process_pct": 100.0 * (per_run - job) / job, "overhead_target_pct": 5.0,
    }
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
