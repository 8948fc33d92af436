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
* ``mission.rrd``: :func:`oacli.mission.recording.write_mission_recording` from the records (one side).

``--missions N`` also runs the whole mission N times per side in this process (old paths: the above, the reader's
per-record ``json.loads`` of sample records (``oacli.io.mcap_read.FAST_SAMPLES`` off) and no stage records kept in
memory (``oacli.io.mcap_memo.ENABLED`` off), alternating. ``--compare-tree DIR --missions N`` runs the default
mission (``outputs.plots: mission``, as ``bench_mission.py``) N times in fresh processes of this checkout and of
the oacli checkout DIR (e.g. ``git -C /work/main archive 1e98b38 | tar -x -C /tmp/base``), alternating which runs
first, prints each side's "mission outputs and overhead" (wall minus the stages' own wall times), its excite stage,
wall and CPU, and checks that the two sides' last missions agree: the mission PNGs pixel for pixel, every stage MCAP's
samples bit for bit and its other records apart from wall-clock fields, the summaries apart from wall times.

``--mcap-writer DIR --repeats N`` times the stage MCAP writing alone: the default mission is run once capturing every
stage's ``write_*_topics`` call (as ``bench_outputs.py`` does), then the calls are replayed N times into
:class:`~oacli.io.mcap_write.StageMcapWriter` of this checkout and into the one of the oacli checkout DIR (its
``mcap_write.py`` and ``jsonsafe.py`` loaded from there), alternating, CPU time of this process; every message of
the two sides' files (topic, channel metadata, schema, log and publish time, sequence, payload bytes) must be equal.

Run: ``taskset -c 1 python benchmarks/bench_mission_overhead.py [--repeats 5] [--mission-dir runs/mission-...]``
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402

import yaml  # noqa: E402

import oacli.config as config_module  # noqa: E402
from oacli.config import load_config  # noqa: E402
from oacli.config.outputs import PlotSet  # noqa: E402
from oacli.io import mcap_read, mcap_walk  # noqa: E402

try:  # absent in checkouts before it (--compare-tree runs this script against them)
    from oacli.io import mcap_memo
except ImportError:
    mcap_memo = None
from oacli.io.mcap_read import read_stage  # noqa: E402
from oacli.mission import records  # noqa: E402
from oacli.mission.compare import comparison_row  # noqa: E402
from oacli.mission.configs import Handoff, stage_config  # noqa: E402
from oacli.mission.layout import stage_by_key  # noqa: E402
from oacli.mission.recording import write_mission_recording  # noqa: E402
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
        mcap_read.FAST_SAMPLES = False
        if mcap_memo is not None:
            mcap_memo.ENABLED = False
        self.restore = _python_dumper()

    def __exit__(self, *exc: object) -> None:
        import oacli.mission.run as run_module

        run_module.stage_config, run_module.remember_config = self.saved
        mcap_walk.IN_PLACE_CHUNKS = True
        mcap_read.FAST_SAMPLES = True
        if mcap_memo is not None:
            mcap_memo.ENABLED = True
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


def child_mission(config: Path, out: Path) -> None:
    """One default mission into ``out`` in this process (``--child-mission``): prints JSON (wall and CPU [s], the
    overhead row, the stages' wall times)."""
    import oacli.mission.run as run_module

    cfg = load_config(config)
    validate_mission(cfg)
    stage_cpu: dict[str, float] = {}
    run_stage = run_module.run_stage

    def timed_stage(stage, *args, **kwargs):  # the CPU time of each stage call (the machine may be loaded)
        cpu0 = time.process_time()
        try:
            return run_stage(stage, *args, **kwargs)
        finally:
            stage_cpu[stage.key] = time.process_time() - cpu0

    run_module.run_stage = timed_stage
    start, cpu = time.perf_counter(), time.process_time()
    mission_dir = start_mission(cfg, out=out, runs_root=out.parent)
    result = run_mission(cfg, mission_dir)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    stages = {k: float(v["wall_time_s"]) for k, v in result.summary["stages"].items()}
    print(json.dumps({"wall": wall, "cpu": cpu, "overhead": wall - sum(stages.values()), "stages": stages,
                      "overhead_cpu": cpu - sum(stage_cpu.values()), "excite_cpu": stage_cpu["segment-2/excite"]}))


_CLOCK_FIELDS = ("time", "_ms", "created_utc", "elapsed", "git_commit", "version")
#: Wall times inside log texts ("solution after 2 iterations (0.021 s)").
_CLOCK_TEXT = re.compile(r"\(\d+\.\d+ s\)")


def _without_clock(value: object) -> object:
    """A JSON record without its wall-clock fields (solve times, creation time), which differ from run to run."""
    if isinstance(value, dict):
        return {k: _without_clock(v) for k, v in value.items() if not any(c in k for c in _CLOCK_FIELDS)}
    if isinstance(value, list | tuple):
        return [_without_clock(v) for v in value]
    return value


def _rrd_content(path: Path, folder: Path) -> dict[str, list]:
    """A recording's rows per entity (every column but row ids, sorted; chunking and batching differ from run to
    run), the mission folder's name replaced; the recording's own properties (its start time) left out."""
    import rerun.chunk as rc

    out: dict[str, list] = {}
    for chunk in rc.RrdReader(path).stream():
        if chunk.entity_path.startswith("/__properties"):
            continue
        batch = chunk.to_record_batch()
        cols = {f.name: batch.column(i).to_pylist() for i, f in enumerate(batch.schema) if "rowid" not in
                f.name.lower().replace("_", "")}
        rows = out.setdefault(chunk.entity_path, [])
        for r in range(batch.num_rows):
            row = repr(sorted((n, v[r]) for n, v in cols.items())).replace(str(folder), "<mission>")
            rows.append(_CLOCK_TEXT.sub("(? s)", row))
    return {k: sorted(v) for k, v in out.items()}


def same_missions(a: Path, b: Path) -> list[str]:
    """Differences between two finished missions' outputs (module docstring); empty when they agree."""
    import numpy as np
    from matplotlib.image import imread

    def text(value: object, folder: Path) -> str:
        dumped = json.dumps(_without_clock(value), sort_keys=True, default=str).replace(str(folder), "<mission>")
        return _CLOCK_TEXT.sub("(? s)", dumped)

    problems = []
    if _rrd_content(a / "mission.rrd", a) != _rrd_content(b / "mission.rrd", b):
        problems.append("mission.rrd content differs")
    for png in sorted((a / "plots").glob("*.png")):
        other = b / "plots" / png.name
        if not other.is_file() or not np.array_equal(imread(png), imread(other)):
            problems.append(f"plots/{png.name} differs")
    for mcap in sorted(a.glob("segment-*/*/*.mcap")):
        ra, rb = read_stage(mcap), read_stage(b / mcap.relative_to(a))
        name = str(mcap.relative_to(a))
        if ra.trajectories.keys() != rb.trajectories.keys() or ra.wrenches.keys() != rb.wrenches.keys():
            problems.append(f"{name}: other sample topics")
            continue
        for topic, ta in ra.trajectories.items():
            tb = rb.trajectories[topic]
            if not all(np.array_equal(getattr(ta, f), getattr(tb, f)) for f in ("t", "x", "u")):
                problems.append(f"{name} {topic}: samples differ")
        for topic, (ta, wa) in ra.wrenches.items():
            if not (np.array_equal(ta, rb.wrenches[topic][0]) and np.array_equal(wa, rb.wrenches[topic][1])):
                problems.append(f"{name} {topic}: samples differ")
        for field in ("topics", "message_counts"):
            if getattr(ra, field) != getattr(rb, field):
                problems.append(f"{name}: {field} differ")
        if text({k: v.decode() for k, v in ra.attachments.items()}, a) != text(
                {k: v.decode() for k, v in rb.attachments.items()}, b):
            problems.append(f"{name}: attachments differ")
        if text(ra.json_records, a) != text(rb.json_records, b):
            problems.append(f"{name}: JSON records differ (apart from wall-clock fields)")
        if text(ra.log, a) != text(rb.log, b):
            problems.append(f"{name}: log messages differ")
    if text(json.loads((a / "summary.json").read_text()), a) != text(json.loads((b / "summary.json").read_text()), b):
        problems.append("summary.json differs (apart from wall times)")
    return problems


def _old_writer_module(tree: Path):
    """``oacli/io/mcap_write.py`` of the checkout ``tree`` as a module (with that checkout's ``jsonsafe``; the rest
    of oacli from this one)."""
    import importlib.util
    import sys

    def load(name: str, path: Path):
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
        return module

    jsonsafe = load("_other_jsonsafe", tree / "oacli" / "io" / "jsonsafe.py")
    writer = load("_other_mcap_write", tree / "oacli" / "io" / "mcap_write.py")
    writer.to_json_safe = jsonsafe.to_json_safe
    return writer


def _file_messages(path: Path) -> list[tuple]:
    """Every message of an MCAP in file order with its channel and schema (the payload as bytes)."""
    from mcap.reader import make_reader

    with path.open("rb") as f:
        return [(ch.topic, ch.message_encoding, dict(ch.metadata), schema.name if schema else None,
                 bytes(schema.data) if schema else None, msg.log_time, msg.publish_time, msg.sequence,
                 bytes(msg.data)) for schema, ch, msg in make_reader(f).iter_messages(log_time_order=False)]


def compare_mcap_writers(tree: Path, config: Path, repeats: int) -> None:
    """The stage MCAP writing of this checkout against ``tree`` on the same captured calls (module docstring)."""
    import bench_outputs

    from oacli.io import mcap_write

    other = _old_writer_module(tree.resolve())
    captured = [c for c in bench_outputs.CAPTURED if c[2] == "mcap"]
    saved, bench_outputs.CAPTURED[:] = list(bench_outputs.CAPTURED), captured
    out = Path(tempfile.mkdtemp(prefix="bench-mcap-writer-"))
    try:
        calls, _ = bench_outputs.capture_mission(config, out / "mission")
    finally:
        bench_outputs.CAPTURED[:] = saved
    sides = {"this": mcap_write, "other": other}
    cpu: dict[str, list[float]] = {"this": [], "other": []}
    for k in range(repeats):
        for name in (("this", "other") if k % 2 == 0 else ("other", "this")):
            folder = out / f"{name}-{k}"
            folder.mkdir()
            start = time.process_time()
            for i, (_, func, args, kwargs) in enumerate(calls):
                with sides[name].StageMcapWriter(folder / f"{i}.mcap", stage="bench", config_yaml="bench: 1\n",
                                                 time_ordered=True) as w:
                    func(w, *args[1:], **kwargs)
            cpu[name].append(time.process_time() - start)
    differ, messages = [], 0
    for path in sorted((out / "this-0").glob("*.mcap")):
        a, b = _file_messages(path), _file_messages(out / "other-0" / path.name)
        messages += len(a)
        if a != b:
            differ.append(path.name)
    sizes = {n: sum(f.stat().st_size for f in (out / f"{n}-0").glob("*.mcap")) / 1e6 for n in sides}
    print(f"stage MCAP topics of the default mission ({len(calls)} files, {messages} messages), this checkout vs "
          f"{tree}, {repeats} replays each, alternating, CPU [s]")
    for name in sides:
        print(f"  {name:<6} median {statistics.median(cpu[name]):6.3f}  min {min(cpu[name]):6.3f}  "
              f"({', '.join(f'{v:.2f}' for v in cpu[name])})  files {sizes[name]:.2f} MB")
    print("messages: " + ("equal, byte for byte" if not differ else "DIFFER in " + ", ".join(differ)))


def compare_trees(tree: Path, config: Path, missions: int) -> None:
    """This checkout against ``tree``: the default mission in fresh processes, alternating (module docstring)."""
    import subprocess
    import sys

    sides = {"this": ROOT, "other": tree.resolve()}
    rows: dict[str, list[dict]] = {name: [] for name in sides}
    out = Path(tempfile.mkdtemp(prefix="bench-overhead-"))
    print(f"default mission ({config.name}), this checkout vs {tree}, {missions} run(s) each, alternating; "
          f"fresh process each")
    print(f"{'run':<4} {'tree':<6} {'wall [s]':>9} {'cpu [s]':>8} {'overhead [s]':>13} {'excite [s]':>11} "
          f"{'overhead cpu':>13} {'excite cpu':>11}")
    for k in range(missions):
        for name in (("this", "other") if k % 2 == 0 else ("other", "this")):
            folder = out / f"{name}-{k}"
            env = {**os.environ, "PYTHONPATH": str(sides[name])}
            side_config = sides[name] / "configs" / config.name
            done = subprocess.run([sys.executable, __file__, "--child-mission", str(folder), "--config",
                                   str(side_config)],
                                  env=env, cwd=sides[name], capture_output=True, text=True, check=True)
            row = json.loads(done.stdout.strip().splitlines()[-1])
            rows[name].append(row)
            print(f"{k + 1:<4} {name:<6} {row['wall']:>9.2f} {row['cpu']:>8.2f} {row['overhead']:>13.3f} "
                  f"{row['stages']['segment-2/excite']:>11.3f} {row['overhead_cpu']:>13.3f} {row['excite_cpu']:>11.3f}",
                  flush=True)
    for key, label in (("overhead", "mission outputs and overhead"), ("excite", "segment-2/excite"),
                       ("overhead_cpu", "overhead, CPU (outside run_stage)"), ("excite_cpu", "segment-2/excite CPU"),
                       ("wall", "whole mission wall"), ("cpu", "whole mission CPU")):
        def value(row: dict, key: str = key) -> float:
            return row["stages"]["segment-2/excite"] if key == "excite" else row[key]
        this = statistics.median(value(r) for r in rows["this"])
        other = statistics.median(value(r) for r in rows["other"])
        print(f"median {label:30s}: this {this:7.3f} s, other {other:7.3f} s, other - this {other - this:+.3f} s")
    problems = same_missions(out / f"this-{missions - 1}", out / f"other-{missions - 1}")
    print("outputs of the last runs: " + ("the same (PNGs pixel for pixel, MCAP samples bit for bit, records and "
                                          "summaries apart from wall-clock fields)" if not problems
                                          else "; ".join(problems)))
    print(f"mission folders kept in {out}")


#: The rows' clock: wall time, or CPU time of this process with ``--cpu`` (steadier on a loaded machine).
CLOCK = time.perf_counter


def timed(fn: Callable[[], object]) -> float:
    start = CLOCK()
    fn()
    return CLOCK() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mission-dir", type=Path, help="a finished mission folder (default: run one first)")
    parser.add_argument("--config", type=Path, default=ROOT / "configs" / "mission_iss.yaml")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--missions", type=int, default=0,
                        help="also run the whole mission this many times per side (old paths / new), alternating, "
                             "and print its overhead: wall time minus the stages' own wall times")
    parser.add_argument("--cpu", action="store_true", help="time the rows in CPU time of this process")
    parser.add_argument("--compare-tree", type=Path, help="another oacli checkout to compare whole missions with")
    parser.add_argument("--mcap-writer", type=Path,
                        help="another oacli checkout: replay the stage MCAP writing into both writers (CPU)")
    parser.add_argument("--child-mission", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    global CLOCK
    if args.cpu:
        CLOCK = time.process_time
    if args.child_mission:
        child_mission(args.config, args.child_mission)
        return
    if args.mcap_writer:
        compare_mcap_writers(args.mcap_writer, args.config, args.repeats)
        return
    if args.compare_tree:
        compare_trees(args.compare_tree, args.config, max(args.missions, 1))
        return
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

    def old_reads() -> None:  # the file walks and every record through json.loads
        mcap_read.FAST_SAMPLES = False
        try:
            mission_reads(mission_dir, cfg, summary)
        finally:
            mcap_read.FAST_SAMPLES = True

    def remembered_reads() -> None:  # the stage files as the writers keep them during a mission
        with mcap_memo.remembering():
            for s in stages:
                mcap_memo.store(s.mcap(mission_dir), kept[s.key])
            mission_reads(mission_dir, cfg, summary)

    kept = {}
    if mcap_memo is not None:
        for s in stages:  # what each writer keeps (tests/test_mcap_memo.py: reads back equal to the file)
            scan = mcap_read._Scan(s.mcap(mission_dir), True, None)
            scan.run()
            kept[s.key] = mcap_memo.Written(
                messages={t: m for t, m in scan.messages.items()
                          if scan.topics[t] == "foxglove.Log" or next(
                              c.message_encoding for c in scan.channels.values() if c.topic == t) == "json"},
                metadata=scan.metadata, attachments=scan.attachments)
    rows: list[tuple[str, Callable[[], object], Callable[[], object] | None]] = [
        ("mission reads: files walked, json.loads vs one-pass decode", old_reads,
         lambda: mission_reads(mission_dir, cfg, summary)),
        ("mission reads: files walked (json.loads) vs kept in memory", old_reads, remembered_reads),
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
