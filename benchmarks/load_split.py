"""Benchmark: load and validate the AVDN-sized synthetic splits vs plain ``json.load``.

Builds the full synthetic dataset (6,269 records) in the cache on first use, then for
each split times ``json.load`` of the annotation file and ``load_split`` (decode, full
validation, typed records, map image checks) in the same process, best of N runs.
Aim: load_split under 3x json.load.

    python benchmarks/load_split.py [--data-dir DIR] [--repeat 5] [--workers 2]
"""

from __future__ import annotations

import argparse
import functools
import json
import time
from collections.abc import Callable
from pathlib import Path

from skyvln_eval.avdn import SPLITS, annotation_file_name, load_split
from skyvln_eval.worlds.sample import ensure_dataset


def best_of(repeat: int, fn: Callable[[], object]) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    data_dir = args.data_dir or ensure_dataset("full", workers=args.workers)
    print(f"dataset: {data_dir}")
    row = "{:<12} {:>8} {:>6} {:>12} {:>13} {:>6}"
    print(row.format("split", "records", "MB", "json.load s", "load_split s", "ratio"))
    total_json = total_load = 0.0
    for split in SPLITS:
        path = data_dir / "annotations" / annotation_file_name(split)

        def plain(path: Path = path) -> None:
            with path.open("rb") as handle:
                json.load(handle)

        t_json = best_of(args.repeat, plain)
        t_load = best_of(args.repeat, functools.partial(load_split, data_dir, split))
        records = len(load_split(data_dir, split).records)
        total_json += t_json
        total_load += t_load
        size = f"{path.stat().st_size / 1e6:.1f}"
        print(
            row.format(
                split, records, size, f"{t_json:.3f}", f"{t_load:.3f}", f"{t_load / t_json:.2f}"
            )
        )
    ratio = total_load / total_json
    print(row.format("all", "", "", f"{total_json:.3f}", f"{total_load:.3f}", f"{ratio:.2f}"))
    print(f"load_split / json.load = {ratio:.2f}x (aim: under 3x)")


if __name__ == "__main__":
    main()
