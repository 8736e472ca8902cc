"""Navigation figures over many episodes: SR vs success threshold and the NE distribution
(one episode over its map: :mod:`.trajectory_figure`).

Both take a scores frame (:func:`skyvln_eval.metrics.score_results`), one line
per system, each system in a colour and line style of its own. Their title names the
splits drawn: one panel pools them when every system ran the same splits; otherwise each
split has a panel, so that a system run on one split is never drawn beside others pooled
over three (its n would differ, unsaid).

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

import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from skyvln_eval.avdn.constants import SPLITS
from skyvln_eval.errors import MetricInputError, listed
from skyvln_eval.metrics.aggregate import oracle_systems
from skyvln_eval.metrics.conventions import MetricConventions
from skyvln_eval.metrics.scoring import can_succeed, crashed_flights, touched_obstacles
from skyvln_eval.reports.render import new_figure

if TYPE_CHECKING:  # matplotlib is imported when a figure is made (render.new_figure)
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

#: Oracle-flown systems are references: a line style of their own, not a rival's.
_REFERENCE_STYLE = "-."
#: An agent's line: matplotlib's ten cycle colours solid, then dashed, then dotted.
_COLOURS = 10
_DASHES = ("-", "--", ":")
#: The height of one legend line below the axes (small font), inches.
_LEGEND_LINE_IN = 0.2


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
    have = list(dict.fromkeys(scores["system"].astype(str)))
    names = list(dict.fromkeys(systems)) if systems else have
    unknown = [name for name in names if name not in set(have)]
    if unknown:
        raise MetricInputError(
            f"no scores for system(s) {listed(unknown)}; the scores have the systems {listed(have)}"
        )
    return names


def _ordered_splits(splits: Sequence[str]) -> list[str]:
    """The AVDN splits in their usual order (seen validation first), then any other."""
    known = [s for s in SPLITS if s in set(splits)]
    return known + [s for s in dict.fromkeys(splits) if s not in set(SPLITS)]


def _of_one_mode(scores: pd.DataFrame, mode: str | None) -> pd.DataFrame:
    """The episodes of ``mode``; without one, the scores' only mode. ANDH and ANDH-Full
    are different tasks whose episode ids overlap (a trajectory's first round): drawn as
    one line, a system's episodes were counted twice under one n."""
    have = sorted(set(scores["mode"].astype(str))) if "mode" in scores else []
    if mode is None:
        if len(have) > 1:
            raise MetricInputError(
                f"the scores hold episodes of the modes {listed(have)}, which are different "
                "tasks: choose one (--mode)"
            )
        return scores
    if mode not in have:
        raise MetricInputError(f"no scores of mode {mode!r}; the scores have {listed(have)}")
    return scores[scores["mode"] == mode]


def _names(given: object, what: str) -> list[str] | None:
    """``given`` (systems or splits) as a list of names; refused with what it is instead
    (``ne_distribution_figure(scores, conventions)`` had iterated the conventions)."""
    if given is None:
        return None
    if isinstance(given, str):
        raise MetricInputError(f"{what} must be a list of names: write [{given!r}]")
    names = list(given) if isinstance(given, Iterable) else None
    if names is None or not all(isinstance(n, str) for n in names):
        raise MetricInputError(f"{what} must be a list of names, got {type(given).__name__}")
    return names


def _selected(
    scores: pd.DataFrame,
    systems: Sequence[str] | None,
    splits: Sequence[str] | None,
    mode: str | None = None,
) -> tuple[pd.DataFrame, list[str]]:
    """The rows of ``mode`` (the scores' only one by default) and ``splits`` (all by
    default) and the systems to draw, in order; refuses a split or a named system that has
    no scores there, naming those there are. Without named systems, those with no scores
    on ``splits`` are left out, with a warning (a reproduction's Table II rows ran
    test_unseen only)."""
    systems, splits = _names(systems, "systems"), _names(splits, "splits")
    scores = _of_one_mode(scores, mode)
    names = _systems(scores, systems)
    scores = scores[scores["system"].isin(names)]
    if splits:
        have = _ordered_splits(list(scores["split"].astype(str)))
        unknown = [s for s in dict.fromkeys(splits) if s not in set(have)]
        if unknown:
            raise MetricInputError(
                f"no scores of split(s) {listed(unknown)}; these systems have {listed(have)}"
            )
        scores = scores[scores["split"].isin(list(splits))]
        absent = [n for n in names if n not in set(scores["system"])]
        if absent and systems:
            raise MetricInputError(
                f"system(s) {listed(absent)} have no scores on {listed(list(splits))}"
            )
        if absent:
            warnings.warn(
                f"left out: system(s) {listed(absent)}, which have no scores on "
                f"{listed(list(splits))}",
                UserWarning,
                stacklevel=3,
            )
            names = [n for n in names if n not in set(absent)]
    return scores, names


@dataclass(frozen=True)
class _Panel:
    """One axes of a figure: the episodes it draws and the title that says which."""

    scores: pd.DataFrame
    title: str


def _panels(scores: pd.DataFrame, names: Sequence[str]) -> list[_Panel]:
    """One panel pooling every split, when each system ran the same splits; else one per
    split: pooled, a system that ran one split would sit beside others' three-split means
    under a title saying all of them are pooled (an audit found Table II's test-only rows
    drawn so next to Table I's)."""
    ran = {
        name: tuple(_ordered_splits(list(scores.loc[scores["system"] == name, "split"])))
        for name in names
    }
    # ANDH-Full is said (one episode per whole trajectory); ANDH, the usual task, is not.
    kind = "ANDH-Full episodes" if set(scores.get("mode", ())) == {"andh-full"} else "episodes"
    if len(set(ran.values())) == 1:
        splits = next(iter(ran.values()))
        pooled = " pooled" if len(splits) > 1 else ""
        return [_Panel(scores, f"{kind} of {', '.join(splits)}{pooled}")]
    every = _ordered_splits(list(scores["split"].astype(str)))
    return [
        _Panel(
            scores[scores["split"] == split],
            f"{kind} of {split} (one panel per split: the systems ran different splits)",
        )
        for split in every
    ]


def _style(k: int, reference: bool) -> tuple[str, str]:
    """The colour and line style of the ``k``-th system, the same in every panel: the ten
    colours, then again dashed, then dotted (30 systems before two look alike); a
    reference (oracle) line is dash-dotted, a style no agent's line has."""
    colour = f"C{k % _COLOURS}"
    return colour, _REFERENCE_STYLE if reference else _DASHES[(k // _COLOURS) % len(_DASHES)]


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


def _system_rows(scores: pd.DataFrame, system: str, references: Sequence[str]) -> _SystemRows:
    sel = scores[scores["system"] == system]
    errors = int((sel["status"] == "error").sum())
    reference = system in references
    name = f"{system}, reference: ground-truth oracle" if reference else system
    return _SystemRows(sel, errors, name, reference)


def _name_only(ax: Axes, rows: _SystemRows, colour: str) -> None:
    """A legend entry with nothing drawn (a system whose episodes are all errors)."""
    ax.plot([], [], color=colour, ls="none", marker="x", label=rows.label_when_empty)


def _figure(panels: int, entries: int, axes_height_in: float) -> tuple[Figure, list[Axes]]:
    """A figure of ``panels`` axes side by side, tall enough for a legend of ``entries``
    lines below each (a fixed height clipped the axis label at 11 systems)."""
    figure = new_figure(6.0 * panels, axes_height_in + _LEGEND_LINE_IN * (entries + 1))
    axes = figure.subplots(1, panels, squeeze=False)[0]
    return figure, list(axes)


def _legend_below(ax: Axes) -> None:
    # Below the axes: inside, the legend of a few systems covers their curves.
    ax.legend(fontsize="small", loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=1)


def sr_vs_threshold_figure(
    scores: pd.DataFrame,
    conventions: MetricConventions,
    systems: Sequence[str] | None = None,
    max_threshold_m: float = 100.0,
    splits: Sequence[str] | None = None,
    mode: str | None = None,
) -> Figure:
    """R2R success rate as a function of the success radius, per system.

    Uses ``r2r_ne_m`` (2-D or 3-D as the conventions say); the conventions' threshold is
    marked. An episode that cannot succeed counts as a failure, as in the scores' SR: one
    that ended in error (the legend says how many; a system of errors only is named, not
    drawn as a 0% line) and, under the conventions' ``collision_fails``, one whose flight
    touched an obstacle (the legend says how many crashed); a 'degraded' episode is
    scored on its views.

    ``systems``, ``splits`` and ``mode`` choose what is drawn (all systems and splits;
    the scores' one mode, else ``mode`` must be given). When every system
    ran the same splits, one panel pools them and its title names them; otherwise there
    is one panel per split, each line one system's episodes of that split (its n in the
    legend). A system has one colour and line style in every panel, unlike any other's.
    """
    scores, names = _selected(scores, systems, splits, mode)
    panels = _panels(scores, names)
    references = oracle_systems(scores)
    thresholds = np.linspace(0.0, max_threshold_m, 401)
    figure, axes = _figure(len(panels), len(names) + 1, 4.0)
    for ax, panel in zip(axes, panels, strict=True):
        for k, system in enumerate(names):
            if system in set(panel.scores["system"]):
                _sr_line(ax, _system_rows(panel.scores, system, references), k, thresholds,
                         conventions)  # fmt: skip
        ax.axvline(
            conventions.threshold_m,
            color="0.4",
            ls="--",
            lw=0.8,
            label=f"d_th = {conventions.threshold_m:g} m",
        )
        ax.set_xlabel(f"success threshold (m, {conventions.distance.upper()} view centres)")
        ax.set_ylabel("R2R success rate (%):\nNE under the threshold")
        ax.set_title(panel.title, fontsize="small")
        ax.set_ylim(0, 100)
        ax.grid(True, lw=0.3)
        _legend_below(ax)
    return figure


def _sr_line(
    ax: Axes,
    rows: _SystemRows,
    k: int,
    thresholds: NDArray[np.float64],
    conventions: MetricConventions,
) -> None:
    """One system's SR curve (its legend entry only, if its episodes all ended in error)."""
    colour, style = _style(k, rows.reference)
    if rows.all_errors:
        _name_only(ax, rows, colour)
        return
    sel = rows.rows
    crashed = crashed_flights(sel, conventions)
    ne = np.where(can_succeed(sel["status"], sel["n_views"] > 0, crashed), sel["r2r_ne_m"], np.inf)
    plural = "s" if rows.errors > 1 else ""
    label = rows.counts(f"counted as failure{plural}" if plural else "counted as a failure")
    if crashed.any():
        label += f", {int(crashed.sum())} crashed (failures)"
    elif touched := int(touched_obstacles(sel).sum()):  # collision_fails off
        label += f", {touched} crashed (scored on their views)"
    ax.plot(
        thresholds,
        success_rate_curve(ne, thresholds, conventions.strict_threshold),
        color=colour,
        ls=style,
        label=f"{rows.name} ({label})",
    )


def ne_distribution_figure(
    scores: pd.DataFrame,
    systems: Sequence[str] | None = None,
    bins: int = 30,
    splits: Sequence[str] | None = None,
    mode: str | None = None,
) -> Figure:
    """Histogram of the official NE (metres) per system, with each median marked. An
    'error' episode counts where it stopped, as in the tables' NE (the legend counts
    them): leaving it out would flatter a system whose failures stop it far away. A
    system whose episodes all ended in error is named, not drawn (its table cell reads
    'error', not a number).

    ``systems`` and ``splits`` choose what is drawn, and the panels are made as
    :func:`sr_vs_threshold_figure` makes them: one pooling the splits, which its title
    names, when every system ran the same ones, else one per split. Every panel has the
    same bins."""
    scores, names = _selected(scores, systems, splits, mode)
    panels = _panels(scores, names)
    references = oracle_systems(scores)
    errors_only = {n for n in names if _system_rows(scores, n, references).all_errors}
    drawn = scores[~scores["system"].isin(errors_only)]["ne_m"].to_numpy(np.float64)
    top = float(drawn.max()) if len(drawn) else 0.0
    edges = np.linspace(0.0, top or 1.0, bins + 1)
    figure, axes = _figure(len(panels), len(names), 3.5)
    for ax, panel in zip(axes, panels, strict=True):
        for k, system in enumerate(names):
            if system in set(panel.scores["system"]):
                _ne_histogram(ax, _system_rows(panel.scores, system, references), k, edges)
        ax.set_xlabel("navigation error NE (m)")
        ax.set_ylabel("episodes")
        ax.set_title(panel.title, fontsize="small")
        ax.grid(True, lw=0.3)
        _legend_below(ax)
    return figure


def _ne_histogram(ax: Axes, rows: _SystemRows, k: int, edges: NDArray[np.float64]) -> None:
    """One system's NE histogram and median (its legend entry only, if its episodes all
    ended in error)."""
    colour, style = _style(k, rows.reference)
    if rows.all_errors:
        _name_only(ax, rows, colour)
        return
    ne = rows.rows["ne_m"].to_numpy(np.float64)
    median = float(np.median(ne))
    where = "at where it stopped" if rows.errors == 1 else "at where they stopped"
    ax.hist(
        ne,
        bins=list(edges),
        histtype="step",
        lw=1.4,
        ls=style,
        color=colour,
        label=f"{rows.name} ({rows.counts(where)}; median {median:.1f} m)",
    )
    ax.axvline(median, color=colour, ls=":", lw=1.0)
