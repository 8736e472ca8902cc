"""Benchmark: time to generate a 1 km^2 synthetic city tile (plan + paint, 4 layers).

Prints per-tile times for a few seeds, split into planning and painting, and the ratio
to the 2 s budget; as a baseline in the same process, the time to allocate and fill the
four rasters of a tile of that size once (the floor any generator pays).

    python benchmarks/city_tile.py [--seeds 5] [--metres-per-px 0.4]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from skyvln_eval.worlds.city.generate import GENERATOR_VERSION
from skyvln_eval.worlds.city.layout import plan_city
from skyvln_eval.worlds.city.paint import paint_plan

BUDGET_S = 2.0


def _fill_rasters(side_px: int) -> float:
    """Seconds to allocate and fill a tile's four rasters. Filled with ``np.full``: the
    pages of ``np.zeros`` are mapped only when first written, so it would time nothing."""
    start = time.perf_counter()
    rasters = (
        np.full((side_px, side_px, 3), 128, np.uint8),
        np.full((side_px, side_px), 0, np.uint8),
        np.full((side_px, side_px), 0, np.uint16),
        np.full((side_px, side_px), 0.0, np.float32),
    )
    seconds = time.perf_counter() - start
    del rasters
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--metres-per-px", type=float, default=0.4)
    args = parser.parse_args()
    side_px = round(1000 / args.metres_per_px)
    baseline = min(_fill_rasters(side_px) for _ in range(3))
    print(f"tile 1000 m x 1000 m at {args.metres_per_px} m/px = {side_px} x {side_px} px")
    print(f"baseline (allocate and fill 4 rasters): {baseline * 1000:.1f} ms")
    totals = []
    for seed in range(args.seeds):
        rng = np.random.default_rng(np.random.SeedSequence([GENERATOR_VERSION, seed]))
        t0 = time.perf_counter()
        plan = plan_city(rng, 1000.0, 1000.0)
        t1 = time.perf_counter()
        paint_plan(plan, args.metres_per_px, rng)
        t2 = time.perf_counter()
        totals.append(t2 - t0)
        print(
            f"seed {seed}: plan {t1 - t0:.2f} s, paint {t2 - t1:.2f} s, total {t2 - t0:.2f} s "
            f"({len(plan.buildings)} buildings, {len(plan.trees)} trees, {len(plan.cars)} cars, "
            f"{len(plan.landmarks)} landmarks)"
        )
    mean = float(np.mean(totals))
    print(
        f"mean {mean:.2f} s per tile = {mean / BUDGET_S:.2f} x the {BUDGET_S:.0f} s budget, "
        f"{mean / baseline:.0f} x the raster baseline"
    )


if __name__ == "__main__":
    main()
