"""Paper-style tables (SkyVLN Table I and Table II) as Markdown, LaTeX and CSV.

Input is a summary from :func:`skyvln_eval.metrics.summarise` (one row per system,
split, mode and metric, with optional ``ci_low`` / ``ci_high`` and the ``ci_method`` that
made them, which a table with intervals states in a note; a missing interval shows
``[n/a]``). Rows are the systems, labelled exactly as the results name them (a
rule-based backend is labelled so by the caller), in the order given. Column groups are
splits, each with a few metrics:

- :data:`TABLE_I`: Seen Validation / Unseen Validation / Unseen Testing x SPL, SR;
- :data:`TABLE_II`: Unseen Testing x SPL, SR, NE (rows are LLM backends).

In every column the best value is bold and the second best underlined (higher is better
except NE, errors, costs and times); ranks use the displayed (rounded) values, so tied
values share a mark, a column where every row shows the same value has no mark, and the
second best is marked only when it is not also the worst. Reference rows (an oracle) and
cells whose every episode ended in error are never ranked, and nothing is marked on a
split whose rows ran different numbers of episodes (a note says so).

A failure never reads as a score: a path metric's cell (SR, SPL, NE, ...) whose every
episode ended in error shows ``error``, not the 0 its episodes score as failures; one where
some did carries ``⋄`` and a note says how many (the health columns, Error/% and the like,
show their numbers); a split whose ground truth is withheld shows ``withheld``.
Every rendering carries the metric conventions and the notes: Markdown and LaTeX the same
caption (with what the marks mean) and footnotes (LaTeX's in a block under the tabular, and
the exact conventions as a comment), CSV as comment lines.
"""

from __future__ import annotations

import csv
import decimal
import io
import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass, replace

import pandas as pd

from skyvln_eval.errors import MetricInputError, listed
from skyvln_eval.metrics.aggregate import CI_METHODS, LOWER_IS_BETTER
from skyvln_eval.metrics.conventions import MetricConventions, check_conventions


@dataclass(frozen=True)
class TableSpec:
    """Shape of a table: column groups ``(split, title)`` and metrics ``(key, label)``;
    ``digits`` overrides the table's number of decimals for some metrics."""

    name: str
    row_header: str
    groups: tuple[tuple[str, str], ...]
    metrics: tuple[tuple[str, str], ...]
    caption: str
    label: str
    digits: tuple[tuple[str, int], ...] = ()

    def digits_of(self, metric: str, default: int) -> int:
        return dict(self.digits).get(metric, default)

    def over(self, *splits: str) -> TableSpec:
        """The same table over other splits (e.g. Table II, the paper's over the unseen
        test split, over ``val_seen``): one column group per split, in the order given."""
        unknown = [s for s in splits if s not in SPLIT_TITLES]
        if not splits or unknown:
            raise MetricInputError(
                f"{self.name}.over: splits must be some of {listed(list(SPLIT_TITLES))}, "
                f"got {listed(list(splits))}"
            )
        return replace(self, groups=tuple((s, SPLIT_TITLES[s]) for s in splits))


#: How the tables title each split.
SPLIT_TITLES = {
    "train": "Training",
    "val_seen": "Seen Validation",
    "val_unseen": "Unseen Validation",
    "test_unseen": "Unseen Testing",
}


TABLE_I = TableSpec(
    name="table1",
    row_header="Model",
    groups=tuple((s, SPLIT_TITLES[s]) for s in ("val_seen", "val_unseen", "test_unseen")),
    metrics=(("spl", "SPL/%"), ("success", "SR/%")),
    caption="Comparison on the validation and unseen test sets (AVDN-format data).",
    label="tab:results_systems",
)
TABLE_II = TableSpec(
    name="table2",
    row_header="LLM",
    groups=(("test_unseen", SPLIT_TITLES["test_unseen"]),),
    metrics=(
        ("spl", "SPL/%"),
        ("success", "SR/%"),
        ("ne_m", "NE/m"),
        ("fallback_rate", "Fallback/%"),
        ("llm_call_failure_rate", "Call fail/%"),
        ("status_degraded", "Degraded/%"),
        ("status_error", "Error/%"),
        ("llm_cost_usd", "Cost/$"),
        ("llm_latency_s", "LLM s"),
    ),
    caption=(
        "Ablation over LLM backends. Fallback: share of all decisions that used the "
        "fallback action; Call fail: share of all LLM calls with no answer after retries; "
        "Degraded: episodes where an "
        "answer could not be used (a fallback action, no sub-goals, ...); Error: episodes "
        "with no usable LLM answer or that raised; Cost and LLM s: per episode (n/a: unknown; "
        "an answer from the response cache counts the cost and time of the call that made it)."
    ),
    label="tab:results_backends",
    digits=(("llm_cost_usd", 4),),
)
TABLES = {spec.name: spec for spec in (TABLE_I, TABLE_II)}


@dataclass(frozen=True)
class Cell:
    mean: float
    ci_low: float | None = None
    ci_high: float | None = None
    rank: int | None = None  # 1 = best, 2 = second best, None = neither
    episodes: int = 0  # how many episodes the mean is over (0: not known)
    errors: int = 0  # how many of them ended in error (scored as failures)
    lower_bound: bool = False  # the mean is unknown; ``mean`` is a known lower bound of it
    ci_method: str = ""  # how the interval was made (a key of CI_METHODS)
    ci_draws: str = ""  # a bootstrap's resamples and seed ("1000 resamples, seed 0")
    trajectories: int = 0  # the units of a trajectory interval (0: not one, or not known)

    @property
    def all_errors(self) -> bool:
        """Every episode ended in error: the mean only repeats the failures' score."""
        return self.episodes > 0 and self.errors == self.episodes

    @property
    def shows_interval(self) -> bool:
        """The cell shows its interval (or '[n/a]') with its mean: it has one, and its
        mean is a number of its own (not 'error', 'n/a' or a lower bound)."""
        return self.ci_low is not None and not (
            self.all_errors or self.lower_bound or math.isnan(self.mean)
        )


#: The marker of a cell where some episodes ended in error.
SOME_ERRORS = "⋄"
#: What the marker and an 'error' cell mean.
ERRORS_MEANING = (
    f"{SOME_ERRORS} some episodes ended in error (no usable LLM answer, or the episode "
    "raised): they count as failures (0 in SR and SPL; NE as flown, to where they stopped); "
    "'error': every episode of the cell did."
)
#: Metrics shown as "≥ x" from a known lower bound (another summary metric) when their
#: mean is unknown: a backend's cost when only failed attempts have none.
LOWER_BOUNDS: dict[str, str] = {"llm_cost_usd": "llm_cost_lower_usd"}
AT_LEAST = "≥"
#: Summary metrics that say how many of a row's LLM calls were replayed from the cache.
CACHE_METRICS = ("llm_calls", "llm_cached_calls")
#: Columns that describe the run's health, not the agent's path: measured whatever the
#: episodes' status, so they always show their numbers (a dead endpoint's Error/% is 100).
HEALTH_METRICS = frozenset(
    {
        "status_ok",
        "status_degraded",
        "status_error",
        "fallback_rate",
        "llm_call_failure_rate",
        "llm_cost_usd",
        "llm_latency_s",
        "wall_s",
    }
)


@dataclass(frozen=True)
class Table:
    """A table ready to render: ``cells[row][(split, metric)]`` (None when not run)."""

    spec: TableSpec
    rows: tuple[str, ...]
    cells: dict[str, dict[tuple[str, str], Cell | None]]
    conventions: MetricConventions
    digits: int
    show_ci: bool
    notes: tuple[str, ...] = ()
    withheld: tuple[str, ...] = ()  # splits whose ground truth is withheld (not scored)

    @property
    def columns(self) -> list[tuple[str, str]]:
        return [(split, metric) for split, _ in self.spec.groups for metric, _ in self.spec.metrics]

    def digits_of(self, column: tuple[str, str]) -> int:
        return self.spec.digits_of(column[1], self.digits)

    def _repr_markdown_(self) -> str:
        """Jupyter shows a table as its Markdown (:func:`to_markdown`), notes included."""
        return to_markdown(self)


def fixed(value: float, digits: int) -> str:
    """``value`` with ``digits`` decimals, a half rounded away from zero, as a reader
    rounds (Python's rounding of the binary value showed 62.5 as 62 and 37.5 as 38 in one
    column); the value is taken as its shortest decimal repr."""
    if not math.isfinite(value):
        return f"{value:.{digits}f}"
    quantum = decimal.Decimal(1).scaleb(-digits)
    # repr of a Python float (numpy's scalars repr as "np.float64(...)").
    shown = decimal.Decimal(repr(float(value))).quantize(quantum, rounding=decimal.ROUND_HALF_UP)
    return f"{shown:f}" if shown else f"{abs(shown):f}"  # no "-0.00"


def nonzero_digits(value: float, digits: int) -> int:
    """``digits``, or more decimals (two significant digits, at most 8) for a value other
    than zero that ``digits`` would show as zero: a cost of $0.00004 per episode is not
    "0.0000", nor its known part "≥0.0000". A value that even 8 decimals show as zero (a
    rounding residue, e.g. the oracle's NE of 6e-10 m) keeps ``digits``: "0.00000000"
    would say no more than "0.00"."""
    if value == 0.0 or not math.isfinite(value) or fixed(value, digits).strip("-0."):
        return digits
    wanted = min(8, max(digits, 1 - math.floor(math.log10(abs(value)))))
    return wanted if fixed(value, wanted).strip("-0.") else digits


def nonzero_fixed(value: float, digits: int) -> str:
    """:func:`fixed` with the decimals of :func:`nonzero_digits`."""
    return fixed(value, nonzero_digits(value, digits))


def _ranks(values: dict[str, float], lower_is_better: bool, digits: int) -> dict[str, int]:
    """Best (1) and second best (2) by the shown values; no second when it is the worst."""
    # As the cells show them: a small value keeps the decimals that tell it from 0.
    shown = {row: float(nonzero_fixed(v, digits)) for row, v in values.items() if not math.isnan(v)}
    distinct = sorted(set(shown.values()), reverse=not lower_is_better)
    marked = 2 if len(distinct) > 2 else 1 if len(distinct) == 2 else 0
    return {row: distinct.index(v) + 1 for row, v in shown.items() if v in distinct[:marked]}


def build_table(
    summary: pd.DataFrame,
    spec: TableSpec,
    conventions: MetricConventions,
    rows: Sequence[str] | None = None,
    mode: str = "andh",
    digits: int = 2,
    show_ci: bool = False,
    notes: Sequence[str] = (),
    *,
    unranked: Collection[str] = (),
    withheld: Collection[str] = (),
) -> Table:
    """Arrange a summary into ``spec``'s shape. ``rows``: systems in order (default: all);
    ``notes``: footnotes every rendering carries (e.g. what a row marker means);
    ``unranked``: reference rows never marked best (an oracle); ``withheld``: splits whose
    ground truth is withheld, shown as such. Error counts come from the summary's
    ``status_error`` rows, where it has them."""
    check_conventions(summary, conventions, f"table {spec.name}")
    sel = summary[summary["mode"] == mode]
    if sel.empty:
        raise MetricInputError(f"the summary has no {mode!r} episodes")
    splits = [split for split, _ in spec.groups]
    if not set(splits) & (set(sel["split"]) | set(withheld)):  # a table of dashes
        raise MetricInputError(
            f"{spec.name} is over {listed(splits)}, and the scores have only "
            f"{listed(sorted(set(sel['split'].astype(str))))} (a spec's .over(split, ...) "
            "is the same table over other splits)"
        )
    if show_ci and "ci_low" not in sel.columns:
        raise MetricInputError("confidence intervals were asked for but the summary has none")
    if show_ci and "ci_method" not in sel.columns:
        # A table says how its intervals were made: a Wilson and a bootstrap one differ.
        raise MetricInputError(
            "the summary's intervals do not say how they were made (no ci_method column; "
            "summarise gives one)"
        )
    row_names = tuple(rows) if rows else tuple(dict.fromkeys(sel["system"]))
    unknown = [r for r in row_names if r not in set(sel["system"])]
    if unknown and not withheld:  # a row that ran only withheld splits has no scores
        raise MetricInputError(
            f"no scores for system(s) {listed(unknown)}; the scores have the systems "
            f"{listed(list(dict.fromkeys(sel['system'].astype(str))))}"
        )
    index = sel.set_index(["system", "split", "metric"])
    errors = _error_counts(index, row_names, [split for split, _ in spec.groups])
    cells: dict[str, dict[tuple[str, str], Cell | None]] = {r: {} for r in row_names}
    titles = dict(spec.groups)
    bounded: list[str] = []  # cells shown as a lower bound
    unmarked: dict[str, None] = {}  # splits whose ranked rows ran different episode counts
    for split, _ in spec.groups:
        for metric, _ in spec.metrics:
            present = {}
            for row in row_names:
                key = (row, split, metric)
                present[row] = index.loc[key] if key in index.index else None
            counts = {row: errors.get((row, split), (0, 0)) for row in row_names}
            # A path metric scores an error episode as a failure, so its cell says so; a
            # health metric measures it and shows its number. Neither is ranked for a row
            # whose every episode ended in error: a dead endpoint is not the "fastest".
            in_cell = {
                row: counts[row] if metric not in HEALTH_METRICS else (0, 0) for row in counts
            }
            means = {
                r: float(v["mean"])
                for r, v in present.items()
                if v is not None and r not in unranked and not 0 < counts[r][0] == counts[r][1]
            }
            ranks = _ranks(means, metric in LOWER_IS_BETTER, spec.digits_of(metric, digits))
            ran = {errors[(r, split)][0] for r in means if (r, split) in errors}
            if len(ran) > 1:  # not like with like: no marks
                ranks = {}
                unmarked.setdefault(titles[split], None)
            for row, v in present.items():
                if v is None:
                    cells[row][(split, metric)] = None
                    continue
                low = float(v["ci_low"]) if show_ci else None
                high = float(v["ci_high"]) if show_ci else None
                cell = Cell(float(v["mean"]), low, high, ranks.get(row), *in_cell[row])
                if show_ci:
                    cell = replace(cell, ci_method=str(v["ci_method"]), ci_draws=_draws(v))
                    units = v.get("n_trajectories", math.nan)
                    if not pd.isna(units):
                        cell = replace(cell, trajectories=int(units))
                bound = _summary_mean(index, (row, split, LOWER_BOUNDS.get(metric, "")))
                if math.isnan(cell.mean) and bound is not None:
                    # Never ranked: the true value is unknown (its CI too).
                    cell = replace(cell, mean=bound, rank=None, lower_bound=True)
                    bounded.append(f"{row} on {titles[split]}")
                cells[row][(split, metric)] = cell
    notes = [*notes, *_error_notes(errors, row_names, spec, titles)]
    notes += _episode_count_notes(errors, cells, row_names, spec)
    if unmarked:
        notes.append(
            f"No best or second marked on {', '.join(unmarked)}: its rows ran different "
            "numbers of episodes, so their values are not over the same episodes."
        )
    if {"llm_cost_usd", "llm_latency_s"} & set(dict(spec.metrics)):
        notes += _cached_notes(index, row_names, spec, titles)
    notes += _not_run_notes(cells, row_names, spec, titles, withheld)
    if bounded:
        notes.append(
            f"{AT_LEAST}: at least this much (its exact value is unknown, 'n/a' in the CSV): "
            "every answered call is priced, but some failed attempts reported no token count "
            f"and a provider may bill them: {'; '.join(bounded)}."
        )
    references = [r for r in row_names if r in unranked]
    if references:
        shown = ", ".join(references)
        notes.append(f"Not ranked (a reference, not a competitor): {shown}.")
    shown_withheld = tuple(split for split, _ in spec.groups if split in withheld)
    if shown_withheld:
        names = ", ".join(titles[split] for split in shown_withheld)
        notes.append(f"withheld: the ground truth of {names} is withheld, so it is not scored.")
    if show_ci:
        levels = sel.loc[sel["metric"].isin(dict(spec.metrics)), "confidence"].dropna()
        notes += _interval_notes(cells, row_names, spec, sorted(set(levels)))
    return Table(spec, row_names, cells, conventions, digits, show_ci, tuple(notes), shown_withheld)


def _summary_mean(index: pd.DataFrame, key: tuple[str, str, str]) -> float | None:
    """The summary's known mean at ``key`` (row, split, metric); None if it has none."""
    if key not in index.index:
        return None
    mean = float(index.loc[key]["mean"])
    return None if math.isnan(mean) else mean


def _draws(summary_row: pd.Series) -> str:
    """A bootstrap interval's resamples and seed, from its summary row ('' if unsaid)."""
    resamples, seed = summary_row.get("ci_resamples"), summary_row.get("ci_seed")
    if resamples is None or seed is None or pd.isna(resamples) or pd.isna(seed):
        return ""
    return f"{int(resamples)} resamples, seed {int(seed)}"


def _interval_notes(
    cells: dict[str, dict[tuple[str, str], Cell | None]],
    rows: Sequence[str],
    spec: TableSpec,
    levels: Sequence[float],
) -> list[str]:
    """How the shown intervals were made, naming the columns of each method, and what
    '[n/a]' means where a cell has none."""
    labels, titles = dict(spec.metrics), dict(spec.groups)
    # method -> column -> the cells (row on split) it made
    by_method: dict[str, dict[str, list[str]]] = {}
    unavailable = False
    units: set[int] = set()
    for row in rows:
        for (split, metric), cell in cells[row].items():
            if cell is None or not cell.shows_interval:
                continue
            if cell.trajectories:
                units.add(cell.trajectories)
            if cell.ci_low is not None and math.isnan(cell.ci_low):
                unavailable = True
                continue
            method = CI_METHODS.get(cell.ci_method, cell.ci_method) + (
                f", {cell.ci_draws}" if cell.ci_draws else ""
            )
            made = by_method.setdefault(method, {}).setdefault(labels[metric], [])
            made.append(f"{row} on {titles[split]}")
    if not by_method and not unavailable:
        return []
    level = ", ".join(f"{100.0 * c:g}%" for c in levels)
    parts = [
        f"{method}: {', '.join(_columns_made(column_cells, method, by_method))}"
        for method, column_cells in sorted(by_method.items())
    ]
    if units:  # few dialogs make a wide interval: say how few
        low, high = min(units), max(units)
        span = f"{low}" if low == high else f"{low} to {high}"
        parts.append(f"each over {span} trajector{'y' if high == 1 else 'ies'}")
    if unavailable:
        parts.append(
            "[n/a]: no interval (a bootstrap needs trajectories whose values differ, so none "
            "over one trajectory)"
            if units
            else "[n/a]: no interval (a bootstrap needs episodes whose values differ)"
        )
    return [f"Brackets: {level} intervals; {'; '.join(parts)}."]


def _columns_made(
    column_cells: dict[str, list[str]], method: str, by_method: dict[str, dict[str, list[str]]]
) -> list[str]:
    """The columns a method made intervals for; a column whose cells used several methods
    names the cells of each but its most common one (a reader cannot tell them apart)."""
    named = []
    for column, made in column_cells.items():
        counts = {m: len(c[column]) for m, c in by_method.items() if column in c}
        most = max(sorted(counts), key=lambda m: counts[m])  # ties: the first by name
        named.append(column if method == most else f"{column} ({', '.join(made)})")
    return named


def _not_run_notes(
    cells: dict[str, dict[tuple[str, str], Cell | None]],
    rows: Sequence[str],
    spec: TableSpec,
    titles: dict[str, str],
    withheld: Collection[str],
) -> list[str]:
    """What '-' means, when some row has no scores on a split: a split no row ran is
    named once, else the rows that did not run it."""
    not_run = []
    for split, title in spec.groups:
        missing = [
            row
            for row in rows
            if split not in withheld
            and all(cells[row][(split, m)] is None for m, _ in spec.metrics)
        ]
        if missing:
            not_run.append(
                title if len(missing) == len(rows) else f"{', '.join(missing)} on {title}"
            )
    return [f"-: no scores (no episode recorded): {'; '.join(not_run)}."] if not_run else []


def _error_counts(
    index: pd.DataFrame, rows: Sequence[str], splits: Sequence[str]
) -> dict[tuple[str, str], tuple[int, int]]:
    """Per (row, split) with a ``status_error`` summary row: (episodes, episodes in error)."""
    counts = {}
    for row in rows:
        for split in splits:
            key = (row, split, "status_error")
            if key in index.index:
                v = index.loc[key]
                n = int(v["n"])
                counts[(row, split)] = (n, round(float(v["mean"]) / 100.0 * n))
    return counts


def episodes(n: int) -> str:
    """``n`` episodes in words: "1 episode", "30 episodes"."""
    return f"{n} episode" + ("" if n == 1 else "s")


def _episode_count_notes(
    errors: dict[tuple[str, str], tuple[int, int]],
    cells: dict[str, dict[tuple[str, str], Cell | None]],
    rows: Sequence[str],
    spec: TableSpec,
) -> list[str]:
    """How many episodes each cell's mean is over, so a reader always knows n: one number
    when every cell has the same, else per split, naming the rows of a split that ran
    different numbers (their means are then over different episode sets). A cell whose
    count the summary does not give (no ``status_error`` row) is not described."""
    uniform: dict[str, int] = {}  # split title -> the one count of its cells
    differing: list[str] = []
    every_cell_counted = True
    for split, title in spec.groups:
        shown = [r for r in rows if any(cells[r][(split, m)] is not None for m, _ in spec.metrics)]
        counts = {row: errors[(row, split)][0] for row in shown if (row, split) in errors}
        every_cell_counted &= len(counts) == len(shown)
        if len(set(counts.values())) > 1:
            differing.append(f"{title}: " + ", ".join(f"{row} {n}" for row, n in counts.items()))
        elif counts and len(counts) == len(shown):
            uniform[title] = next(iter(counts.values()))
    if every_cell_counted and not differing and len(set(uniform.values())) == 1:
        return [f"Each cell: {episodes(next(iter(uniform.values())))}."]
    notes = []
    if uniform:
        shown_counts = "; ".join(f"{title} {n}" for title, n in uniform.items())
        notes.append(f"Episodes per cell: {shown_counts}.")
    if differing:
        notes.append(f"Rows ran different numbers of episodes: {'; '.join(differing)}.")
    return notes


def _cached_notes(
    index: pd.DataFrame, rows: Sequence[str], spec: TableSpec, titles: dict[str, str]
) -> list[str]:
    """How many of a row's LLM calls were answers replayed from the response cache: their
    cost and time are those of the call that made them, not paid or waited for again."""
    parts = []
    for row in rows:
        for split, _ in spec.groups:
            calls, cached = (_summary_mean(index, (row, split, metric)) for metric in CACHE_METRICS)
            if calls and cached:
                parts.append(f"{row} on {titles[split]}: {100.0 * cached / calls:.0f}%")
    return [cached_calls_note(parts, "their Cost and LLM s are those")] if parts else []


def cached_calls_note(parts: Sequence[str], counted: str) -> str:
    """The note on answers replayed from the response cache: ``parts`` their share of each
    row's calls ("sys on split: 40%"), ``counted`` the columns they count in ("their Cost
    is that"). Said by the tables and the score printout alike."""
    return (
        f"Replayed from the response cache ({counted} of the calls that made them; this run "
        f"neither paid nor waited for them): {'; '.join(parts)} of the LLM calls."
    )


def _error_notes(
    errors: dict[tuple[str, str], tuple[int, int]],
    rows: Sequence[str],
    spec: TableSpec,
    titles: dict[str, str],
) -> list[str]:
    """What ``error`` and ``‡`` mean, with the counts, when some cell has errors."""
    some = [
        f"{row} on {titles[split]} {failed} of {n}"
        for row in rows
        for split, _ in spec.groups
        for n, failed in [errors.get((row, split), (0, 0))]
        if failed
    ]
    if not some:
        return []
    return [f"{ERRORS_MEANING} Episodes that ended in error: {'; '.join(some)}."]


def _number(cell: Cell | None, digits: int, with_ci: bool, withheld: bool = False) -> str:
    if cell is None:
        return "withheld" if withheld else "-"
    if cell.all_errors:
        return "error"  # its episodes score as failures: a 0 here would read as a result
    if math.isnan(cell.mean):
        return "n/a"  # unknown (e.g. a cost without a price), never shown as a number
    if cell.lower_bound:
        return f"{AT_LEAST}{nonzero_fixed(cell.mean, digits)}" + (
            SOME_ERRORS if cell.errors else ""
        )
    text = nonzero_fixed(cell.mean, digits)
    if with_ci and cell.shows_interval:
        text += f" {_bracket(cell, digits)}"
    return text + (SOME_ERRORS if cell.errors else "")


def _bracket(cell: Cell, digits: int) -> str:
    """A cell's interval, ``[low, high]``, or ``[n/a]`` where it has none; with as many
    decimals as its value shows (``0.0019 [0.0012, 0.0031]``, not ``[0.00, 0.00]``)."""
    if cell.ci_low is None or cell.ci_high is None or math.isnan(cell.ci_low):
        return "[n/a]"
    digits = nonzero_digits(cell.mean, digits)
    return f"[{fixed(cell.ci_low, digits)}, {fixed(cell.ci_high, digits)}]"


def _arrow(metric: str) -> str:
    return "↓" if metric in LOWER_IS_BETTER else "↑"


def to_markdown(table: Table) -> str:
    spec = table.spec
    head = [spec.row_header] + [
        f"{title} {label} {_arrow(metric)}"
        for _, title in spec.groups
        for metric, label in spec.metrics
    ]
    lines = [
        "| " + " | ".join(head) + " |",
        "|" + "|".join([":---"] + ["---:"] * (len(head) - 1)) + "|",
    ]
    for row in table.rows:
        out = [row.replace("|", "\\|")]
        for column in table.columns:
            cell = table.cells[row][column]
            withheld = column[0] in table.withheld
            text = _number(cell, table.digits_of(column), table.show_ci, withheld)
            if cell is not None and cell.rank == 1:
                text = f"**{text}**"
            elif cell is not None and cell.rank == 2:
                text = f"<u>{text}</u>"
            out.append(text)
        lines.append("| " + " | ".join(out) + " |")
    lines += ["", f"{_caption(table)} {_conventions_note(table)}"]
    lines += ["", *table.notes] if table.notes else []
    return "\n".join(lines) + "\n"


#: What the marks of every rendering mean (bold and underline in Markdown and LaTeX).
RANK_MARKS = "Best in bold, second underlined."


def _caption(table: Table) -> str:
    """The caption every rendering carries: the table's and what its marks mean (when
    some cell is marked: a table of references alone ranks nothing)."""
    ranked = any(
        cell is not None and cell.rank is not None
        for row in table.cells.values()
        for cell in row.values()
    )
    return f"{table.spec.caption} {RANK_MARKS}" if ranked else table.spec.caption


def _conventions_note(table: Table) -> str:
    return f"Conventions: {table.conventions.describe()}."


_LATEX_SPECIALS = {"&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_", "{": r"\{",
                   "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}",
                   "\\": r"\textbackslash{}", SOME_ERRORS: r"$\diamond$",
                   AT_LEAST: r"$\geq$",
                   # Text-mode < and > print as other glyphs in LaTeX's default font encoding.
                   "<": r"$<$", ">": r"$>$"}  # fmt: skip


def latex_escape(text: str) -> str:
    return "".join(_LATEX_SPECIALS.get(ch, ch) for ch in text)


def to_latex(table: Table) -> str:
    """A booktabs ``table`` environment (needs the booktabs and multirow packages) with the
    Markdown's caption, and its conventions and notes in a footnote block under the tabular."""
    spec = table.spec
    n_metrics = len(spec.metrics)
    arrow = {"↑": r"$\uparrow$", "↓": r"$\downarrow$"}
    lines = [
        f"% generated by skyvln-eval; conventions: {table.conventions.to_json()}",
        r"% needs \usepackage{booktabs} and \usepackage{multirow}",
        r"\begin{table}[t]",
        r"\centering",
        f"\\caption{{{latex_escape(_caption(table))}}}",
        f"\\label{{{spec.label}}}",
        r"\begin{tabular}{l " + " ".join(["c" * n_metrics] * len(spec.groups)) + "}",
        r"\toprule",
        f"\\multirow{{2}}{{*}}{{\\textbf{{{latex_escape(spec.row_header)}}}}}"
        + "".join(
            f" & \\multicolumn{{{n_metrics}}}{{c}}{{\\textbf{{{latex_escape(t)}}}}}"
            for _, t in spec.groups
        )
        + r" \\",
        " ".join(
            f"\\cmidrule(lr){{{2 + g * n_metrics}-{1 + (g + 1) * n_metrics}}}"
            for g in range(len(spec.groups))
        ),
        "".join(
            f" & \\textbf{{{latex_escape(label)}}} {arrow[_arrow(metric)]}"
            for _ in spec.groups
            for metric, label in spec.metrics
        )
        + r" \\",
        r"\midrule",
    ]
    for row in table.rows:
        out = [latex_escape(row)]
        for column in table.columns:
            cell = table.cells[row][column]
            digits = table.digits_of(column)
            text = _number(cell, digits, False, column[0] in table.withheld)
            text = text.replace(SOME_ERRORS, r"$^\diamond$").replace(AT_LEAST, r"$\geq$")
            if cell is not None and cell.rank == 1:
                text = f"\\textbf{{{text}}}"
            elif cell is not None and cell.rank == 2:
                text = f"\\underline{{{text}}}"
            if table.show_ci and cell is not None and cell.shows_interval:
                text += f"\\,{{\\scriptsize{_bracket(cell, digits)}}}"
            out.append(text)
        lines.append(" & ".join(out) + r" \\")
    # The conventions and notes the Markdown carries, as a footnote block under the table
    # (a caption is for the list of tables, not for paragraphs of notes).
    notes = [_conventions_note(table), *table.notes]
    lines += [r"\bottomrule", r"\end{tabular}", r"\par\smallskip\footnotesize"]
    lines += [f"{latex_escape(note)}\\par" for note in notes]
    lines.append(r"\end{table}")
    return "\n".join(lines) + "\n"


def to_csv(table: Table) -> str:
    """One line per system: mean (and CI bounds) per split and metric, then per split the
    episodes scored and how many of them ended in error (what the other formats mark with
    the error marker: a script reading the CSV sees it too); conventions, each metric's
    label with its unit, and the notes first, as comment lines."""
    buffer = io.StringIO()
    buffer.write(f"# conventions: {table.conventions.to_json()}\n")
    # The units with the metrics: shares are percent here (fractions in scores.csv).
    labels = "; ".join(f"{metric} is {label}" for metric, label in table.spec.metrics)
    buffer.write(f"# columns: {labels}\n")
    for note in table.notes:
        buffer.write(f"# note: {note}\n")
    writer = csv.writer(buffer, lineterminator="\n")
    header = [table.spec.row_header]
    for split, metric in table.columns:
        header.append(f"{split}:{metric}")
        if table.show_ci:
            header += [f"{split}:{metric}:ci_low", f"{split}:{metric}:ci_high"]
    splits = list(dict.fromkeys(split for split, _ in table.columns))
    for split in splits:
        header += [f"{split}:episodes", f"{split}:error_episodes"]
    writer.writerow(header)
    for row in table.rows:
        out: list[str] = [row]
        for column in table.columns:
            cell = table.cells[row][column]
            if cell is None:
                out.append("withheld" if column[0] in table.withheld else "")
            elif cell.all_errors:
                out.append("error")
            else:  # unknown means (pandas reads "n/a" back as NaN), a lower bound's too
                unknown = math.isnan(cell.mean) or cell.lower_bound
                out.append("n/a" if unknown else repr(cell.mean))
            if table.show_ci:
                # A cell of errors only has no value: nor an interval (md and LaTeX show none).
                bounds = [] if cell is None or cell.all_errors else [cell.ci_low, cell.ci_high]
                out += [_csv_number(x) for x in bounds] or ["", ""]
        for split in splits:
            out += _episode_counts(table, row, split)
        writer.writerow(out)
    return buffer.getvalue()


def _episode_counts(table: Table, row: str, split: str) -> list[str]:
    """The episodes of ``row`` on ``split`` and those that ended in error, from its cells
    that count them (a health metric's do not); empty where no cell says."""
    counted = [
        cell
        for (cell_split, _), cell in table.cells[row].items()
        if cell_split == split and cell is not None and cell.episodes > 0
    ]
    if not counted:
        return ["", ""]
    return [str(counted[0].episodes), str(counted[0].errors)]


def _csv_number(value: float | None) -> str:
    """A number exactly (shortest repr), "n/a" when unknown (pandas reads it as NaN)."""
    return "n/a" if value is None or math.isnan(value) else repr(value)


RENDERERS = {"md": to_markdown, "latex": to_latex, "csv": to_csv}
