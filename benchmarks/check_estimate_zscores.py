"""Are the estimators' reported σ honest over many missions? Issue 30's z-score "Done when", from a campaign of
missions (e.g. ``configs/campaign_tube_noise.yaml``: the default mission over seeds, only the noise changing).

For the batch (``segment-2/estimate``) and the sequential filter (``segment-2/estimate-sequential``) of every run, the
z-score of every estimated entry against the simulated truth (``rigid_body.z_score`` of the stage's summary: the
error ÷ the reported, physical σ), and the error ÷ the Cramér-Rao bound (``rigid_body.error_over_crb``). Printed
per estimator and entry: the mean and the spread (standard deviation over the runs) of z, the share within 2σ, the
largest |z|, and the spread of error ÷ CRB; then the stages' statuses. Issue 30 asks for a spread ≤ 1.2 per entry
and ≥ 90 % within 2σ; a spread far below 1 says the σ is conservative (wider than the errors).

Run: ``python benchmarks/check_estimate_zscores.py CAMPAIGN_DIR``.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np

STAGES = {"batch": "segment-2/estimate", "sequential": "segment-2/estimate-sequential"}


def mission_dirs(campaign: Path) -> list[Path]:
    """Each run's last attempt's mission folder (complete or not)."""
    out = []
    for run in sorted((campaign / "runs").glob("run-*")):
        attempts = sorted(run.glob("attempt-*/mission"), key=lambda p: int(p.parts[-2].split("-")[1]))
        if attempts:
            out.append(attempts[-1])
    return out


def table(missions: list[Path], stage: str) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], Counter]:
    """z-scores and error ÷ CRB per entry over the missions whose ``stage`` reported them, and the statuses."""
    z: dict[str, list[float]] = {}
    crb: dict[str, list[float]] = {}
    statuses: Counter = Counter()
    for mission in missions:
        path = mission / stage / "summary.json"
        if not path.is_file():
            statuses["missing"] += 1
            continue
        summary = json.loads(path.read_text())
        statuses[str(summary.get("status"))] += 1
        rigid = summary.get("rigid_body") or {}
        for name, value in (rigid.get("z_score") or {}).items():
            z.setdefault(name, []).append(float(value))
        for name, value in (rigid.get("error_over_crb") or {}).items():
            crb.setdefault(name, []).append(float(value))
    return ({k: np.asarray(v) for k, v in z.items()}, {k: np.asarray(v) for k, v in crb.items()}, statuses)


def main() -> None:
    """Print the tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("campaign", type=Path)
    args = parser.parse_args()
    missions = mission_dirs(args.campaign)
    print(f"{len(missions)} missions in {args.campaign}")
    for label, stage in STAGES.items():
        z, crb, statuses = table(missions, stage)
        print(f"\n{label} ({stage}): statuses {dict(statuses)}")
        print(f"  {'entry':<16} {'runs':>4} {'mean z':>8} {'spread z':>9} {'in 2σ':>7} {'max |z|':>8} "
              f"{'spread err/CRB':>15}")
        every = []
        for name, values in z.items():
            every.append(values)
            c = crb.get(name)
            spread_crb = f"{np.std(c, ddof=1):15.2f}" if c is not None and c.size > 1 else f"{'':>15}"
            spread = np.std(values, ddof=1) if values.size > 1 else float("nan")
            print(f"  {name:<16} {values.size:4d} {np.mean(values):8.3f} {spread:9.3f} "
                  f"{100 * np.mean(np.abs(values) <= 2):6.1f}% {np.max(np.abs(values)):8.3f}{spread_crb}")
        if every:
            allz = np.concatenate(every)
            print(f"  all entries: {allz.size} z-scores, {100 * np.mean(np.abs(allz) <= 2):.1f} % within 2σ, "
                  f"largest |z| {np.max(np.abs(allz)):.2f}")


if __name__ == "__main__":
    main()
