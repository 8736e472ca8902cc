"""Small builders of views and results for the metric tests (hand-checkable geometry)."""

from __future__ import annotations

from typing import Any

import numpy as np

from skyvln_eval.avdn.constants import METERS_PER_DEGREE
from skyvln_eval.metrics import EpisodeResult

LAT0, LNG0 = 30.0, 40.0


def box(lat_lo: float, lat_hi: float, lng_lo: float, lng_hi: float) -> np.ndarray:
    """An axis-aligned view (north-up): FL, FR, BR, BL as ``[lat, lng]``."""
    return np.array([[lat_hi, lng_lo], [lat_hi, lng_hi], [lat_lo, lng_hi], [lat_lo, lng_lo]])


def square(north_m: float, east_m: float, edge_m: float = 40.0) -> np.ndarray:
    """A north-up square view centred ``north_m`` / ``east_m`` from (LAT0, LNG0)."""
    lat = LAT0 + north_m / METERS_PER_DEGREE
    lng = LNG0 + east_m / METERS_PER_DEGREE
    h = edge_m / 2.0 / METERS_PER_DEGREE
    return box(lat - h, lat + h, lng - h, lng + h)


def result(
    visited: Any,
    gt: Any,
    status: str = "ok",
    episode_id: str = "1913__0_1",
    system: str = "agent",
    split: str = "val_seen",
    **kwargs: Any,
) -> EpisodeResult:
    views = np.asarray(visited, dtype=np.float64).reshape(-1, 4, 2)
    if status == "error":
        kwargs.setdefault("error", "test error")
    kwargs.setdefault("mode", "andh")
    return EpisodeResult(
        episode_id=episode_id,
        split=split,
        system=system,
        status=status,  # type: ignore[arg-type]
        visited_views=views,
        gt_path_corners=np.asarray(gt, dtype=np.float64),
        **kwargs,
    )
