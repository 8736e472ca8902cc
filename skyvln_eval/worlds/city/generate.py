"""Generate one synthetic city tile: plan it, paint it, georeference it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skyvln_eval.worlds.city.layout import plan_city
from skyvln_eval.worlds.city.paint import Canvas, paint_plan
from skyvln_eval.worlds.city.plan import CityPlan

#: Bump when the generator's output changes for the same seed.
GENERATOR_VERSION = 1


@dataclass(frozen=True, eq=False)
class CityTile:
    """A painted city: its vector plan (metres) and rasters (flat frame, north up)."""

    seed: int
    plan: CityPlan
    canvas: Canvas
    metres_per_px: float


def generate_city(
    seed: int, width_m: float = 1000.0, height_m: float = 1000.0, metres_per_px: float = 0.4
) -> CityTile:
    """Plan and paint a tile; identical output for identical arguments."""
    rng = np.random.default_rng(np.random.SeedSequence([GENERATOR_VERSION, seed]))
    plan = plan_city(rng, width_m, height_m)
    canvas = paint_plan(plan, metres_per_px, rng)
    return CityTile(seed, plan, canvas, metres_per_px)
