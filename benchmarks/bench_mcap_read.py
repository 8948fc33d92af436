"""Time :func:`oacli.io.mcap_read.read_stage` on MCAP files, optionally against another version of the reader.

Usage::

    taskset -c 1 python benchmarks/bench_mcap_read.py FILE.mcap [FILE.mcap ...] [--baseline OLD/mcap_read.py] [-n 5]

With ``--baseline`` the two readers alternate per repeat (same process, same page cache) and both must return the
same topics, message counts and truncation flag. Prints the median wall time of each per file.
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from oacli.io import mcap_read


def _load(path: Path):
    spec = importlib.util.spec_from_file_location("baseline_mcap_read", path)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules[spec.name] = module  # type: ignore[union-attr]
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+", type=Path)
    parser.add_argument("--baseline", type=Path, help="another mcap_read.py to compare with")
    parser.add_argument("-n", "--repeats", type=int, default=5)
    args = parser.parse_args()
    readers = {"this": mcap_read}
    if args.baseline is not None:
        readers["baseline"] = _load(args.baseline)
    for path in args.files:
        times: dict[str, list[float]] = {name: [] for name in readers}
        results = {}
        for _ in range(args.repeats):
            for name, module in readers.items():
                start = time.perf_counter()
                record = module.read_stage(path)
                times[name].append(time.perf_counter() - start)
                results[name] = (record.topics, record.message_counts, record.truncated)
        if len({repr(r) for r in results.values()}) != 1:
            raise SystemExit(f"{path}: the readers disagree")
        size = path.stat().st_size
        messages = sum(results["this"][1].values())
        row = "  ".join(f"{name} {statistics.median(t) * 1e3:8.1f} ms" for name, t in times.items())
        print(f"{path} ({size / 1e6:.2f} MB, {messages} messages): {row}")


if __name__ == "__main__":
    main()
