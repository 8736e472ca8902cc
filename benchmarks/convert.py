"""Benchmark: convert the AVDN-sized synthetic val_unseen and test_unseen splits to MCAP.

Builds the full synthetic dataset (6,269 records) in the cache on first use. For each
split, in the same process: the baseline is loading the same records from JSON
(``json.load`` of the annotation file, and ``load_split``: decode + full validation),
best of N; then ``convert_split`` into a fresh folder (ANDH episodes, GT observations on,
``--workers`` processes, process start-up and map loading included), then the same
again as a re-run that verifies and skips every file. Prints episodes/s, output MB/s and
the ratios to the JSON baselines. Aim: at least 100 episodes/s with observations on 2 cores.

    python benchmarks/convert.py [--data-dir DIR] [--workers 2] [--repeat 3] [--no-observations]
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from skyvln_eval.avdn import annotation_file_name, load_split
from skyvln_eval.converters import ConvertOptions, convert_split
from skyvln_eval.worlds.sample import ensure_dataset

SPLITS = ("val_unseen", "test_unseen")


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
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--no-observations", action="store_true")
    args = parser.parse_args()
    data_dir = args.data_dir or ensure_dataset("full", workers=args.workers)
    options = ConvertOptions(observations=not args.no_observations)
    print(f"dataset: {data_dir}")
    print(f"workers: {args.workers}, observations: {options.observations}")
    head = "{:<12} {:>8} {:>10} {:>9} {:>10} {:>8} {:>7} {:>10} {:>10} {:>9}"
    print(
        head.format(
            "split",
            "episodes",
            "json.load",
            "load_split",
            "convert s",
            "ep/s",
            "MB/s",
            "x json",
            "x load",
            "rerun s",
        )
    )
    totals = {"episodes": 0, "json": 0.0, "load": 0.0, "convert": 0.0, "rerun": 0.0, "mb": 0.0}
    for split in SPLITS:
        path = data_dir / "annotations" / annotation_file_name(split)

        def plain(path: Path = path) -> None:
            with path.open("rb") as handle:
                json.load(handle)

        t_json = best_of(args.repeat, plain)
        t_load = best_of(args.repeat, lambda split=split: load_split(data_dir, split))
        out = Path(tempfile.mkdtemp(prefix="skyvln-convert-bench-"))
        try:
            start = time.perf_counter()
            report = convert_split(data_dir, split, out, "andh", args.workers, options)
            t_convert = time.perf_counter() - start
            start = time.perf_counter()
            rerun = convert_split(data_dir, split, out, "andh", args.workers, options)
            t_rerun = time.perf_counter() - start
        finally:
            shutil.rmtree(out, ignore_errors=True)
        if report.failed or rerun.count("skipped") != len(report.rows):
            raise SystemExit(
                f"{split}: conversion failed or the re-run did not skip: {report.failed[:3]}"
            )
        episodes = len(report.rows)
        mb = sum(r.size_bytes for r in report.rows) / 1e6
        print(
            head.format(
                split,
                episodes,
                f"{t_json:.3f}",
                f"{t_load:.3f}",
                f"{t_convert:.2f}",
                f"{episodes / t_convert:.0f}",
                f"{mb / t_convert:.1f}",
                f"{t_convert / t_json:.0f}",
                f"{t_convert / t_load:.1f}",
                f"{t_rerun:.2f}",
            )
        )
        for key, value in (
            ("episodes", episodes),
            ("json", t_json),
            ("load", t_load),
            ("convert", t_convert),
            ("rerun", t_rerun),
            ("mb", mb),
        ):
            totals[key] += value
    rate = totals["episodes"] / totals["convert"]
    print(
        head.format(
            "both",
            int(totals["episodes"]),
            f"{totals['json']:.3f}",
            f"{totals['load']:.3f}",
            f"{totals['convert']:.2f}",
            f"{rate:.0f}",
            f"{totals['mb'] / totals['convert']:.1f}",
            f"{totals['convert'] / totals['json']:.0f}",
            f"{totals['convert'] / totals['load']:.1f}",
            f"{totals['rerun']:.2f}",
        )
    )
    print(
        f"{rate:.0f} episodes/s, {totals['mb'] / totals['convert']:.1f} MB/s of MCAP "
        f"({totals['mb']:.0f} MB); conversion takes {totals['convert'] / totals['json']:.0f}x "
        f"json.load and {totals['convert'] / totals['load']:.1f}x load_split of the same records "
        f"(aim: >= 100 episodes/s with observations on 2 cores)"
    )


if __name__ == "__main__":
    main()
