"""Benchmark: is the full rigid body's reported σ honest? z-scores of the default mission's estimate over seeds.

The default mission's segment 2 (``oacli mission configs/mission_iss.yaml --out RUN``) is re-flown with other seeds:
its track stage on the same excitation (``RUN/segment-2/excite/excite.mcap``, the track config with ``--seed S``:
new sensor noise), then its estimate stage (batch by default; ``--method sequential``). Every estimated parameter's
z-score ``(θ̂ − θ)/σ`` (summary ``rigid_body``) is collected; printed per parameter: the z-scores' standard
deviation (honest σ: 1; the issue asks ≤ 1.2), mean, largest |z| and the share within 2σ (≥ 90 %), and the χ² and
NIS ratios and statuses of the runs.

Run: ``python benchmarks/bench_rigid_body_seeds.py RUN [--seeds 2-11] [--method batch] [--keep DIR]``
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


def fly(run: Path, seed: int, method: str, work: Path) -> dict:
    """Track segment 2's excitation with ``seed`` and estimate; the estimate's summary."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    seg = run / "segment-2"
    track, est = work / f"track-{seed}", work / f"estimate-{seed}"
    cmd = [sys.executable, "-m", "oacli"]
    subprocess.run([*cmd, "track", str(seg / "track" / "config.yaml"), "--reference",
                    str(seg / "excite" / "excite.mcap"), "--seed", str(seed), "--out", str(track), "-q"],
                   check=True, env=env, capture_output=True)
    subprocess.run([*cmd, "estimate", str(seg / "estimate" / "config.yaml"), "--telemetry",
                    str(track / "track.mcap"), "--method", method, "--out", str(est), "-q"],
                   check=False, env=env, capture_output=True)
    return json.loads((est / "summary.json").read_text())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a default mission's run folder")
    parser.add_argument("--seeds", default="2-11", help="first-last seed")
    parser.add_argument("--method", default="batch", choices=["batch", "sequential"])
    parser.add_argument("--keep", type=Path, help="keep the runs here (default: a temporary folder)")
    args = parser.parse_args()
    first, last = (int(v) for v in args.seeds.split("-"))
    z: dict[str, list[float]] = {}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        for seed in range(first, last + 1):
            s = fly(args.run, seed, args.method, work)
            rb = s.get("rigid_body", {})
            for name, value in (rb.get("z_score") or {}).items():
                if value is not None:
                    z.setdefault(name, []).append(float(value))
            rows.append((seed, s["status"], s.get("chi2_ratio"), s.get("nis_ratio"), s.get("error_pct", {})))
            worst = max((abs(v) for v in (rb.get("z_score") or {}).values() if v is not None), default=0.0)
            print(f"seed {seed}: {s['status']}, χ² ratio {s.get('chi2_ratio')}, NIS ratio {s.get('nis_ratio')}, "
                  f"max |z| {worst:.2f}", flush=True)
    print(f"\n{len(rows)} seeds, method {args.method}: statuses "
          f"{ {st: sum(r[1] == st for r in rows) for st in {r[1] for r in rows}} }")
    print(f"{'parameter':<16} {'std(z)':>7} {'mean(z)':>8} {'max|z|':>7} {'within 2σ':>10}")
    for name, values in z.items():
        v = np.array(values)
        print(f"{name:<16} {np.std(v, ddof=1) if v.size > 1 else float('nan'):7.2f} {np.mean(v):8.2f} "
              f"{np.max(np.abs(v)):7.2f} {100 * np.mean(np.abs(v) <= 2):9.0f}%")
    errors = np.array([[r[4].get(k, np.nan) for k in ("mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2")] for r in rows])
    print("median error % (mass, Ixx, Iyy, Izz):", np.round(np.nanmedian(errors, axis=0), 3).tolist())


if __name__ == "__main__":
    main()
