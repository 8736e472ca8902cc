"""One episode over its map: ground-truth and flown views on the world tile's image.

:func:`trajectory_figure` takes a :class:`~skyvln_eval.worlds.WorldTile` and view arrays
(``(K, 4, 2)`` ``[lat, lng]``) and draws them with the tile's georeference;
:func:`trajectory_labels` gives a result row's title and legend label (its status unless
ok, an oracle flight labelled a reference).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.metrics.records import EpisodeResult
from skyvln_eval.reports.render import new_figure
from skyvln_eval.worlds.tile import WorldTile

if TYPE_CHECKING:  # matplotlib is imported when a figure is made (render.new_figure)
    from matplotlib.figure import Figure

#: How much of an error's first line a trajectory title shows.
_TITLE_ERROR_CHARS = 80


def trajectory_figure(
    tile: WorldTile,
    gt_views: NDArray[np.float64],
    visited_views: NDArray[np.float64] | None = None,
    title: str = "",
    margin_px: int = 60,
    agent_label: str = "agent",
) -> Figure:
    """The map around an episode with its GT views (yellow) and visited views (cyan).

    Centres are joined in order; the start is a white dot, the GT end a chequered flag
    marker. The image is cropped to the views plus ``margin_px``. ``agent_label`` names
    the visited views in the legend (:func:`trajectory_labels` for a result row).
    """
    georef = tile.georef
    layers = [("ground truth", np.asarray(gt_views), "gold")]
    if visited_views is not None and len(visited_views):
        layers.append((agent_label, np.asarray(visited_views), "cyan"))
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


def trajectory_labels(row: EpisodeResult) -> tuple[str, str]:
    """The title and the flown views' legend label of a trajectory figure of ``row``.

    The title says the episode's status unless ``ok`` (an 'error' episode with the first
    line of its error: what it flew is not a result); a run of the ground-truth oracle is
    labelled a reference.
    """
    title = f"{row.system}: {row.episode_id}"
    if row.status == "error":
        first = ((row.error or "").strip().splitlines() or ["no error text"])[0]
        if len(first) > _TITLE_ERROR_CHARS:
            first = first[: _TITLE_ERROR_CHARS - 3] + "..."
        title += f" — error: {first}"
    elif row.status != "ok":
        title += f" — {row.status}"
    oracle = row.extra.get("oracle") is True
    flown = "ground-truth oracle (reference)" if oracle else "agent"
    if row.status == "error":
        flown += ", until the error"
    return title, flown
