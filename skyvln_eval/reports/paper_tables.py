"""Table I and Table II from per-episode scores: the one way every caller makes them.

`reproduce`, `skyvln-eval table` and the notebooks all call :func:`paper_table`, so the
same scores give the same cells and notes wherever they are rendered: error cells and
their counts, unknown costs shown as lower bounds, references never ranked (systems the
ground-truth oracle flew; in Table II also the stand-ins, which are what the models are
measured against), Table I rows answered by a stand-in marked with a footnote, rows the
oracle flew labelled "(oracle)" whatever their system is called, and the share of
answers replayed from the response cache.

The scores say all of that themselves: ``status`` for errors, ``oracle`` for the oracle,
``llm_backend`` for what answered the LLM calls (empty in files scored before it was
recorded: such rows are taken as they are labelled).
"""

from __future__ import annotations

from collections.abc import Collection, Sequence

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from skyvln_eval.errors import MetricInputError
from skyvln_eval.metrics import summarise
from skyvln_eval.metrics.aggregate import CiUnit, oracle_systems
from skyvln_eval.metrics.conventions import MetricConventions
from skyvln_eval.metrics.scoring import touched_obstacles
from skyvln_eval.reports.tables import (
    CACHE_METRICS,
    LOWER_BOUNDS,
    TABLE_I,
    Table,
    TableSpec,
    build_table,
)

#: Row markers (both tables) for systems whose LLM modules a stand-in answered.
STAND_IN_MARKERS = {
    "rule": (
        "†",
        "† LLM modules answered by the rule-based stand-in (not an LLM). On the synthetic "
        "sample it was developed with the train and validation splits' phrasings; only "
        "test_unseen's are held out from it.",
    ),
    "random": ("‡", "‡ LLM modules answered at random (not an LLM)."),
    "scripted": ("§", "§ LLM modules answered by a script (a test double)."),
    "task-data": (
        "¶",
        "¶ the server was sent each request's task data (a test set-up: a test server "
        "answers from it as the rule-based stand-in does), so not a model's answers.",
    ),
}


#: What a row the ground-truth oracle flew says of itself, and its footnote.
ORACLE_MARK = "(oracle)"
ORACLE_NOTE = (
    "(oracle): run by the harness's ground-truth oracle, which follows the annotated "
    "route: a reference, not an agent's result."
)


def oracle_label(system: str) -> str:
    """How a system the oracle flew is shown: marked, unless its name already carries the
    mark (a name that only contains the word, "Non-oracle planner", is marked)."""
    return system if ORACLE_MARK in system.lower() else f"{system} {ORACLE_MARK}"


def stand_in_kind(backend: str | None) -> str | None:
    """The kind of stand-in (a key of :data:`STAND_IN_MARKERS`) a backend spec names, or
    ``None`` for a model (or no backend)."""
    if not backend:
        return None
    kind = backend.partition(":")[0]
    return kind if kind in STAND_IN_MARKERS else None


def stand_in_systems(scores: pd.DataFrame) -> dict[str, str]:
    """The systems of ``scores`` whose LLM calls a stand-in answered, with its kind."""
    if "llm_backend" not in scores.columns:
        return {}
    kinds: dict[str, str] = {}
    for system, backend in scores[["system", "llm_backend"]].dropna().itertuples(index=False):
        kind = stand_in_kind(str(backend))
        if kind is not None:
            kinds.setdefault(str(system), kind)
    return kinds


def model_label(label: str, backend: str) -> str:
    """A Table I row label that names the real model that answered its LLM calls
    (``Full (openai:gpt-4o)``), unless the label already names it."""
    model = backend.partition(":")[2] or backend
    return label if model.split(":")[-1] in label else f"{label} ({backend})"


def model_systems(scores: pd.DataFrame) -> dict[str, str]:
    """The systems of ``scores`` whose LLM calls a real model answered, with its backend."""
    if "llm_backend" not in scores.columns:
        return {}
    backends: dict[str, str] = {}
    for system, backend in scores[["system", "llm_backend"]].dropna().itertuples(index=False):
        if str(backend) and stand_in_kind(str(backend)) is None:
            backends.setdefault(str(system), str(backend))
    return backends


def table_metrics(spec: TableSpec) -> list[str]:
    """The summary metrics ``spec`` reads: its columns, ``status_error`` (cells whose
    episodes ended in error), the lower bounds of unknown costs and, for a table with
    LLM columns, the calls answered from the cache."""
    columns = [metric for metric, _ in spec.metrics]
    bounds = [LOWER_BOUNDS[m] for m in columns if m in LOWER_BOUNDS]
    cache = list(CACHE_METRICS) if set(columns) & {"llm_cost_usd", "llm_latency_s"} else []
    return list(dict.fromkeys([*columns, "status_error", *bounds, *cache]))


def paper_table(
    scores: pd.DataFrame,
    spec: TableSpec,
    conventions: MetricConventions,
    *,
    summary: pd.DataFrame | None = None,
    rows: Sequence[str] | None = None,
    notes: Sequence[str] = (),
    mode: str = "andh",
    digits: int = 2,
    show_ci: bool = False,
    resamples: int = 1000,
    seed: int = 0,
    withheld: Collection[str] = (),
    ci_unit: CiUnit = "trajectory",
) -> Table:
    """``spec`` (:data:`TABLE_I` or :data:`TABLE_II`) from ``scores``.

    ``summary``: a summary of ``scores`` already made (with :func:`table_metrics` among
    its metrics, and intervals when ``show_ci``); else one is made here (``resamples``
    bootstrap resamples with ``seed`` when ``show_ci``, resampling episodes or whole
    trajectories: ``ci_unit``, see :func:`summarise`). ``rows``: systems in order
    (default: all of ``mode``, in the order the scores list them); ``notes``: footnotes
    of the caller's; ``withheld``: splits whose ground truth is withheld. Rows are
    labelled by what answered their LLM calls: a stand-in's marker, or, in Table I, the
    real model's backend unless the label names it (``rows`` may give either label).
    """
    stand_ins = stand_in_systems(scores)
    oracles = oracle_systems(scores)
    # Table I compares systems: a row on a real model says which (Table II's rows are
    # the models).
    models = model_systems(scores) if spec.name == TABLE_I.name else {}
    labels = {
        **{s: named for s, b in models.items() if (named := model_label(s, b)) != s},
        **marked_labels(stand_ins),
        **{o: oracle_label(o) for o in oracles if oracle_label(o) != o},
    }
    systems = set(scores["system"])
    clashes = {old: new for old, new in labels.items() if new in systems}
    if clashes:  # two systems would become one row, their episodes pooled
        old, new = next(iter(clashes.items()))
        why = (
            "the ground-truth oracle flew it"
            if old in oracles
            else "it ran on a stand-in"
            if old in stand_ins
            else "it names its model"
        )
        raise MetricInputError(
            f"system {old!r} would be shown as {new!r} ({why}), the label of another "
            "system in these scores: their episodes would be pooled in one row. Give one "
            "of the runs another system label"
        )
    if labels:
        scores = scores.assign(system=scores["system"].replace(labels))
        if summary is not None:
            summary = summary.assign(system=summary["system"].replace(labels))
        rows = None if rows is None else [labels.get(r, r) for r in rows]
    if rows is None:  # every system of the mode, in the order the scores list them
        rows = list(dict.fromkeys(scores.loc[scores["mode"] == mode, "system"])) or None
    if summary is None:
        metrics = [m for m in table_metrics(spec) if m in scores.columns]
        summary = summarise(  # the table shows the errors: no warning
            scores,
            metrics,
            resamples if show_ci else 0,
            seed=seed,
            ci_unit=ci_unit,
            warn_errors=False,
        )
    shown_labels = {system: labels.get(system, system) for system in stand_ins}
    references = set(oracle_systems(scores))
    if spec.name != TABLE_I.name:  # Table II, over whichever splits
        # The reference the models are measured against, under the label it is shown by.
        references |= set(shown_labels.values())
    marker_notes = [
        STAND_IN_MARKERS[kind][1]
        for system, kind in stand_ins.items()
        if (rows is None or shown_labels[system] in rows)
        and STAND_IN_MARKERS[kind][0] in shown_labels[system]
    ]
    if any(labels.get(o, o) in (rows or ()) for o in oracles):
        marker_notes.append(ORACLE_NOTE)
    shown = rows if rows is not None else []
    asked = _questions_note(scores, shown, spec, mode)
    crashes = _crashes_note(scores, shown, spec, mode, conventions)
    degraded = _degraded_note(scores, shown, spec, mode)
    detector = _detector_note(scores, shown, spec, mode)
    return build_table(
        summary,
        spec,
        conventions,
        rows,
        mode,
        digits,
        show_ci,
        list(
            dict.fromkeys(
                [*notes, *sorted(set(marker_notes)), *detector, *crashes, *degraded, *asked]
            )
        ),
        unranked=references,
        withheld=withheld,
    )


def _questions_note(
    scores: pd.DataFrame, rows: Sequence[str], spec: TableSpec, mode: str
) -> list[str]:
    """Which rows the simulated commander (who knows the goal) answered and how often: help
    the other rows did not get, which their differences include. A question it did not
    answer (``max_questions`` spent, or 0) was no help and is not counted."""
    column = next((c for c in ("questions_answered", "questions_asked") if c in scores), None)
    if column is None:
        return []
    splits = [split for split, _ in spec.groups]
    sel = scores[scores["split"].isin(splits) & (scores["mode"] == mode)]
    parts = []
    for row in rows:
        answered = sel.loc[sel["system"] == row, column].dropna()
        if len(answered) and answered.sum() > 0:
            parts.append(
                f"{row} {int(answered.sum())} in {int((answered > 0).sum())} of "
                f"{len(answered)} episodes"
            )
    if not parts:
        return []
    what = "answered by" if column == "questions_answered" else "asked of"
    return [
        f"Questions {what} the simulated commander, who knows the goal (help the other "
        f"rows did not get): {'; '.join(parts)}."
    ]


def _shown_cells(scores: pd.DataFrame, spec: TableSpec, mode: str) -> pd.DataFrame:
    """The scores of ``spec``'s splits in ``mode``."""
    return scores[scores["split"].isin(dict(spec.groups)) & (scores["mode"] == mode)]


def _flagged_per_cell(
    sel: pd.DataFrame, flagged: NDArray[np.bool_], rows: Sequence[str], spec: TableSpec
) -> list[str]:
    """``"<row> on <split title> k of n"`` for each cell with ``k`` flagged episodes."""
    parts = []
    for row in rows:
        for split, title in spec.groups:
            cell = ((sel["system"] == row) & (sel["split"] == split)).to_numpy(bool)
            count = int(flagged[cell].sum())
            if count:
                parts.append(f"{row} on {title} {count} of {int(cell.sum())}")
    return parts


#: What a row whose landmarks the ``simulated`` detector found rests on, said in the tables:
#: it reads the simulator's segmentation of the landmarks, not pixels.
SIMULATED_DETECTOR_NOTE = (
    "Landmarks found by the simulated detector: the simulator's segmentation of the "
    "landmarks with their true categories, colours measured in the pixels, and seeded "
    "misses, false positives and wrong labels; not a detector on pixels"
)


def _detector_note(
    scores: pd.DataFrame, rows: Sequence[str], spec: TableSpec, mode: str
) -> list[str]:
    """Which rows found their landmarks with the ``simulated`` detector: their numbers
    rest on it as much as on the agent (a detector on pixels, ``grounding_dino``, finds
    fewer and worse)."""
    if "detector" not in scores.columns:
        return []
    sel = _shown_cells(scores, spec, mode)
    simulated = sel.loc[sel["detector"] == "simulated", "system"]
    named = [row for row in rows if row in set(simulated)]
    notes = [f"{SIMULATED_DETECTOR_NOTE} ({', '.join(named)})."] if named else []
    # A detector on pixels, by its weights: a random or another checkpoint is not this one.
    on_pixels = sel.loc[sel["detector"].fillna("").str.startswith("grounding_dino:")]
    for detector, group in on_pixels.groupby("detector", sort=True):
        shown = [row for row in rows if row in set(group["system"])]
        if shown:
            model = str(detector).split(":", 1)[1]
            notes.append(
                f"Landmarks found on the camera's RGB pixels by GroundingDINO, weights "
                f"{model} ({', '.join(shown)})."
            )
    return notes


def _degraded_note(
    scores: pd.DataFrame, rows: Sequence[str], spec: TableSpec, mode: str
) -> list[str]:
    """How many episodes of each cell were degraded (a module's answer unusable, and its
    stand-in used: the STOP fallback, no sub-goals, the proposal order): scored as flown,
    they are in the cell's numbers without a mark of their own, so the note counts them."""
    sel = _shown_cells(scores, spec, mode)
    parts = _flagged_per_cell(sel, (sel["status"] == "degraded").to_numpy(bool), rows, spec)
    if not parts:
        return []
    return [
        "Degraded episodes (a module's answer was unusable and its stand-in used: the STOP "
        f"fallback, no sub-goals, HSD's proposal order; scored as flown): {'; '.join(parts)}."
    ]


def _crashes_note(
    scores: pd.DataFrame,
    rows: Sequence[str],
    spec: TableSpec,
    mode: str,
    conventions: MetricConventions,
) -> list[str]:
    """How many episodes of each cell flew into an obstacle, and how they were scored: a
    success rate means something else when most flights crashed."""
    sel = _shown_cells(scores, spec, mode)
    parts = _flagged_per_cell(sel, touched_obstacles(sel), rows, spec)
    if not parts:
        return []
    how = (
        "count as failures (0 in SR and SPL; distances as flown, to the crash)"
        if conventions.collision_fails
        else "are scored on their views alone (--collisions-succeed)"
    )
    return [f"Episodes whose flight touched an obstacle, which {how}: {'; '.join(parts)}."]


def marked_labels(stand_ins: dict[str, str]) -> dict[str, str]:
    """Row labels with the marker of their stand-in, where the label does not already say
    what answered it (its marker, "not an LLM" or "stand-in", as reproduce's rows do)."""
    marked = {}
    for system, kind in stand_ins.items():
        marker = STAND_IN_MARKERS[kind][0]
        says = marker in system or any(w in system.lower() for w in ("not an llm", "stand-in"))
        if not says:
            marked[system] = f"{system} {marker}"
    return marked
