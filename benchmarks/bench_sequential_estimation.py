"""Benchmark: the sequential estimator (``estimate --method sequential``) on the default mission's segment 2,
this tree against a base tree (issue 9: the mission's second slowest stage).

The data: a default mission's ``segment-2/track/track.mcap`` (60 s, 325 control records, flight-like noise), its
records read and aligned exactly as the ``estimate`` stage does, estimated with ``segment-2/estimate-sequential/
config.yaml``. Without ``--mission`` the default mission (``configs/mission_iss.yaml``) is flown once first (about a
minute). The base tree (``--base``, default ``/tmp/base-seqest``; created with ``git archive 1e98b38`` when absent)
and this tree run alternately per repeat, each in a fresh process (``PYTHONPATH`` set to its tree, BLAS on one
thread) that times

* ``estimator``: :func:`oacli.stages.estimate.run_estimation` (the filter, its bootstrap and the Cramér-Rao bound),
  the first call in the process, as the stage makes it;
* ``stage``: the whole stage (a second run in the same process), :func:`oacli.stages.estimate.run_estimate`
  into a temporary folder (reading the telemetry, the estimation, ``estimate.mcap``, ``estimate.rrd``,
  ``summary.json``), as the mission runs it.

Each also as the process's CPU time (less sensitive to other load on the core). Printed: min and median of each
over the repeats for both trees, the ratio, and how far the two final estimates are apart (θ: largest relative
difference; covariance: largest entry difference relative to the largest entry, and the largest relative difference
of a standard deviation). With ``--batch`` also the batch estimate on the same records
(the cross-check of a start-up change: which covariance is closer to the batch's).

Run (pinned, e.g. ``taskset -c 1``): ``python benchmarks/bench_sequential_estimation.py [--repeats 5]
[--mission RUN_DIR] [--base PATH] [--batch]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
BASE_COMMIT = "1e98b38"

_WORKER = r"""
import os, sys, time, tempfile, json
from pathlib import Path
import numpy as np
mission, out_npz, batch = Path(sys.argv[1]), sys.argv[2], sys.argv[3] == "1"
from oacli.config import load_config
from oacli.estimation.alignment import align_records
from oacli.io.telemetry_streams import read_telemetry_streams
from oacli.stages.settings import estimation_prior, estimator_settings
from oacli.stages.estimate import _with_imu, run_estimate, run_estimation
cfg_path = mission / "segment-2" / "estimate-sequential" / "config.yaml"
track = mission / "segment-2" / "track" / "track.mcap"
cfg = load_config(cfg_path)
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
t0, c0 = time.perf_counter(), time.process_time()
run = run_estimation(records, settings, prior, "sequential")
t_est, c_est = time.perf_counter() - t0, time.process_time() - c0
with tempfile.TemporaryDirectory() as tmp:
    t0, c0 = time.perf_counter(), time.process_time()
    run_estimate(cfg, telemetry=track, method="sequential", out=Path(tmp) / "est")
    t_stage, c_stage = time.perf_counter() - t0, time.process_time() - c0
    summary = json.loads((Path(tmp) / "est" / "summary.json").read_text())
extra = {}
if batch:
    from oacli.estimation.batch import estimate_batch
    b = estimate_batch(records, settings, prior)
    extra = {"batch_theta": b.estimate.theta, "batch_cov": b.estimate.covariance}
np.savez(out_npz, theta=run.final.theta, cov=run.final.covariance, t_est=t_est, t_stage=t_stage, c_est=c_est,
         c_stage=c_stage,
         records=len(records), reinit=run.reinitialisations, status=summary["status"], **extra)
"""


def ensure_base(base: Path, commit: str = BASE_COMMIT) -> None:
    """Export ``commit``'s tree to ``base`` when it is not there yet."""
    if (base / "oacli" / "__init__.py").exists():
        return
    base.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(REPO), "archive", commit], check=True, capture_output=True)
    subprocess.run(["tar", "-x", "-C", str(base)], input=archive.stdout, check=True)


def ensure_mission(mission: Path | None, scratch: Path) -> Path:
    """A finished default mission folder (flown here when not given)."""
    if mission is not None:
        return mission
    out = scratch / "mission"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    subprocess.run([sys.executable, "-m", "oacli", "mission", str(REPO / "configs" / "mission_iss.yaml"),
                    "--out", str(out), "--quiet"], check=True, env=env, stdout=subprocess.DEVNULL)
    return out


def run_side(tree: Path, mission: Path, out_npz: Path, batch: bool) -> dict:
    """One timed run in a fresh process with ``tree`` first on the path."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS"):
        env[var] = "1"
    subprocess.run([sys.executable, "-c", _WORKER, str(mission), str(out_npz), "1" if batch else "0"],
                   check=True, env=env, cwd=str(tree))
    with np.load(out_npz) as data:
        return {k: data[k] for k in data.files}


def rel_max(a: np.ndarray, b: np.ndarray) -> float:
    """Largest entry difference relative to the largest entry of b."""
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="alternating repeats of each tree")
    parser.add_argument("--mission", type=Path, help="a finished default mission folder (flown when absent)")
    parser.add_argument("--base", type=Path, default=Path("/tmp/base-seqest"), help=f"base tree ({BASE_COMMIT})")
    parser.add_argument("--batch", action="store_true", help="also compare both covariances with the batch's")
    args = parser.parse_args()
    ensure_base(args.base)
    with tempfile.TemporaryDirectory() as tmp:
        scratch = Path(tmp)
        mission = ensure_mission(args.mission, scratch)
        runs: dict[str, list[dict]] = {"base": [], "new": []}
        for i in range(args.repeats):
            for side, tree in (("base", args.base), ("new", REPO)):
                res = run_side(tree, mission, scratch / f"{side}.npz", batch=args.batch and i == 0)
                runs[side].append(res)
                print(f"repeat {i + 1} {side:4s}: estimator {float(res['t_est']):.3f} s (CPU "
                      f"{float(res['c_est']):.3f} s), stage {float(res['t_stage']):.3f} s (CPU "
                      f"{float(res['c_stage']):.3f} s)", flush=True)
    base, new = runs["base"][0], runs["new"][0]
    print(f"\nrecords: {int(new['records'])}, re-initialisations base {int(base['reinit'])} new {int(new['reinit'])}, "
          f"status base {base['status']} new {new['status']}")
    for key, label in (("t_est", "estimator"), ("t_stage", "stage"), ("c_est", "estimator CPU"),
                       ("c_stage", "stage CPU")):
        b = np.array([float(r[key]) for r in runs["base"]])
        n = np.array([float(r[key]) for r in runs["new"]])
        print(f"{label:13s}: base min {b.min():.3f} / median {np.median(b):.3f} s, new min {n.min():.3f} / median "
              f"{np.median(n):.3f} s, ratio (median) {np.median(b) / np.median(n):.2f}x")
    std_b, std_n = np.sqrt(np.diag(base["cov"])), np.sqrt(np.diag(new["cov"]))
    print(f"θ base {np.array2string(base['theta'], precision=8)}\nθ new  {np.array2string(new['theta'], precision=8)}")
    print(f"relative difference: θ {float(np.max(np.abs(new['theta'] - base['theta']) / np.abs(base['theta']))):.2e}, "
          f"cov {rel_max(new['cov'], base['cov']):.2e}, std {float(np.max(np.abs(std_n - std_b) / std_b)):.2e}")
    if args.batch:
        cov_batch = new["batch_cov"]
        print(f"batch θ {np.array2string(new['batch_theta'], precision=8)}; covariance against the batch's: base "
              f"{rel_max(base['cov'], cov_batch):.3e}, new {rel_max(new['cov'], cov_batch):.3e}")
    print(json.dumps({"theta_rel": float(np.max(np.abs(new["theta"] - base["theta"]) / np.abs(base["theta"]))),
                      "cov_rel": rel_max(new["cov"], base["cov"])}))


if __name__ == "__main__":
    main()
