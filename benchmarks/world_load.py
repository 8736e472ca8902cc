"""Benchmark: loading an episode's world (map image and layers), decoded vs from the cache.

Every worker process of a run loads each map its episodes fly over. Prints, per map of the
AVDN-sized synthetic val_unseen, milliseconds to decode it without the cache (the TIFF, its
width resize and the three PNG layers: the baseline, what every process paid before the
decoded-map cache), the first load on a machine (decoded and stored) and a load from the
cache (memory-mapped ``.npy``), each in a fresh subprocess, as a worker meets the map; then
the ratio, also counting the time a mapped file's pages take to be read in when every pixel
is first read, and the cache's size on disk. The cache is a temporary folder, so the machine's
own is untouched.

    python benchmarks/world_load.py [--maps 10] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from skyvln_eval.avdn.loader import load_split
from skyvln_eval.harness.run import resolve_data_dir

# Run in a fresh interpreter: the time of one load_world call, and the arrays' checksum.
_CHILD = """
import json, sys, time, zlib
from skyvln_eval.avdn.loader import load_split
from skyvln_eval.worlds import load_world
import skyvln_eval.worlds.loading as loading
data_dir, split, map_name, use_cache = sys.argv[1:5]
if use_cache == "no":  # the baseline: decode, as every process did before the cache
    loading.decoded_rasters = lambda sources, recipe, decode, cache_dir=None: decode()
record = next(r for r in load_split(data_dir, split, check_map_images=False).records
              if r.map_name == map_name)
start = time.perf_counter()
world = load_world(data_dir, map_name, record.georef)
seconds = time.perf_counter() - start
start = time.perf_counter()
crc = 0
for array in (world.bgr, world.semantic, world.instance, world.height_m):
    crc = zlib.crc32(memoryview(array).cast("B"), crc)
first_read = time.perf_counter() - start
# Reading every pixel once more: a mapped file's pages are read on first use (above), so
# the first read's extra time is what the first read cost minus this.
start = time.perf_counter()
for array in (world.bgr, world.semantic, world.instance, world.height_m):
    zlib.crc32(memoryview(array).cast("B"))
again = time.perf_counter() - start
print(json.dumps({"seconds": seconds, "first_read": first_read - again, "crc": crc}))
"""


def load_once(
    data_dir: Path, split: str, map_name: str, cache: Path, use_cache: bool = True
) -> dict[str, float]:
    env = {**os.environ, "SKYVLN_EVAL_CACHE": str(cache)}
    flag = "yes" if use_cache else "no"
    done = subprocess.run(
        [sys.executable, "-c", _CHILD, str(data_dir), split, map_name, flag],
        env=env,
        check=True,
        capture_output=True,
        text=True,
    )
    result: dict[str, float] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--maps", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    data_dir = resolve_data_dir("full")
    split = "val_unseen"
    maps = sorted({r.map_name for r in load_split(data_dir, split).records})[: args.maps]
    decode_ms, first_ms, cached_ms, paging_ms = [], [], [], []
    with tempfile.TemporaryDirectory(prefix="bench-world-load-") as folder:
        for map_name in maps:
            decoded, stored, opened, paging = [], [], [], []
            for k in range(args.repeats):
                cache = Path(folder) / f"{map_name}-{k}"
                plain = load_once(data_dir, split, map_name, cache, use_cache=False)
                first = load_once(data_dir, split, map_name, cache)  # decodes and stores
                second = load_once(data_dir, split, map_name, cache)  # opens the store
                if not plain["crc"] == first["crc"] == second["crc"]:
                    raise SystemExit(f"map {map_name}: the cached arrays differ from the decoded")
                decoded.append(1e3 * plain["seconds"])
                stored.append(1e3 * first["seconds"])
                opened.append(1e3 * second["seconds"])
                # A difference of two noisy differences: below zero it measured only noise.
                paging.append(max(0.0, 1e3 * (second["first_read"] - plain["first_read"])))
            decode_ms.append(statistics.median(decoded))
            first_ms.append(statistics.median(stored))
            cached_ms.append(statistics.median(opened))
            paging_ms.append(statistics.median(paging))
            print(
                f"map {map_name}: decode {decode_ms[-1]:6.1f} ms, first load (decode and "
                f"store) {first_ms[-1]:6.1f} ms, from the cache {cached_ms[-1]:5.1f} ms (+ "
                f"{paging_ms[-1]:.1f} ms of paging in on the first read of every pixel)"
            )
        entry = next(p for p in Path(folder).iterdir()) / "decoded-maps"
        size_mb = sum(p.stat().st_size for p in entry.rglob("*") if p.is_file()) / 1e6
    decode, cached = statistics.mean(decode_ms), statistics.mean(cached_ms)
    paged = statistics.mean(paging_ms)
    print(
        f"{len(maps)} maps of {split}: decode {decode:.1f} ms per map (baseline), first load "
        f"{statistics.mean(first_ms):.1f} ms, from the cache {cached:.1f} ms -> "
        f"{decode / cached:.0f}x, or {decode / (cached + paged):.1f}x counting the paging in "
        f"of every pixel; {size_mb:.0f} MB on disk per map; arrays identical"
    )


if __name__ == "__main__":
    main()
