"""Diagnosis of the ``gapped`` row of ``bench_estimation.py``: what its Ixx spread against the ``prior`` bound owes to
the lost input's prediction, and what to the closed loop.

Each seed flies the benchmark's closed-loop run (``bench_estimation.one_seed``'s configuration, the same seeds and
the same lost steps) and estimates the ``gapped`` records with the lost wrench's model replaced, in the estimator
*and* in its Cramér-Rao bound (:func:`oacli.estimation.lost_inputs.lost_input_model`, patched here only):

* ``row`` -- as the benchmark (the neighbours' noise-corrected regression, its error variance measured on the run);
* ``exact`` -- the prediction replaced by the true lost input, its variance kept (a prior centred on the truth);
* ``exact+error`` -- the true lost input plus a Gaussian error drawn with exactly the modelled variance (per seed and
  lost step): a correctly specified prior, independent of every measurement. ``--torque-variance-scale s`` multiplies
  the torque's variance by ``s`` (estimator, bound and the drawn error alike): a prior ``1/s`` times tighter than
  the neighbours' regression gives, correctly specified.

``--open-loop`` replays every run open-loop (:func:`bench_estimation.open_loop_telemetry`: the true trajectory and
applied inputs, fresh measurement noise; the inputs no longer react to the records' noise). ``--methods
sequential`` runs the filter (``row``, and ``exact+error`` at scale 1 through its own neighbours' prediction,
:meth:`oacli.estimation.sequential.SequentialEstimator._bridge_gap`).

Printed per mode: the spread ``sqrt(mean(z²))`` of ``z = (θ̂ − θ) / CRB`` with its 95 % χ² interval, the bias
``mean(z)``, the kurtosis of the Ixx z-scores (3 for normal errors) and their correlation with the ``row`` mode's.

Measured (80 seeds, batch unless noted; Ixx spread): row 1.25, exact 1.31 (z correlation with row 0.99), exact+error
1.25 (sequential 1.27), exact+error with the torque variance × 0.7 / 0.3 / 0.05: 1.25 / 1.24 / 1.19; open-loop row
0.93, open-loop exact 0.94. Row Ixx kurtosis 4.0. The row's 1.25 is these 80 seeds': over 160 seeds it reads 1.11
(seeds 80-159 alone 0.95), within the target (``bench_estimation.py``, "The gapped row"), so the figures above
compare the modes on the same 80 seeds but overstate the row's excess.

Run: ``python benchmarks/bench_gapped_diagnosis.py [--seeds 20] [--modes row,exact,exact+error]
[--torque-variance-scale 1] [--open-loop] [--methods batch]``
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_estimation as be

import oacli.estimation.batch as batch
import oacli.estimation.bounds as bounds
import oacli.estimation.sequential as sequential
from oacli.io.mcap_io import read_telemetry
from oacli.stages.estimate import run_estimation
from oacli.stages.track import run_track

MODES = ("row", "exact", "exact+error")


@contextlib.contextmanager
def lost_input_replaced(mode: str, u_true: np.ndarray, period_s: float, seed: int, torque_scale: float
                        ) -> Iterator[None]:
    """Patch the batch's and the bound's lost-wrench model (and the filter's gap prediction) for one estimate."""
    original = batch.lost_input_model
    original_bridge = sequential.SequentialEstimator._bridge_gap

    def model(t, u, links, mass_kg, **kw):  # type: ignore[no-untyped-def]
        u_model, bridged, variance, offset = original(t, u, links, mass_kg, **kw)
        variance = variance * np.r_[1.0, 1.0, 1.0, torque_scale, torque_scale, torque_scale]
        if mode != "row":
            steps = np.rint(np.asarray(t) / period_s).astype(int)
            for i in np.flatnonzero(bridged):
                u_model[i] = u_true[steps[i]]
                if mode == "exact+error":
                    sd = np.sqrt(variance[i] * np.r_[mass_kg**2, mass_kg**2, mass_kg**2, 1.0, 1.0, 1.0])
                    u_model[i] += sd * np.random.default_rng([seed, int(steps[i])]).standard_normal(6)
        return u_model, bridged, variance, offset

    def bridge(self, rec):  # type: ignore[no-untyped-def]
        ok = original_bridge(self, rec)
        if ok and mode == "exact+error":
            t = np.array(self._inputs_t)
            starts = np.array(self._inputs_start, dtype=bool)
            var = batch.lost_input_prior(t, np.array(self._inputs_u), ~starts[1:])[2]
            step = round(float(t[-2]) / period_s)
            self._u_last = u_true[step] + np.sqrt(var) * np.random.default_rng([seed, step]).standard_normal(6)
        return ok

    batch.lost_input_model = model
    bounds.lost_input_model = model  # type: ignore[attr-defined]
    sequential.SequentialEstimator._bridge_gap = bridge  # type: ignore[method-assign]
    try:
        yield
    finally:
        batch.lost_input_model = original
        bounds.lost_input_model = original  # type: ignore[attr-defined]
        sequential.SequentialEstimator._bridge_gap = original_bridge  # type: ignore[method-assign]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--modes", default=",".join(MODES))
    parser.add_argument("--methods", default="batch")
    parser.add_argument("--torque-variance-scale", type=float, default=1.0)
    parser.add_argument("--open-loop", action="store_true")
    parser.add_argument("--reference", type=Path, default=be.DEFAULT_REFERENCE)
    args = parser.parse_args()
    if not args.reference.exists():
        raise SystemExit(f"--reference {args.reference}: not found (RATTLE data, see README)")
    be._setup(args.reference)
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    z: dict[tuple[str, str], list[np.ndarray]] = {(me, mo): [] for me in methods for mo in modes}
    for seed in range(args.seeds):
        cfg = be._SETUP["cfg0"].model_copy(update={"seed": seed})
        with tempfile.TemporaryDirectory() as tmp:
            run_track(cfg, reference=be._SETUP["reference"], out=Path(tmp) / "track")
            tel = read_telemetry(Path(tmp) / "track" / "track.mcap")
        if args.open_loop:
            tel = be.open_loop_telemetry(tel, seed)
        records = be.tampered_records(tel, "gapped", np.random.default_rng(20_000 + seed))
        period = float(np.median(np.diff(tel.t_ctrl)))
        for method in methods:
            for mode in modes:
                if method == "sequential" and (mode == "exact" or args.torque_variance_scale != 1.0):
                    continue  # the filter has no per-gap variance to scale and no exact mode here
                with lost_input_replaced(mode, tel.u_applied, period, seed, args.torque_variance_scale):
                    run = run_estimation(records, be._SETUP["settings"], be.PRIOR, method, window_s=1e6)
                z[(method, mode)].append((run.final.theta - be.TRUTH) / np.asarray(run.bound.std, float))
        print(f"seed {seed:2d}: " + "  ".join(f"{me}/{mo} Ixx z {v[-1][1]:+.2f}" for (me, mo), v in z.items() if v),
              flush=True)
    print()
    print(f"{args.seeds} seeds{' (open-loop replay)' if args.open_loop else ''}, torque variance × "
          f"{args.torque_variance_scale:g}: spread sqrt(mean(z²)) [95 % interval], bias mean(z), Ixx kurtosis, "
          "Ixx z correlation with 'row'")
    for (method, mode), values in z.items():
        if not values:
            continue
        arr = np.array(values)
        ratio, low, high = be.spread_ratio(arr, np.ones_like(arr))
        cells = "  ".join(f"{p} {r:4.2f} [{lo:4.2f}, {hi:4.2f}]" for p, r, lo, hi in zip(be.NAMES, ratio, low, high,
                                                                                          strict=True))
        kurt = float(np.mean(arr[:, 1] ** 4) / np.mean(arr[:, 1] ** 2) ** 2)
        ref = z.get((method, "row"))
        corr = float(np.corrcoef(arr[:, 1], np.array(ref)[:, 1])[0, 1]) if ref and mode != "row" else math.nan
        print(f"{method:<10} {mode:<12} | {cells} | bias " + " ".join(f"{v:+.2f}" for v in arr.mean(axis=0))
              + f" | kurtosis {kurt:.2f} | corr {corr:.2f}")


if __name__ == "__main__":
    main()
