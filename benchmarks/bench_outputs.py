"""Benchmark: the default mission's outputs (stage PNGs, Rerun recordings, MCAP topics, the mission's own outputs and
hand-offs), the old path against the new one on the same data, alternating per repeat (issue 9).

Runs the mission once (``configs/mission_iss.yaml``, BLAS pinned to one thread) while capturing the arguments of
every stage's output call (``write_*_plots``, ``write_*_recording``, ``write_*_topics``), then replays each call
``--repeats`` times into temporary folders, old path then new path, and prints the median time per output kind:

* ``stage PNGs`` -- :data:`oacli.io.plots.common.LEGACY` (pyplot figures, constrained layout + tight bbox, every
  sample drawn, Pillow's PNG encoder) against the new path: fixed layout, decimated series, one blank figure reused per
  shape (:data:`~oacli.io.plots.common.REUSE`), text bitmaps cached
  (:data:`~oacli.io.plots.common.FAST_TEXT`), at most six ticks per linear axis, plain-text log tick labels, own PNG
  writer (RGB, no row filter, zlib 1);
* ``stage Rerun`` / ``stage MCAP`` -- the recordings and the MCAP topics (complete files, as the stages write them;
  their code has no old path: both columns run the same code, the spread between them is the machine's noise);
* ``mission outputs`` -- ``mission.rrd`` + ``plots/`` + the summary's comparison rows (the stage MCAPs read back),
  :data:`oacli.mission.records.CACHE` off (every reader reads its files) against on (each file read once);
* ``mission hand-offs`` -- :func:`oacli.mission.run.handoff_for` of every stage (the earlier stages' MCAPs read);
* ``stage configs`` -- ``validate_mission`` and every stage's :func:`oacli.mission.configs.stage_config` (no old
  path: both columns run the same code).

Last, the PNGs and the mission's outputs and overhead of the default mission, wall and CPU: with ``outputs.plots:
all`` as main's default was (every stage's PNGs, new drawing path) against the new default
``outputs.plots: mission`` (the mission's three PNGs only; ``oacli plots RUN_DIR`` draws the rest on demand).
The mission is run with ``outputs.plots: all`` so that every stage's PNG call is captured.

Run: ``taskset -c 1 python benchmarks/bench_outputs.py [--repeats 3] [--config configs/mission_iss.yaml]``
(``--mission DIR`` reuses a finished mission folder: its stage PNGs are drawn from its MCAPs as ``oacli plots`` draws
them, the same figures as at run time, and the stage Rerun and MCAP rows are skipped).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from contextlib import contextmanager  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import oacli.io.plots.common as plot_common  # noqa: E402
import oacli.mission.records as mission_records  # noqa: E402
import oacli.stages.estimate as st_estimate  # noqa: E402
import oacli.stages.excite as st_excite  # noqa: E402
import oacli.stages.plan as st_plan  # noqa: E402
import oacli.stages.smooth as st_smooth  # noqa: E402
import oacli.stages.track as st_track  # noqa: E402
from oacli.config import load_config  # noqa: E402
from oacli.config.outputs import PlotSet  # noqa: E402
from oacli.io.mcap_write import StageMcapWriter  # noqa: E402
from oacli.io.runfolder import is_complete  # noqa: E402
from oacli.mission.compare import comparison_row  # noqa: E402
from oacli.mission.configs import stage_config  # noqa: E402
from oacli.mission.layout import MISSION_STAGES, stage_by_key  # noqa: E402
from oacli.mission.plots import write_mission_plots  # noqa: E402
from oacli.mission.recording import write_mission_recording  # noqa: E402
from oacli.mission.run import handoff_for, mission_stages, run_mission, start_mission, validate_mission  # noqa: E402
from oacli.stages.replot import stage_figures  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

#: (module, function name, output kind) of every stage output call captured.
CAPTURED = [
    (st_track, "write_track_plots", "plots"), (st_estimate, "write_estimate_plots", "plots"),
    (st_excite, "write_excite_plots", "plots"), (st_plan, "write_path_plots", "plots"),
    (st_smooth, "write_path_plots", "plots"),
    (st_track, "write_track_recording", "rerun"), (st_estimate, "write_estimate_recording", "rerun"),
    (st_excite, "write_excite_recording", "rerun"), (st_plan, "write_plan_recording", "rerun"),
    (st_smooth, "write_smooth_recording", "rerun"),
    (st_track, "write_track_topics", "mcap"), (st_estimate, "write_estimate_topics", "mcap"),
    (st_excite, "write_offline_topics", "mcap"), (st_plan, "write_plan_topics", "mcap"),
    (st_smooth, "write_smooth_topics", "mcap"),
]


class FakeRun:
    """What the plot writers need of a run folder, in a temporary folder."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir

    def file(self, role: str, name: str) -> Path:
        return self.run_dir / name


def capture_mission(config: Path, out: Path) -> tuple[list[tuple[str, Callable[..., Any], tuple, dict]], Path]:
    """Run the mission into ``out`` and return every captured stage output call ``(kind, function, args, kwargs)``."""
    calls: list[tuple[str, Callable[..., Any], tuple, dict]] = []
    saved = []
    for module, name, kind in CAPTURED:
        real = getattr(module, name)
        saved.append((module, name, real))

        def wrapper(*args: Any, _real: Callable[..., Any] = real, _kind: str = kind, **kwargs: Any) -> Any:
            calls.append((_kind, _real, args, kwargs))
            return _real(*args, **kwargs)

        setattr(module, name, wrapper)
    try:
        cfg = load_config(config)
        # every stage's PNG call is captured: run as outputs.plots all (main's default before the mission presets
        # drew only the mission's PNGs)
        cfg = cfg.model_copy(update={"outputs": cfg.outputs.model_copy(update={"plots": PlotSet.ALL})})
        validate_mission(cfg)
        mission_dir = start_mission(cfg, out=out, runs_root=out.parent)
        run_mission(cfg, mission_dir)
    finally:
        for module, name, real in saved:
            setattr(module, name, real)
    return calls, mission_dir


def replay(kind: str, func: Callable[..., Any], args: tuple, kwargs: dict, tmp: Path, k: int) -> None:
    """One captured call again, into ``tmp``."""
    if kind == "plots" and not args:  # a stage's figure read back from its folder (--mission)
        func(tmp / f"p{k}.png")
    elif kind == "plots":
        func(FakeRun(tmp), {**args[1], "warnings": []}, **kwargs)
    elif kind == "rerun":
        func(tmp / f"r{k}.rrd", *args[1:], **kwargs)
    else:
        with StageMcapWriter(tmp / f"m{k}.mcap", stage="bench", config_yaml="bench: 1\n", time_ordered=True) as w:
            func(w, *args[1:], **kwargs)


@contextmanager
def legacy(on: bool):
    """Switch every old path on (``on``) or off."""
    before = (plot_common.LEGACY, mission_records.CACHE)
    plot_common.LEGACY, mission_records.CACHE = on, not on
    mission_records.clear_cache()
    try:
        yield
    finally:
        plot_common.LEGACY, mission_records.CACHE = before
        mission_records.clear_cache()


def mission_outputs(mission_dir: Path, tmp: Path) -> None:
    """What ``run_mission`` does after the last stage: comparison rows, ``mission.rrd``, ``plots/``."""
    summary = json.loads((mission_dir / "summary.json").read_text())
    for key in summary["comparison"]:
        comparison_row(key, json.loads((stage_by_key(key).folder(mission_dir) / "summary.json").read_text()),
                       mission_dir)
    if mission_records.CACHE:  # new: read once for both
        records = mission_records.load_mission_records(mission_dir, summary)
        write_mission_recording(tmp / "mission.rrd", mission_dir, summary, recording_name="bench", records=records)
        write_mission_plots(mission_dir, summary, records=records, out_dir=tmp / "plots")
    else:
        write_mission_recording(tmp / "mission.rrd", mission_dir, summary, recording_name="bench")
        write_mission_plots(mission_dir, summary, out_dir=tmp / "plots")


def handoffs(mission_dir: Path) -> None:
    """Every stage's hand-off, read from the mission folder."""
    cfg = load_config(mission_dir / "config.yaml")
    for stage in mission_stages(cfg):
        handoff_for(cfg, stage, mission_dir)


def stage_configs(mission_dir: Path) -> None:
    """What the mission derives per stage: every config up front (``validate_mission``), then each with its
    hand-off (the hand-offs' files cached), remembered as the stage's config (``remember_config``: the outputs need
    not parse its file; a no-op with the cache off)."""
    cfg = load_config(mission_dir / "config.yaml")
    validate_mission(cfg)
    for stage in mission_stages(cfg):
        mission_records.remember_config(stage.folder(mission_dir) / "config.yaml",
                                        stage_config(cfg, stage, handoff_for(cfg, stage, mission_dir)))


class _Clock:
    """Wall and CPU time of a block, appended to ``times[(row, side)]`` as ``(wall, cpu)`` [s]."""

    def __init__(self, times: dict[tuple[str, str], list[tuple[float, float]]], row: str, side: str) -> None:
        self.times, self.key = times, (row, side)

    def __enter__(self) -> None:
        self.wall, self.cpu = time.perf_counter(), time.process_time()

    def __exit__(self, *exc: object) -> None:
        self.times.setdefault(self.key, []).append((time.perf_counter() - self.wall, time.process_time() - self.cpu))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=ROOT / "configs" / "mission_iss.yaml")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--mission", type=Path, help="a finished mission folder: only the mission rows")
    args = parser.parse_args()
    times: dict[tuple[str, str], list[tuple[float, float]]] = {}
    counts: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        calls: list[tuple[str, Callable[..., Any], tuple, dict]] = []
        if args.mission is None:
            start = time.perf_counter()
            calls, mission_dir = capture_mission(args.config, tmp / "mission")
            print(f"mission run (new path, capturing) {time.perf_counter() - start:.1f} s")
        else:
            mission_dir = args.mission
            # the stage PNGs from the folder's MCAPs, as `oacli plots` draws them (the same figures as at run time)
            for stage in MISSION_STAGES:
                if is_complete(stage.folder(mission_dir)):
                    calls += [("plots", draw, (), {}) for draw in stage_figures(stage.folder(mission_dir)).values()]
        for kind, *_ in calls:
            counts[kind] = counts.get(kind, 0) + 1
        for rep in range(args.repeats):
            for side in ("old", "new") if rep % 2 == 0 else ("new", "old"):
                with legacy(side == "old"):
                    out = tmp / f"{side}{rep}"
                    out.mkdir()
                    for kind in ("plots", "rerun", "mcap"):
                        with _Clock(times, kind, side):
                            for k, (c_kind, func, a, kw) in enumerate(calls):
                                if c_kind == kind:
                                    replay(kind, func, a, kw, out, k)
                    # as in the mission: the hand-offs first (the cache, new path, starts empty), then the outputs
                    with _Clock(times, "mission hand-offs", side):
                        handoffs(mission_dir)
                    with _Clock(times, "stage configs", side):
                        stage_configs(mission_dir)
                    with _Clock(times, "mission outputs", side):
                        mission_outputs(mission_dir, out)
    names = {"plots": f"stage PNGs ({counts.get('plots', 0)} calls)", "rerun": "stage Rerun recordings",
             "mcap": "stage MCAP topics"}

    def med(row: str, side: str, which: int) -> float:
        return statistics.median(v[which] for v in times[(row, side)])

    print(f"{args.repeats} repeat(s), old and new alternating, median wall [s] (CPU [s] in brackets); calls per kind: "
          f"{counts}")
    print(f"  {'output kind':<28} {'old':>15} {'new':>15} {'speed-up':>9}")
    for kind in ("plots", "rerun", "mcap", "mission hand-offs", "stage configs", "mission outputs"):
        if (kind, "old") not in times or (kind in names and not counts.get(kind)):
            continue
        old, new = med(kind, "old", 0), med(kind, "new", 0)
        print(f"  {names.get(kind, kind):<28} {old:6.2f} ({med(kind, 'old', 1):6.2f}) {new:6.2f} "
              f"({med(kind, 'new', 1):6.2f}) {old / max(new, 1e-9):8.1f}x")
    overhead = ("mission hand-offs", "stage configs", "mission outputs")
    if counts.get("plots"):
        for which, unit in ((0, "wall"), (1, "CPU")):
            main_default = med("plots", "new", which) + sum(med(r, "new", which) for r in overhead)
            now_default = sum(med(r, "new", which) for r in overhead)
            print(f"PNGs + mission outputs and overhead ({unit}): outputs.plots all, as main's default (every "
                  f"stage's PNGs) {main_default:.2f} s; outputs.plots mission (the new "
                  f"default: the mission's PNGs only) {now_default:.2f} s")


if __name__ == "__main__":
    main()
