"""Benchmark: the default mission's two estimators (``segment-2/estimate``, batch on growing windows, and
``segment-2/estimate-sequential``), this tree against a base tree, with an equality check (issue 9).

The data: a default mission's ``segment-2/track/track.mcap`` (60 s, 325 control records), its records read and
aligned exactly as the ``estimate`` stage does (:func:`oacli.stages.estimate._with_imu` included), estimated with
``segment-2/estimate/config.yaml`` (batch: :func:`oacli.estimation.batch.estimate_batch_windows` on the stage's
growing windows) and ``segment-2/estimate-sequential/config.yaml`` (:class:`oacli.estimation.sequential.
SequentialEstimator` over every record, then ``flush``, as the stage runs it). Without ``--mission`` the default
mission (``configs/mission_iss.yaml``) is flown once first (about a minute). The base tree (``--base``, default
``/tmp/base-estimate-stages``; exported with ``git archive BASE_COMMIT`` when absent) and this tree run alternately
per repeat, each in a fresh process (``PYTHONPATH`` set to its tree, BLAS on one thread, pinned to one core with
``taskset -c CPU`` when ``taskset`` exists), timed by the process's CPU time (``time.process_time``: less sensitive
to other load on a shared machine than wall time).

Printed per stage: min and median CPU time of both trees over the repeats and their ratio, and how far the answers
are apart -- batch: θ and cov(θ) of every window (largest relative difference of θ; of cov(θ) both the largest
relative difference of a variance and the largest ``|Δcov_ij| / sqrt(cov_ii cov_jj)``), the covariance of
``[x_K, φ]``, the inlier sets, iterations, gating rounds and convergence of every window; sequential: θ, cov(θ),
every record's status and d², and the hand-over record.

Run (e.g. ``taskset -c 1``): ``python benchmarks/bench_estimate_stages.py [--repeats 5] [--mission RUN_DIR]
[--base PATH] [--base-commit d98dee9] [--cpu 1]``
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # run as a script: the benchmarks package from this checkout
from benchmarks.bench_sequential_estimation import ensure_base, ensure_mission  # noqa: E402

BASE_COMMIT = "d98dee9"

_WORKER = r"""
import sys, time
from pathlib import Path
import numpy as np
from oacli.config import load_config
from oacli.estimation.alignment import align_records
from oacli.estimation.batch import estimate_batch_windows
from oacli.estimation.sequential import SequentialEstimator
from oacli.io.telemetry_streams import read_telemetry_streams
from oacli.stages.estimate import _with_imu
from oacli.stages.settings import estimation_prior, estimator_settings

mission, out_npz = Path(sys.argv[1]), sys.argv[2]
track = mission / "segment-2" / "track" / "track.mcap"
out = {}
for method, folder in (("batch", "estimate"), ("sequential", "estimate-sequential")):
    cfg = load_config(mission / "segment-2" / folder / "config.yaml")
    streams = read_telemetry_streams(track)
    use_loc = streams.t_localisation is not None and streams.t_localisation.size > 0
    t_meas, x_meas = ((streams.t_localisation, streams.x_localisation) if use_loc
                      else (streams.t_measured, streams.x_measured))
    records, al = align_records(
        t_meas, x_meas, streams.t_applied, streams.u_applied, reorder_window=cfg.estimation.reorder_window,
        t_command=streams.t_command, u_command=streams.u_command,
        input_limits=np.r_[cfg.robot.force_limit_N, cfg.robot.torque_limit_Nm])
    records, _ = _with_imu(cfg, records, streams, al.control_period_s, track)
    settings, prior = estimator_settings(cfg), estimation_prior(cfg)
    if method == "batch":
        t = np.array([r.t for r in records])
        window_s = cfg.estimation.window_s
        ends = [*np.arange(t[0] + window_s, t[-1] - 0.5 * window_s, window_s), t[-1]]
        c0 = time.process_time()
        res = estimate_batch_windows(records, settings, prior, ends)
        out["b_cpu"] = time.process_time() - c0
        out["b_theta"] = np.array([r.estimate.theta for r in res])
        out["b_cov"] = np.array([r.estimate.covariance for r in res])
        out["b_last_cov"] = np.array([r.last_covariance for r in res])
        out["b_inliers"] = np.concatenate([r.inliers for r in res])
        out["b_converged"] = np.array([r.converged for r in res])
        out["b_iterations"] = np.array([r.iterations for r in res])
        out["b_rounds"] = np.array([r.gating_rounds for r in res])
        out["b_records"] = len(records)
    else:
        c0 = time.process_time()
        est = SequentialEstimator(settings, prior, intermediate_estimates=False)
        for rec in records:
            est.update(rec)
        final = est.flush()
        out["s_cpu"] = time.process_time() - c0
        out["s_theta"] = final.theta
        out["s_cov"] = final.covariance
        out["s_status"] = np.array([s.status for s in est.history])
        out["s_d2"] = np.array([s.d2 for s in est.history])
        out["s_boot"] = est.bootstrap_records
np.savez(out_npz, **out)
"""


def run_side(tree: Path, mission: Path, out_npz: Path, cpu: int | None) -> dict:
    """One run of both estimators in a fresh process with ``tree`` first on the path."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS"):
        env[var] = "1"
    cmd = [sys.executable, "-c", _WORKER, str(mission), str(out_npz)]
    if cpu is not None and shutil.which("taskset"):
        cmd = ["taskset", "-c", str(cpu), *cmd]
    subprocess.run(cmd, check=True, env=env, cwd=str(tree))
    with np.load(out_npz) as data:
        return {k: data[k] for k in data.files}


def rel(a: np.ndarray, b: np.ndarray) -> float:
    """Largest entry-wise relative difference."""
    return float(np.max(np.abs(a - b) / np.abs(b)))


def cov_rel(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Largest relative difference of a variance, and largest ``|Δcov_ij| / sqrt(cov_ii cov_jj)``."""
    var_a, var_b = np.einsum("...ii->...i", a), np.einsum("...ii->...i", b)
    scale = np.sqrt(var_b[..., :, None] * var_b[..., None, :])
    return rel(var_a, var_b), float(np.max(np.abs(a - b) / scale))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="alternating repeats of each tree")
    parser.add_argument("--mission", type=Path, help="a finished default mission folder (flown when absent)")
    parser.add_argument("--base", type=Path, default=Path("/tmp/base-estimate-stages"), help="base tree")
    parser.add_argument("--base-commit", default=BASE_COMMIT, help="commit exported to --base when it is absent")
    parser.add_argument("--cpu", type=int, default=1, help="core to pin each run to (taskset); -1: no pinning")
    args = parser.parse_args()
    ensure_base(args.base, args.base_commit)
    cpu = None if args.cpu < 0 else args.cpu
    with tempfile.TemporaryDirectory() as tmp:
        scratch = Path(tmp)
        mission = ensure_mission(args.mission, scratch)
        runs: dict[str, list[dict]] = {"base": [], "new": []}
        for i in range(args.repeats):
            for side, tree in (("base", args.base), ("new", REPO)):
                res = run_side(tree, mission, scratch / f"{side}.npz", cpu)
                runs[side].append(res)
                print(f"repeat {i + 1} {side:4s}: batch windows {float(res['b_cpu']):.3f} s CPU, sequential "
                      f"{float(res['s_cpu']):.3f} s CPU", flush=True)
    base, new = runs["base"][0], runs["new"][0]
    print(f"\n{int(new['b_records'])} records; CPU time [s] over {args.repeats} alternating repeats:")
    for key, label in (("b_cpu", "segment-2/estimate (batch windows)"),
                       ("s_cpu", "segment-2/estimate-sequential")):
        b = np.array([float(r[key]) for r in runs["base"]])
        n = np.array([float(r[key]) for r in runs["new"]])
        print(f"  {label:36s} base min {b.min():.3f} / median {np.median(b):.3f}, new min {n.min():.3f} / "
              f"median {np.median(n):.3f}, ratio (median) {np.median(b) / np.median(n):.2f}x")
    var_d, corr_d = cov_rel(new["b_cov"], base["b_cov"])
    last_d = float(np.max(np.abs(new["b_last_cov"] - base["b_last_cov"])) / np.max(np.abs(base["b_last_cov"])))
    print("\nbatch, every window, new against base:")
    print(f"  θ {rel(new['b_theta'], base['b_theta']):.1e}; cov(θ) variances {var_d:.1e}, "
          f"|Δcov_ij|/sqrt(cov_ii cov_jj) {corr_d:.1e}; cov([x_K, φ]) {last_d:.1e} (relative to its largest entry)")
    print(f"  inlier sets equal {bool(np.array_equal(new['b_inliers'], base['b_inliers']))}; iterations "
          f"{new['b_iterations'].tolist()} (base {base['b_iterations'].tolist()}); rounds {new['b_rounds'].tolist()} "
          f"(base {base['b_rounds'].tolist()}); converged {new['b_converged'].tolist()} "
          f"(base {base['b_converged'].tolist()})")
    var_s, corr_s = cov_rel(new["s_cov"], base["s_cov"])
    finite = np.isfinite(base["s_d2"])
    print("sequential, new against base:")
    print(f"  θ {rel(new['s_theta'], base['s_theta']):.1e}; cov(θ) variances {var_s:.1e}, "
          f"|Δcov_ij|/sqrt(cov_ii cov_jj) {corr_s:.1e}; d² {rel(new['s_d2'][finite], base['s_d2'][finite]):.1e}")
    print(f"  statuses equal {bool(np.array_equal(new['s_status'], base['s_status']))}; hand-over after "
          f"{int(new['s_boot'])} records (base {int(base['s_boot'])})")


if __name__ == "__main__":
    main()
