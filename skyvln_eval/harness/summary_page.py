"""``SUMMARY.md`` of a reproduce run: the tables inline, links to every file, completeness."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import pandas as pd

from skyvln_eval.avdn.summary import SplitSummary
from skyvln_eval.fileio import atomic_write_text
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
        "| system | split | episodes | run now | already done | failed | missing | simulated s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in report.reports:
        splits = sorted({split for split, _ in r.expected})
        counts = f"{len(r.expected)} | {r.ran_now} | {r.already_done} | {len(r.failed)}"
        lines.append(
            f"| {r.system} | {', '.join(splits)} | {counts} | {len(r.missing)} "
            f"| {r.simulated_s:.0f} |"
        )
    problems = [
        f"- {r.system}: failed {split}/{episode}: {message}"
        for r in report.reports
        for (split, episode), message in r.failed.items()
    ] + [
        f"- {r.system}: missing {split}/{episode}"
        for r in report.reports
        for split, episode in r.missing
    ]
    return lines + (["", *problems] if problems else [])


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
    status = "complete" if report.complete else "INCOMPLETE: see the runs below"
    rule_note = (
        "Rows marked *not an LLM* use offline stand-ins (the rule-based backend reads the "
        "prompts' structured data; the random backend answers at random): they measure the "
        "pipeline, not a language model."
    )
    text = "\n".join(
        [
            f"# Reproduce: plan `{plan.name}`",
            "",
            f"Status: {status}. {int(scores.shape[0])} scored episode rows; episodes ran in "
            f"{wall:.0f} s of wall time for {simulated:.0f} s of simulated flight; "
            f"everything took {report.wall_s:.0f} s.",
            "",
            f"Metric conventions: {conventions.describe()}",
            "",
            "## Table I: systems (SPL and SR, %)",
            "",
            _read(report, "table1.md"),
            "",
            f"Also as {_link(report, 'table1.tex')} (LaTeX) and {_link(report, 'table1.csv')}; "
            + (
                f"with 95% bootstrap intervals: {_link(report, 'table1_ci.md')}."
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
