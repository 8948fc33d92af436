"""Benchmark: the mission's overhead outside the stages' own computation (issue 9): reading the stage MCAPs back,
deriving the stage configs, writing ``mission.rrd``.

On one finished mission folder (``--mission-dir``, or a default mission with ``outputs.plots: false`` run first
into a temporary folder), each row is timed old path vs new path, alternating which side runs first per repeat,
file caches cleared before each side (:func:`oacli.mission.records.clear_cache`):

* ``mission reads``: what the mission reads back after its stages (the hand-offs ``estimate_model`` and the final
  positions, the comparison rows, :func:`~oacli.mission.records.load_mission_records`); old = the former chunk
  parser (``oacli.io.mcap_walk.IN_PLACE_CHUNKS`` off: a ``StreamReader`` record object per record);
* ``one track.mcap read_stage``: all topics of ``segment-2/track/track.mcap``, same two parsers;
* ``stage_config x N``: every stage's config; old = the same plus the removed ``yaml.safe_load(dump_config(cfg))``
  round trip with the pure-Python emitter;
* ``dump_config``: a stage config's YAML text, pure-Python emitter vs libyaml's (same text);
* ``load_config_cached x stages``: parsing each stage's ``config.yaml`` (old) vs remembering the config the stage ran
  with (:func:`~oacli.mission.records.remember_config`, new);
* ``mission.rrd``: :func:`oacli.io.rerun.mission.write_mission_recording` from the records (one side).

Run: ``taskset -c 1 python benchmarks/bench_mission_overhead.py [--repeats 5] [--mission-dir runs/mission-...]``
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
from pathlib import Path  # noqa: E402

import yaml  # noqa: E402

import oacli.config as config_module  # noqa: E402
from oacli.config import load_config  # noqa: E402
from oacli.config.outputs import PlotSet  # noqa: E402
from oacli.io import mcap_walk  # noqa: E402
from oacli.io.mcap_read import read_stage  # noqa: E402
from oacli.io.rerun.mission import write_mission_recording  # noqa: E402
from oacli.mission import records  # noqa: E402
from oacli.mission.compare import comparison_row  # noqa: E402
from oacli.mission.configs import Handoff, stage_config  # noqa: E402
from oacli.mission.layout import stage_by_key  # noqa: E402
from oacli.mission.run import (  # noqa: E402
    _final_position,
    estimate_model,
    mission_stages,
    run_mission,
    start_mission,
    validate_mission,
)

ROOT = Path(__file__).resolve().parents[1]


def _python_dumper() -> Callable[[], None]:
    config_module._DUMPER = config_module._FlowVectorDumper
    return lambda: setattr(config_module, "_DUMPER", config_module._DUMPERS[-1])


def mission_reads(mission_dir: Path, cfg, summary: dict) -> None:
    """Everything the mission reads back after running its stages (cache cleared first)."""
    records.clear_cache()
    estimate_model(cfg, stage_by_key("segment-2/estimate").mcap(mission_dir))
    _final_position(stage_by_key("segment-1/track").mcap(mission_dir))
    _final_position(stage_by_key("segment-2/track").mcap(mission_dir))
    for key in summary["comparison"]:
        stage_summary = json.loads((stage_by_key(key).folder(mission_dir) / "summary.json").read_text())
        comparison_row(key, stage_summary, mission_dir)
    records.load_mission_records(mission_dir, summary)


class _OldPaths:
    """Switch the mission to the former paths that are still reachable: the per-record ``StreamReader`` chunk
    parser, the pure-Python YAML emitter, ``stage_config`` preceded by the removed ``yaml.safe_load(dump_config)``
    round trip, stage configs parsed again instead of remembered. (Not reverted: the shared read of each track file
    and of the batch estimate, which the former code read twice.)"""

    def __enter__(self) -> None:
        import oacli.mission.run as run_module

        self.saved = (run_module.stage_config, run_module.remember_config)
        original = run_module.stage_config

        def stage_config_round_trip(cfg, stage, handoff, **kw):
            yaml.safe_load(config_module.dump_config(cfg))
            return original(cfg, stage, handoff, **kw)

        run_module.stage_config = stage_config_round_trip
        run_module.remember_config = lambda path, cfg: False
        mcap_walk.IN_PLACE_CHUNKS = False
        self.restore = _python_dumper()

    def __exit__(self, *exc: object) -> None:
        import oacli.mission.run as run_module

        run_module.stage_config, run_module.remember_config = self.saved
        mcap_walk.IN_PLACE_CHUNKS = True
        self.restore()


def mission_overhead(cfg, old: bool) -> tuple[float, float]:
    """Run the mission (no PNGs) into a temporary folder; (wall [s], wall minus the stages' own wall times [s])."""
    validate_mission(cfg)
    with tempfile.TemporaryDirectory() as tmp:
        records.clear_cache()
        start = time.perf_counter()
        if old:
            with _OldPaths():
                mission_dir = start_mission(cfg, out=Path(tmp) / "run", runs_root=Path(tmp))
                result = run_mission(cfg, mission_dir)
        else:
            mission_dir = start_mission(cfg, out=Path(tmp) / "run", runs_root=Path(tmp))
            result = run_mission(cfg, mission_dir)
        wall = time.perf_counter() - start
        stages = sum(float(s["wall_time_s"]) for s in result.summary["stages"].values())
        records.clear_cache()
        return wall, wall - stages


def timed(fn: Callable[[], object]) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mission-dir", type=Path, help="a finished mission folder (default: run one first)")
    parser.add_argument("--config", type=Path, default=ROOT / "configs" / "mission_iss.yaml")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--missions", type=int, default=0,
                        help="also run the whole mission this many times per side (old paths / new), alternating, "
                             "and print its overhead: wall time minus the stages' own wall times")
    args = parser.parse_args()
    tmp = tempfile.TemporaryDirectory()
    cfg = load_config(args.config)
    cfg = cfg.model_copy(update={"outputs": cfg.outputs.model_copy(update={"plots": PlotSet.NONE})})
    mission_dir = args.mission_dir
    if mission_dir is None:
        validate_mission(cfg)
        mission_dir = start_mission(cfg, out=Path(tmp.name) / "run", runs_root=Path(tmp.name))
        start = time.perf_counter()
        run_mission(cfg, mission_dir)
        print(f"ran the mission first: {time.perf_counter() - start:.1f} s")
    else:
        cfg = load_config(mission_dir / "config.yaml")
    summary = json.loads((mission_dir / "summary.json").read_text())
    stages = mission_stages(cfg)
    track = stage_by_key("segment-2/track").mcap(mission_dir)
    stage_cfgs = [stage_config(cfg, s, Handoff(reference=Path("placeholder.mcap") if s.command == "track" else None))
                  for s in stages]
    stage_yaml = [s.folder(mission_dir) / "config.yaml" for s in stages]

    def with_reader(in_place: bool, fn: Callable[[], object]) -> Callable[[], object]:
        def run() -> object:
            mcap_walk.IN_PLACE_CHUNKS = in_place
            try:
                return fn()
            finally:
                mcap_walk.IN_PLACE_CHUNKS = True
        return run

    def configs_old() -> None:
        restore = _python_dumper()
        try:
            for s in stages:
                yaml.safe_load(config_module.dump_config(cfg))
                stage_config(cfg, s, Handoff(reference=Path("p.mcap") if s.command == "track" else None))
        finally:
            restore()

    def configs_new() -> None:
        for s in stages:
            stage_config(cfg, s, Handoff(reference=Path("p.mcap") if s.command == "track" else None))

    def dump_old() -> None:
        restore = _python_dumper()
        try:
            config_module.dump_config(stage_cfgs[-1])
        finally:
            restore()

    def load_old() -> None:
        records.clear_cache()
        for path in stage_yaml:
            if path.is_file():
                records.load_config_cached(path)

    def load_remembered() -> None:
        for path in stage_yaml:
            if path.is_file():
                records.load_config_cached(path)

    loaded = [records.load_config_cached(p) for p in stage_yaml if p.is_file()]

    def remember_new() -> None:
        records.clear_cache()
        for path, c in zip([p for p in stage_yaml if p.is_file()], loaded, strict=True):
            records.remember_config(path, c)
        load_remembered()

    mission_records = records.load_mission_records(mission_dir, summary)
    rows: list[tuple[str, Callable[[], object], Callable[[], object] | None]] = [
        ("mission reads (hand-offs, comparison, records)", with_reader(False, lambda: mission_reads(
            mission_dir, cfg, summary)), with_reader(True, lambda: mission_reads(mission_dir, cfg, summary))),
        ("one track.mcap read_stage (all topics)", with_reader(False, lambda: read_stage(track)),
         with_reader(True, lambda: read_stage(track))),
        (f"stage_config x {len(stages)}", configs_old, configs_new),
        ("dump_config (one stage config)", dump_old, lambda: config_module.dump_config(stage_cfgs[-1])),
        (f"stage config.yaml x {len(loaded)}: parse vs remember", load_old, remember_new),
        ("mission.rrd (write_mission_recording)", lambda: write_mission_recording(
            Path(tmp.name) / "bench.rrd", mission_dir, summary, recording_name="bench", records=mission_records),
         None),
    ]
    print(f"mission folder {mission_dir}, {args.repeats} repeats, medians [s]")
    print(f"{'row':52s} {'old':>8s} {'new':>8s} {'speed-up':>9s}")
    for name, old, new in rows:
        olds, news = [], []
        for k in range(args.repeats):
            order = ((old, olds), (new, news)) if k % 2 == 0 else ((new, news), (old, olds))
            for fn, out in order:
                if fn is not None:
                    records.clear_cache()
                    out.append(timed(fn))
        o = statistics.median(olds)
        if news:
            n = statistics.median(news)
            print(f"{name:52s} {o:8.3f} {n:8.3f} {o / n:8.1f}x")
        else:
            print(f"{name:52s} {o:8.3f} {'':>8s}")
    if args.missions:
        sides: dict[bool, list[tuple[float, float]]] = {True: [], False: []}
        for k in range(args.missions):
            for old in ((True, False) if k % 2 == 0 else (False, True)):
                sides[old].append(mission_overhead(cfg, old))
        for old in (True, False):
            walls = [w for w, _ in sides[old]]
            over = [o for _, o in sides[old]]
            print(f"whole mission, {'old' if old else 'new'} paths: wall {statistics.median(walls):7.2f} s, "
                  f"outside the stages {statistics.median(over):6.2f} s  (runs: "
                  + ", ".join(f"{o:.2f}" for o in over) + ")")
    records.clear_cache()
    tmp.cleanup()


if __name__ == "__main__":
    main()
