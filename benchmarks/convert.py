"""Benchmark: convert the AVDN-sized synthetic val_unseen and test_unseen splits to MCAP.

Builds the full synthetic dataset (6,269 records) in the cache on first use. For each
split, in the same process: the baseline is loading the same records from JSON
(``json.load`` of the annotation file, and ``load_split``: decode + full validation),
best of N; then ``convert_split`` into a fresh folder (ANDH episodes, GT observations on,
``--workers`` processes, process start-up and map loading included), then the same
again as a re-run that verifies and skips every file. Prints episodes/s, output MB/s and
the ratios to the JSON baselines. Aim: at least 100 episodes/s with observations on 2 cores.

The machine's cores may be shared: the CPU seconds used by this process and its workers
are printed too, with the rate they imply on otherwise idle cores (episodes per CPU second
times the number of workers), so a busy machine does not hide the converter's own cost.

    python benchmarks/convert.py [--data-dir DIR] [--workers 2] [--repeat 3] [--no-observations]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from skyvln_eval.avdn import annotation_file_name, load_split
from skyvln_eval.converters import ConvertOptions, convert_split
from skyvln_eval.worlds.sample import ensure_dataset

# The sibling benchmark's timer (this script's folder is first on sys.path when it runs).
from load_split import best_of  # isort: skip

SPLITS = ("val_unseen", "test_unseen")


def cpu_seconds() -> float:
    """User + system time of this process and of its finished (joined) worker processes."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


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
    head = "{:<12} {:>8} {:>9} {:>10} {:>9} {:>6} {:>6} {:>7} {:>7} {:>7} {:>8}"
    print(
        head.format(
            "split", "episodes", "json.load", "load_split", "convert s",
            "ep/s", "MB/s", "x json", "x load", "CPU s", "rerun s",
        )
    )  # fmt: skip
    rows = [measure(data_dir, split, args.repeat, args.workers, options) for split in SPLITS]
    total = {key: sum(row[key] for row in rows) for key in rows[0] if key != "split"}
    for row in [*rows, {"split": "both", **total}]:
        print(head.format(*cells(row)))
    rate = total["episodes"] / total["convert"]
    print(
        f"{rate:.0f} episodes/s, {total['mb'] / total['convert']:.1f} MB/s of MCAP "
        f"({total['mb']:.0f} MB); conversion takes {total['convert'] / total['json']:.0f}x "
        f"json.load and {total['convert'] / total['load']:.1f}x load_split of the same records "
        f"(aim: >= 100 episodes/s with observations on 2 cores)"
    )
    per_cpu = total["episodes"] / total["cpu"]
    print(
        f"{per_cpu:.0f} episodes per CPU second (workers, start-up and map loading included): "
        f"{per_cpu * args.workers:.0f} episodes/s on {args.workers} otherwise idle cores"
    )


def measure(
    data_dir: Path, split: str, repeat: int, workers: int, options: ConvertOptions
) -> dict[str, Any]:
    """JSON baselines, then a conversion into a fresh folder and a re-run that skips."""
    path = data_dir / "annotations" / annotation_file_name(split)

    def plain() -> None:
        with path.open("rb") as handle:
            json.load(handle)

    t_json = best_of(repeat, plain)
    t_load = best_of(repeat, lambda: load_split(data_dir, split))
    out = Path(tempfile.mkdtemp(prefix="skyvln-convert-bench-"))
    try:
        start, cpu_start = time.perf_counter(), cpu_seconds()
        report = convert_split(data_dir, split, out, "andh", workers, options)
        t_convert = time.perf_counter() - start
        cpu = cpu_seconds() - cpu_start
        start = time.perf_counter()
        rerun = convert_split(data_dir, split, out, "andh", workers, options)
        t_rerun = time.perf_counter() - start
    finally:
        shutil.rmtree(out, ignore_errors=True)
    if report.failed or rerun.count("skipped") != len(report.rows):
        raise SystemExit(f"{split}: conversion failed or the re-run did not skip")
    return {
        "split": split,
        "episodes": len(report.rows),
        "json": t_json,
        "load": t_load,
        "convert": t_convert,
        "mb": sum(r.size_bytes for r in report.rows) / 1e6,
        "cpu": cpu,
        "rerun": t_rerun,
    }


def cells(row: dict[str, Any]) -> list[str]:
    t = row["convert"]
    return [
        row["split"], str(row["episodes"]), f"{row['json']:.3f}", f"{row['load']:.3f}",
        f"{t:.2f}", f"{row['episodes'] / t:.0f}", f"{row['mb'] / t:.1f}",
        f"{t / row['json']:.0f}", f"{t / row['load']:.1f}", f"{row['cpu']:.2f}",
        f"{row['rerun']:.2f}",
    ]  # fmt: skip


if __name__ == "__main__":
    main()
