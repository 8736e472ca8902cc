"""Navigation figures: SR vs success threshold, NE distribution, a trajectory over its map.

The first two take a scores frame (:func:`skyvln_eval.metrics.score_results`), one line
per system. The map figure takes a :class:`~skyvln_eval.worlds.WorldTile` and view
arrays (``(K, 4, 2)`` ``[lat, lng]``) and draws them with the tile's georeference.

An ``error`` episode (it raised, or none of its LLM calls gave a usable answer) is drawn
as the tables score it, and the legend says so: the SR curve counts it as a failure
(``flaky (n=4, 1 error counted as a failure)``), as it does a flight that touched an
obstacle under the conventions' ``collision_fails`` (the default; ``…, 2 crashed
(failures)``); the NE histogram counts it at where it stopped (``flaky (n=4, 1 error at
where it stopped; median …)``); a system of errors only is named, not drawn.
``degraded`` episodes are drawn and counted in the legend. Systems the
ground-truth oracle flew are labelled as references
(:func:`~skyvln_eval.metrics.aggregate.oracle_systems`), dash-dotted.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from skyvln_eval.errors import MetricInputError
from skyvln_eval.metrics.aggregate import oracle_systems
from skyvln_eval.metrics.conventions import MetricConventions
from skyvln_eval.metrics.records import EpisodeResult
from skyvln_eval.metrics.scoring import can_succeed, crashed_flights, touched_obstacles
from skyvln_eval.reports.render import new_figure
from skyvln_eval.worlds.tile import WorldTile

if TYPE_CHECKING:  # matplotlib is imported when a figure is made (render.new_figure)
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

#: Oracle-flown systems are references: a line style of their own, not a rival's.
_REFERENCE_STYLE = "-."
#: How much of an error's first line a trajectory title shows.
_TITLE_ERROR_CHARS = 80


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


@dataclass(frozen=True)
class _SystemRows:
    """One system's episodes as a figure shows them, and its legend text."""

    rows: pd.DataFrame  # every episode, 'error' ones included
    errors: int  # how many of them ended in error
    name: str  # the system, marked as a reference if the oracle flew it
    reference: bool

    @property
    def all_errors(self) -> bool:
        return self.errors == len(self.rows)

    def counts(self, errors_are: str) -> str:
        """What the legend says the line or histogram is made of, e.g. "n=4, 1 degraded,
        1 error counted as a failure": ``errors_are`` says how the errors are shown."""
        parts = [f"n={len(self.rows)}"]
        degraded = int((self.rows["status"] == "degraded").sum())
        if degraded:
            parts.append(f"{degraded} degraded")
        if self.errors:
            plural = "s" if self.errors > 1 else ""
            parts.append(f"{self.errors} error{plural} {errors_are}")
        return ", ".join(parts)

    @property
    def label_when_empty(self) -> str:
        """The legend entry of a system whose episodes all ended in error."""
        return f"{self.name} ({self.errors} of {len(self.rows)} episodes error: not drawn)"

    @property
    def style(self) -> str:
        return _REFERENCE_STYLE if self.reference else "-"


def _system_rows(scores: pd.DataFrame, system: str, references: Sequence[str]) -> _SystemRows:
    sel = scores[scores["system"] == system]
    errors = int((sel["status"] == "error").sum())
    reference = system in references
    name = f"{system}, reference: ground-truth oracle" if reference else system
    return _SystemRows(sel, errors, name, reference)


def _name_only(ax: Axes, rows: _SystemRows, colour: str) -> None:
    """A legend entry with nothing drawn (a system whose episodes are all errors)."""
    ax.plot([], [], color=colour, ls="none", marker="x", label=rows.label_when_empty)


def sr_vs_threshold_figure(
    scores: pd.DataFrame,
    conventions: MetricConventions,
    systems: Sequence[str] | None = None,
    max_threshold_m: float = 100.0,
) -> Figure:
    """R2R success rate as a function of the success radius, per system.

    Uses ``r2r_ne_m`` (2-D or 3-D as the conventions say); the conventions' threshold is
    marked. An episode that cannot succeed counts as a failure, as in the scores' SR: one
    that ended in error (the legend says how many; a system of errors only is named, not
    drawn as a 0% line) and, under the conventions' ``collision_fails``, one whose flight
    touched an obstacle (the legend says how many crashed); a 'degraded' episode is
    scored on its views. The curve pools every split of the scores given.
    """
    thresholds = np.linspace(0.0, max_threshold_m, 401)
    figure = new_figure(6.0, 5.5)
    ax = figure.subplots()
    references = oracle_systems(scores)
    for k, system in enumerate(_systems(scores, systems)):
        rows = _system_rows(scores, system, references)
        if rows.all_errors:
            _name_only(ax, rows, f"C{k}")
            continue
        sel = rows.rows
        crashed = crashed_flights(sel, conventions)
        ne = np.where(
            can_succeed(sel["status"], sel["n_views"] > 0, crashed), sel["r2r_ne_m"], np.inf
        )
        plural = "s" if rows.errors > 1 else ""
        label = rows.counts(f"counted as failure{plural}" if plural else "counted as a failure")
        if crashed.any():
            label += f", {int(crashed.sum())} crashed (failures)"
        elif touched := int(touched_obstacles(sel).sum()):  # collision_fails off
            label += f", {touched} crashed (scored on their views)"
        ax.plot(
            thresholds,
            success_rate_curve(ne, thresholds, conventions.strict_threshold),
            color=f"C{k}",
            ls=rows.style,
            label=f"{rows.name} ({label})",
        )
    ax.axvline(
        conventions.threshold_m,
        color="0.4",
        ls="--",
        lw=0.8,
        label=f"d_th = {conventions.threshold_m:g} m",
    )
    ax.set_xlabel(f"success threshold (m, {conventions.distance.upper()} view centres)")
    splits = ", ".join(dict.fromkeys(scores["split"].astype(str)))
    ax.set_ylabel("R2R success rate (%): NE under the threshold")
    ax.set_title(f"episodes of {splits} pooled", fontsize="small")
    ax.set_ylim(0, 100)
    ax.grid(True, lw=0.3)
    # Below the axes: inside, the legend of a few systems covers their curves.
    ax.legend(fontsize="small", loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=1)
    return figure


def ne_distribution_figure(
    scores: pd.DataFrame, systems: Sequence[str] | None = None, bins: int = 30
) -> Figure:
    """Histogram of the official NE (metres) per system, with each median marked. An
    'error' episode counts where it stopped, as in the tables' NE (the legend counts
    them): leaving it out would flatter a system whose failures stop it far away. A
    system whose episodes all ended in error is named, not drawn (its table cell reads
    'error', not a number)."""
    references = oracle_systems(scores)
    every = [_system_rows(scores, system, references) for system in _systems(scores, systems)]
    drawn = [
        rows.rows["ne_m"].to_numpy(np.float64) if not rows.all_errors else np.empty(0)
        for rows in every
    ]
    top = max((float(ne.max()) for ne in drawn if len(ne)), default=0.0) or 1.0
    edges = np.linspace(0.0, top, bins + 1)
    figure = new_figure(6.0, 4.0)
    ax = figure.subplots()
    for k, (rows, ne) in enumerate(zip(every, drawn, strict=True)):
        if not len(ne):
            _name_only(ax, rows, f"C{k}")
            continue
        median = float(np.median(ne))
        where = "at where it stopped" if rows.errors == 1 else "at where they stopped"
        ax.hist(
            ne,
            bins=list(edges),
            histtype="step",
            lw=1.4,
            ls=rows.style,
            color=f"C{k}",
            label=f"{rows.name} ({rows.counts(where)}; median {median:.1f} m)",
        )
        ax.axvline(median, color=f"C{k}", ls=":", lw=1.0)
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
