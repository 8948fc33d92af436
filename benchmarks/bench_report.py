"""Benchmark: ``oacli report RUN_DIR`` alone against the mission it reports (issue 34: ≤ 10 % of the mission).

Per seed: the default mission (``configs/mission_iss.yaml``, ``outputs.report=false``: no page written in the
mission) is run in a fresh process, then ``oacli report`` in fresh processes on its folder, wall and CPU time (user +
system of the child) each:

* ``cold``: no ``plots/tracking_bands.png`` yet: the report reads the stage MCAPs and draws its tracking figure
  (what a campaign run, written without a page, costs);
* ``warm``: the same command again: the figure the first report left in ``plots/`` is inlined (what ``oacli
  report`` of a mission that wrote its page costs, the mission's default);
* with ``--compare-tree DIR``, ``old-cold`` and ``old-warm``: the same two reports by another oacli checkout
  (e.g. ``git -C /work/main archive HEAD | tar -x -C /tmp/base``) on the same folder; the two trees alternate which
  runs first per seed.

Every child runs as an installed oacli does: with its bytecode cached (both trees are byte-compiled first and
``PYTHONDONTWRITEBYTECODE`` is dropped from the children's environment; with it set and no ``__pycache__``, every
run compiles the tree's modules again, ~0.1 s of CPU that an installed package never spends).

Prints per seed and the medians, each report's time as a percentage of the mission's (wall and CPU) and, with a
compared tree, the new/old ratios. The machine's load inflates wall times; the CPU columns are the steadier figure.

Run: ``nice -n 10 python benchmarks/bench_report.py [--seeds 3] [--compare-tree /tmp/base]``
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CACHE = Path("plots") / "tracking_bands.png"


def timed(cmd: list[str], tree: Path) -> tuple[float, float]:
    """Wall and CPU (user + system of the child) seconds of ``cmd`` run with ``tree`` first on the path."""
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # as installed: bytecode cached (module docstring)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(cmd, cwd=tree, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def report(tree: Path, mission: Path, out: Path, clear: bool) -> tuple[float, float]:
    """One ``oacli report`` of ``mission`` by the checkout ``tree`` (its cached figure removed first if ``clear``)."""
    if clear:
        (mission / CACHE).unlink(missing_ok=True)
    return timed([sys.executable, "-m", "oacli", "report", str(mission), "--out", str(out)], tree)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--config", type=Path, default=ROOT / "configs" / "mission_iss.yaml")
    parser.add_argument("--compare-tree", type=Path, help="another oacli checkout: its reports as the 'old' side")
    args = parser.parse_args()
    trees = [ROOT] + ([args.compare_tree.resolve()] if args.compare_tree else [])
    for tree in trees:  # bytecode as an installed package has it (module docstring)
        subprocess.run([sys.executable, "-m", "compileall", "-q", str(tree / "oacli")], check=True,
                       stdout=subprocess.DEVNULL)
    rows: dict[str, list[tuple[float, float]]] = {"mission": [], "cold": [], "warm": [], "old-cold": [],
                                                  "old-warm": []}
    with tempfile.TemporaryDirectory(prefix="bench-report-") as tmp:
        for i in range(args.seeds):
            seed = i + 1
            mission = Path(tmp) / f"mission-{seed}"
            rows["mission"].append(timed([sys.executable, "-m", "oacli", "mission", str(args.config), "--seed",
                                          str(seed), "--set", "outputs.report=false", "--out", str(mission), "-q"],
                                         ROOT))
            sides = [("", ROOT)] + ([("old-", args.compare_tree.resolve())] if args.compare_tree else [])
            for prefix, tree in (sides if i % 2 == 0 else sides[::-1]):  # alternate which side runs first
                rows[prefix + "cold"].append(report(tree, mission, Path(tmp) / f"{prefix}cold-{seed}.html",
                                                    clear=True))
                rows[prefix + "warm"].append(report(tree, mission, Path(tmp) / f"{prefix}warm-{seed}.html",
                                                    clear=False))
            m = rows["mission"][-1]
            print(f"seed {seed}: mission {m[0]:.1f} s wall, {m[1]:.1f} s CPU; " + "; ".join(
                f"{k} {v[-1][0]:.2f} s ({100 * v[-1][0] / m[0]:.1f} %) wall, {v[-1][1]:.2f} s "
                f"({100 * v[-1][1] / m[1]:.1f} %) CPU" for k, v in rows.items() if k != "mission" and v), flush=True)
    med = {k: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v)) for k, v in rows.items() if v}
    m = med["mission"]
    print(f"median over {args.seeds} seeds: mission {m[0]:.1f} s wall, {m[1]:.1f} s CPU")
    for k, (w, c) in med.items():
        if k != "mission":
            print(f"  report {k}: {w:.2f} s wall ({100 * w / m[0]:.1f} %), {c:.2f} s CPU ({100 * c / m[1]:.1f} %)")
    for case in ("cold", "warm"):
        if f"old-{case}" in med:
            (w, c), (wo, co) = med[case], med[f"old-{case}"]
            print(f"  {case}: new / old = {w / wo:.2f} wall, {c / co:.2f} CPU")


if __name__ == "__main__":
    main()
