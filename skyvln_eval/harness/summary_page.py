"""``SUMMARY.md`` of a reproduce run: the tables inline, links to every file, completeness."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import pandas as pd

from skyvln_eval.avdn.summary import SplitSummary
from skyvln_eval.fileio import atomic_write_text
from skyvln_eval.harness.reproduce import WALL_CLOCK_METRICS
from skyvln_eval.metrics import MetricConventions
from skyvln_eval.reports.table_layout import LAYOUT_FILE
from skyvln_eval.reports.tables import episodes

if TYPE_CHECKING:
    from skyvln_eval.harness.plan import ReproducePlan
    from skyvln_eval.harness.reproduce import ReproduceReport


def _link(report: ReproduceReport, name: str) -> str:
    path = report.files[name]
    return f"[{name}]({path.relative_to(report.out_dir).as_posix()})"


def _read(report: ReproduceReport, name: str) -> str:
    return report.files[name].read_text(encoding="utf-8").strip()


def _datasets(datasets: Sequence[SplitSummary]) -> list[str]:
    lines = [
        "| split | records | trajectories | maps | mean GT length m | GT replay hull-IoU, least |",
        "|---|---|---|---|---|---|",
    ]
    for s in datasets:
        replay = "withheld" if s.ground_truth_withheld else f"{s.gt_replay_min_iou:.6f}"
        lines.append(
            f"| {s.split} | {s.records} | {s.trajectories} | {s.maps} | "
            f"{s.mean_gt_length_m:.1f} | {replay} |"
        )
    return lines


def _rows_of(rows: Sequence[tuple[str, str]], sep: str = ", ") -> str:
    """A run's table rows as the tables label them: ``Full † (Table I)``."""
    return sep.join(f"{label} ({table})" for table, label in rows)


def _shared_runs(report: ReproduceReport, scores: pd.DataFrame) -> str:
    """How the scored rows outnumber the episodes: a run that fills several table rows has
    its episodes scored once for each (the same episodes, not more of them)."""
    parts = []
    extra = 0
    for r, rows in zip(report.reports, report.run_rows, strict=True):
        if len(rows) < 2:
            continue
        splits = sorted({split for split, _ in r.expected})
        # Its episodes as scored under its first row (withheld ground truth is not scored).
        of_run = (scores["system"] == rows[0][1]) & scores["split"].isin(splits)
        scored = int(of_run.sum())
        extra += scored * (len(rows) - 1)
        parts.append(
            f"{_rows_of(rows, ' and ')} are one run "
            f"({', '.join(splits)}: {episodes(scored)}), scored once for each row"
        )
    if not parts:
        return ""
    return f" for {int(scores.shape[0]) - extra} episodes: {'; '.join(parts)}"


def _relative(path: Path, report: ReproduceReport) -> str:
    """``path`` as SUMMARY.md links it: from the output folder, where it lies in it."""
    try:
        return str(Path(path).relative_to(report.out_dir))
    except ValueError:
        return str(path)


def _runs(report: ReproduceReport) -> list[str]:
    lines = [
        "| table rows | split | episodes | ok | degraded | error | missing | run now "
        "| simulated s (run now) | structured output |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    names = [_rows_of(rows) for rows in report.run_rows]
    for r, name in zip(report.reports, names, strict=True):
        splits = sorted({split for split, _ in r.expected})
        counts = " | ".join(str(r.statuses.get(s, 0)) for s in ("ok", "degraded", "error"))
        levels = "; ".join(f"{m}: {lvl}" for m, lvl in r.structured_output.items()) or "-"
        if r.server_defaults:  # decoding parameters the model refused: its defaults applied
            levels += "; at the server's default: " + "; ".join(
                f"{m}: {names}" for m, names in r.server_defaults.items()
            )
        lines.append(
            f"| {name} | {', '.join(splits)} | {len(r.expected)} | {counts} "
            f"| {len(r.missing)} | {r.ran_now} | {r.simulated_s:.0f} | {levels} |"
        )
    runs = list(zip(report.reports, names, strict=True))
    problems = (
        [
            f"- {name}: error {split}/{episode}: {message}"
            for r, name in runs
            for (split, episode), message in r.errors.items()
        ]
        + [
            f"- {name}: missing {split}/{episode}"
            for r, name in runs
            for split, episode in r.missing
        ]
        + [f"- {name}: stopped early: {r.stopped}" for r, name in runs if r.stopped]
        # What each run's launch said (rows set aside or run again, a code change), with
        # its run directory: a system runs one per split.
        + [
            f"- {name} ({_relative(r.run_dir, report)}): {note}"
            for r, name in runs
            for note in r.notes
        ]
    )
    return lines + (["", *problems] if problems else [])


def _timing_note() -> str:
    """Which values are wall-clock measurements: the only ones two runs of the same seed
    and inputs differ in, so a reader comparing them knows what to ignore."""
    columns = ", ".join(f"`{metric}`" for metric in WALL_CLOCK_METRICS)
    return (
        f"Wall-clock measurements, which vary from run to run: {columns} (columns of "
        "scores.csv, and those metrics' rows of summary.csv), control.md's solve-time "
        "columns, cost.md's `llm_latency_s` and `wall_s`, Table II's LLM s column (values, "
        "intervals and marks), the control logs' per-step solve times and the times on this "
        "page. Every other value of the scores, tables and figures is byte-identical for the "
        "same seed and inputs."
    )


def _status_line(report: ReproduceReport) -> str:
    totals = {s: sum(r.statuses.get(s, 0) for r in report.reports) for s in ("ok", "degraded")}
    errors = sum(len(r.errors) for r in report.reports)
    missing = sum(len(r.missing) for r in report.reports)
    return (
        f"Episodes: {totals['ok']} ok, {totals['degraded']} degraded (a fallback action or a "
        f"module's answer unusable), {errors} error (no usable LLM answer, or raised), "
        f"{missing} missing."
    )


def _recordings(report: ReproduceReport) -> list[str]:
    names = sorted(name for name in report.files if name.endswith(".rrd"))
    lines = [f"- {_link(report, name)}" for name in names]
    if names:
        first = report.files[names[0]].relative_to(report.out_dir).as_posix()
        lines += [
            "",
            f"Open one with `skyvln-eval view {first}` (Rerun's web viewer, served on 127.0.0.1 "
            "with its usage analytics off), or with a local Rerun viewer: `rerun <file>.rrd`. "
            "Any episode of a run: `skyvln-eval view runs/<system>/<split> --episode <id>`.",
        ]
    return lines + [f"- {note}" for note in report.notes]


def _other_formats(report: ReproduceReport, table: str) -> str:
    """Links to a table's files: Markdown (shown above it), LaTeX, CSV, and the version
    with intervals if written."""
    text = (
        f"Files: {_link(report, f'{table}.md')}, {_link(report, f'{table}.tex')} (LaTeX) and "
        f"{_link(report, f'{table}.csv')}"
    )
    with_ci = f"{table}_ci.md"
    if with_ci in report.files:
        text += f"; with 95% intervals: {_link(report, with_ci)}"
    return text + "."


def _control_logs(report: ReproduceReport) -> list[str]:
    logs = sorted(name for name in report.files if name.startswith("control_runs/"))
    if not logs:
        return []
    return ["", "The control figures' logs: " + ", ".join(_link(report, n) for n in logs) + "."]


def _this_pass(report: ReproduceReport, wall: float, simulated: float) -> str:
    """What this reproduce pass ran, for the status line."""
    ran_now = sum(r.ran_now for r in report.reports)
    if ran_now:
        flight = f" for {simulated:.0f} s of simulated flight" if simulated > 0 else ""
        return f"the {ran_now} episode(s) run now took {wall:.0f} s of wall time{flight}"
    if report.complete:
        return "nothing was left to run: every episode was recorded before"
    return "no episode finished in this pass"


def write_summary_page(
    report: ReproduceReport,
    plan: ReproducePlan,
    datasets: Sequence[SplitSummary],
    conventions: MetricConventions,
    scores: pd.DataFrame,
) -> Path:
    figures = sorted(name for name in report.files if name.endswith((".png", ".pdf")))
    wall = report.reports[0].wall_s if report.reports else 0.0  # one pass ran every run
    simulated = sum(r.simulated_s for r in report.reports)
    errors = sum(r.statuses.get("error", 0) for r in report.reports)
    status = "complete" if report.complete else "INCOMPLETE: see the runs below"
    if errors:  # every episode has a row, but some rows are failures of the run
        status += f", {errors} episode(s) ended in error (the tables mark them)"
    if plan.limit:  # complete as asked, yet not the whole splits
        status += f"; a quick look: the first {plan.limit} episode(s) of each split (limit)"
    rule_note = (
        "Rows marked *not an LLM* (and Table I rows marked with a dagger) use offline "
        "stand-ins: the rule-based backend reads the requests' task data (the prompt's content "
        "as data) with a vocabulary, the random backend answers at random. They measure the "
        "pipeline, not a language model."
    )
    this_time = _this_pass(report, wall, simulated)
    text = "\n".join(
        [
            f"# Reproduce: plan `{plan.name}`",
            "",
            f"Status: {status}. {int(scores.shape[0])} scored episode rows"
            f"{_shared_runs(report, scores)}; {this_time}; "
            f"everything took {report.wall_s:.0f} s.",
            "",
            _status_line(report),
            "",
            f"Metric conventions: {conventions.describe()}",
            "",
            _timing_note(),
            "",
            "## Table I: systems (SPL and SR, %)",
            "",
            _read(report, "table1.md"),
            "",
            _other_formats(report, "table1"),
            "",
            "## Table II: LLM backends",
            "",
            _read(report, "table2.md"),
            "",
            rule_note,
            _other_formats(report, "table2"),
            "",
            _read(report, "cost.md"),
            "",
            f"File: {_link(report, 'cost.md')}.",
            "",
            _read(report, "control.md"),
            "",
            f"File: {_link(report, 'control.md')}.",
            "",
            "## Figures",
            "",
            *[f"- {_link(report, name)}" for name in figures],
            *_control_logs(report),
            "",
            "## Episode recordings (Rerun)",
            "",
            *(
                _recordings(report)
                or [
                    "(none made this time: recordings were off, by --no-recordings or the "
                    "plan's recordings: 0)"
                    if plan.recordings == 0
                    else "(none made this time)"
                ]
            ),
            "",
            "## Scores",
            "",
            f"- per episode: {_link(report, 'scores.csv')}; per system and split with 95% "
            f"intervals: {_link(report, 'summary.csv')}; each table's rows, order and notes "
            f"(what `skyvln-eval table` on these scores reads): {_link(report, LAYOUT_FILE)}",
            "- every run directory under `runs/` holds `config.yaml`, `versions.json`, "
            "`results.jsonl`, one run MCAP per episode under `logs/` and, flown, its control "
            "log under `control/`",
            "",
            "## Runs",
            "",
            "One line per run (a system on a split), named by the table rows it fills, as the "
            "tables label them; a run that fills two rows is one run, its episodes counted once.",
            "",
            *_runs(report),
            "",
            "## Dataset",
            "",
            *_datasets(datasets),
            "",
            f"As JSON: {_link(report, 'dataset_summary.json')}.",
            "",
        ]
    )
    path = report.out_dir / "SUMMARY.md"
    atomic_write_text(path, text)
    return path
