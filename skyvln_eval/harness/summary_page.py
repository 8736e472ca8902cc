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
        "| split | records | trajectories | maps | mean GT length m | GT replay hull-IoU |",
        "|---|---|---|---|---|---|",
    ]
    for s in datasets:
        replay = "withheld" if s.ground_truth_withheld else f"{s.gt_replay_min_iou:.6f}"
        lines.append(
            f"| {s.split} | {s.records} | {s.trajectories} | {s.maps} | "
            f"{s.mean_gt_length_m:.1f} | {replay} |"
        )
    return lines


def _runs(report: ReproduceReport) -> list[str]:
    lines = [
        "| system | split | episodes | ok | degraded | error | missing | run now | simulated s "
        "| structured output |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in report.reports:
        splits = sorted({split for split, _ in r.expected})
        counts = " | ".join(str(r.statuses.get(s, 0)) for s in ("ok", "degraded", "error"))
        levels = "; ".join(f"{m}: {lvl}" for m, lvl in r.structured_output.items()) or "-"
        if r.server_defaults:  # decoding parameters the model refused: its defaults applied
            levels += "; at the server's default: " + "; ".join(
                f"{m}: {names}" for m, names in r.server_defaults.items()
            )
        lines.append(
            f"| {r.system} | {', '.join(splits)} | {len(r.expected)} | {counts} "
            f"| {len(r.missing)} | {r.ran_now} | {r.simulated_s:.0f} | {levels} |"
        )
    problems = (
        [
            f"- {r.system}: error {split}/{episode}: {message}"
            for r in report.reports
            for (split, episode), message in r.errors.items()
        ]
        + [
            f"- {r.system}: missing {split}/{episode}"
            for r in report.reports
            for split, episode in r.missing
        ]
        + [f"- {r.system}: stopped early: {r.stopped}" for r in report.reports if r.stopped]
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
    rule_note = (
        "Rows marked *not an LLM* (and Table I rows marked with a dagger) use offline "
        "stand-ins: the rule-based backend reads the requests' task data (the prompt's content "
        "as data) with a vocabulary, the random backend answers at random. They measure the "
        "pipeline, not a language model."
    )
    text = "\n".join(
        [
            f"# Reproduce: plan `{plan.name}`",
            "",
            f"Status: {status}. {int(scores.shape[0])} scored episode rows; the episodes run now "
            f"took {wall:.0f} s of wall time for {simulated:.0f} s of simulated flight; "
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
            f"Also as {_link(report, 'table1.tex')} (LaTeX) and {_link(report, 'table1.csv')}; "
            + (
                f"with 95% intervals: {_link(report, 'table1_ci.md')}."
                if "table1_ci.md" in report.files
                else ""
            ),
            "",
            "## Table II: LLM backends",
            "",
            _read(report, "table2.md"),
            "",
            rule_note,
            f"Also as {_link(report, 'table2.tex')} and {_link(report, 'table2.csv')}.",
            "",
            _read(report, "cost.md"),
            "",
            _read(report, "control.md"),
            "",
            "## Figures",
            "",
            *[f"- {_link(report, name)}" for name in figures],
            "",
            "## Episode recordings (Rerun)",
            "",
            *(_recordings(report) or [f"(none: the plan asks for {plan.recordings})"]),
            "",
            "## Scores",
            "",
            f"- per episode: {_link(report, 'scores.csv')}; per system and split with 95% "
            f"intervals: {_link(report, 'summary.csv')}",
            "- every run directory under `runs/` holds `config.yaml`, `versions.json`, "
            "`results.jsonl`, one run MCAP per episode under `logs/` and, flown, its control "
            "log under `control/`",
            "",
            "## Runs",
            "",
            *_runs(report),
            "",
            "## Dataset",
            "",
            *_datasets(datasets),
            "",
        ]
    )
    path = report.out_dir / "SUMMARY.md"
    atomic_write_text(path, text)
    return path
