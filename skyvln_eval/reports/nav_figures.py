"""Navigation figures: SR vs success threshold, NE distribution, a trajectory over its map.

The first two take a scores frame (:func:`skyvln_eval.metrics.score_results`), one line
per system. The map figure takes a :class:`~skyvln_eval.worlds.WorldTile` and view
arrays (``(K, 4, 2)`` ``[lat, lng]``) and draws them with the tile's georeference.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from skyvln_eval.errors import MetricInputError
from skyvln_eval.metrics.conventions import MetricConventions
from skyvln_eval.metrics.scoring import can_succeed
from skyvln_eval.reports.render import new_figure
from skyvln_eval.worlds.tile import WorldTile

if TYPE_CHECKING:  # matplotlib is imported when a figure is made (render.new_figure)
    from matplotlib.figure import Figure


def success_rate_curve(
    ne_m: NDArray[np.float64], thresholds_m: NDArray[np.float64], strict: bool
) -> NDArray[np.float64]:
    """Percent of episodes with NE under each threshold (``<`` if strict, else ``<=``)."""
    ne = np.sort(np.asarray(ne_m, dtype=np.float64))
    if len(ne) == 0:
        raise MetricInputError("no episodes for a success-rate curve")
    found = np.searchsorted(ne, np.asarray(thresholds_m), side="left" if strict else "right")
    return np.asarray(found, dtype=np.float64) / len(ne) * 100.0


def _systems(scores: pd.DataFrame, systems: Sequence[str] | None) -> list[str]:
    if scores.empty:
        raise MetricInputError("no scores to plot")
    names = list(systems) if systems else list(dict.fromkeys(scores["system"]))
    unknown = sorted(set(names) - set(scores["system"]))
    if unknown:
        raise MetricInputError(f"no scores for system(s) {unknown}")
    return names


def sr_vs_threshold_figure(
    scores: pd.DataFrame,
    conventions: MetricConventions,
    systems: Sequence[str] | None = None,
    max_threshold_m: float = 100.0,
) -> Figure:
    """R2R success rate as a function of the success radius, per system.

    Uses ``r2r_ne_m`` (2-D or 3-D as the conventions say); the conventions' threshold is
    marked. An episode that cannot succeed (:func:`~skyvln_eval.metrics.scoring.can_succeed`:
    an 'error', or no view) counts as a failure at every radius, as in the scores; a
    'degraded' one is scored on its views.
    """
    thresholds = np.linspace(0.0, max_threshold_m, 401)
    figure = new_figure(6.0, 4.0)
    ax = figure.subplots()
    for system in _systems(scores, systems):
        sel = scores[scores["system"] == system]
        ne = np.where(can_succeed(sel["status"], sel["n_views"] > 0), sel["r2r_ne_m"], np.inf)
        ax.plot(
            thresholds,
            success_rate_curve(ne, thresholds, conventions.strict_threshold),
            label=f"{system} (n={len(sel)})",
        )
    ax.axvline(
        conventions.threshold_m,
        color="0.4",
        ls="--",
        lw=0.8,
        label=f"d_th = {conventions.threshold_m:g} m",
    )
    ax.set_xlabel(f"success threshold (m, {conventions.distance.upper()} view centres)")
    ax.set_ylabel("success rate (%)")
    ax.set_ylim(0, 100)
    ax.grid(True, lw=0.3)
    ax.legend(fontsize="small")
    return figure


def ne_distribution_figure(
    scores: pd.DataFrame, systems: Sequence[str] | None = None, bins: int = 30
) -> Figure:
    """Histogram of the official NE (metres) per system, with each median marked."""
    names = _systems(scores, systems)
    top = float(scores["ne_m"].max()) or 1.0
    edges = np.linspace(0.0, top, bins + 1)
    figure = new_figure(6.0, 4.0)
    ax = figure.subplots()
    for k, system in enumerate(names):
        ne = scores.loc[scores["system"] == system, "ne_m"].to_numpy(np.float64)
        ax.hist(
            ne,
            bins=list(edges),
            histtype="step",
            lw=1.4,
            color=f"C{k}",
            label=f"{system} (median {np.median(ne):.1f} m)",
        )
        ax.axvline(float(np.median(ne)), color=f"C{k}", ls=":", lw=1.0)
    ax.set_xlabel("navigation error NE (m)")
    ax.set_ylabel("episodes")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize="small")
    return figure


def trajectory_figure(
    tile: WorldTile,
    gt_views: NDArray[np.float64],
    visited_views: NDArray[np.float64] | None = None,
    title: str = "",
    margin_px: int = 60,
) -> Figure:
    """The map around an episode with its GT views (yellow) and visited views (cyan).

    Centres are joined in order; the start is a white dot, the GT end a chequered flag
    marker. The image is cropped to the views plus ``margin_px``.
    """
    georef = tile.georef
    layers = [("ground truth", np.asarray(gt_views), "gold")]
    if visited_views is not None and len(visited_views):
        layers.append(("agent", np.asarray(visited_views), "cyan"))
    every = np.concatenate([views.reshape(-1, 2) for _, views, _ in layers])
    px = georef.gps_to_pixel_float(every)
    height, width = tile.shape
    x0, y0 = np.maximum(np.floor(px.min(axis=0)) - margin_px, 0).astype(int)
    x1, y1 = np.minimum(np.ceil(px.max(axis=0)) + margin_px, [width, height]).astype(int)
    figure = new_figure(6.0, 6.0 * max(1, y1 - y0) / max(1, x1 - x0))
    ax = figure.subplots()
    ax.imshow(tile.bgr[y0:y1, x0:x1, ::-1], extent=(x0, x1, y1, y0), interpolation="nearest")
    for name, views, colour in layers:
        pixels = georef.gps_to_pixel_float(views)
        for quad in pixels:
            ring = np.vstack([quad, quad[:1]])
            ax.plot(ring[:, 0], ring[:, 1], color=colour, lw=0.8, alpha=0.8)
        centres = pixels.mean(axis=1)
        ax.plot(centres[:, 0], centres[:, 1], color=colour, lw=1.8, marker="o", ms=3, label=name)
    start = georef.gps_to_pixel_float(np.asarray(gt_views)[0].mean(axis=0))
    goal = georef.gps_to_pixel_float(np.asarray(gt_views)[-1].mean(axis=0))
    ax.plot(*start, marker="o", ms=8, color="white", mec="black", ls="none", label="start")
    ax.plot(*goal, marker=(8, 2, 0), ms=12, color="black", mec="white", ls="none", label="GT end")
    ax.set_xlim(x0, x1)
    ax.set_ylim(y1, y0)
    ax.set_xlabel("x (px, resized map)")
    ax.set_ylabel("y (px)")
    ax.set_title(title or tile.map_name)
    ax.legend(fontsize="small", loc="upper right")
    return figure
