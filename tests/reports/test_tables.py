"""Paper-style tables: shape, best / second marks, CIs, escaping, and a LaTeX golden file.

To update the golden file after an intended change, render ``golden_table()`` with
``to_latex`` and review the diff before committing it.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import pandas as pd
import pytest

from skyvln_eval.errors import MetricInputError
from skyvln_eval.metrics import MetricConventions
from skyvln_eval.reports import TABLE_I, TABLE_II, build_table, to_csv, to_latex, to_markdown

EXPECTED = Path(__file__).parent / "expected"

# (system, split) -> (SPL %, SR %, NE m); "w/o TMA" did not run test_unseen.
VALUES = {
    ("Random", "val_seen"): (0.5, 1.6, 150.0),
    ("Random", "val_unseen"): (0.2, 1.0, 160.0),
    ("Random", "test_unseen"): (0.5, 1.1, 155.0),
    ("w/o TMA & co_1", "val_seen"): (11.57, 12.97, 90.0),
    ("w/o TMA & co_1", "val_unseen"): (18.3, 19.95, 80.0),
    ("Ours Full", "val_seen"): (14.7, 17.3, 70.0),
    ("Ours Full", "val_unseen"): (16.62, 20.44, 72.0),
    ("Ours Full", "test_unseen"): (28.11, 42.37, 60.0),
}


def summary(with_ci: bool = False) -> pd.DataFrame:
    rows = []
    for (system, split), values in VALUES.items():
        for metric, value in zip(("spl", "success", "ne_m"), values, strict=True):
            row = {"system": system, "split": split, "mode": "andh", "metric": metric,
                   "unit": "m" if metric == "ne_m" else "%", "n": 100, "mean": value}  # fmt: skip
            if with_ci:
                row.update(ci_low=value - 1.0, ci_high=value + 1.5, confidence=0.95)
            rows.append(row)
    return pd.DataFrame(rows)


def golden_table() -> str:
    table = build_table(summary(), TABLE_I, MetricConventions(), digits=2)
    return to_latex(table)


def test_latex_table_i_matches_the_expected_file() -> None:
    assert golden_table() == (EXPECTED / "table1.tex").read_text()


def test_best_is_bold_and_second_underlined_per_column() -> None:
    table = build_table(summary(), TABLE_I, MetricConventions())
    cell = table.cells
    assert cell["Ours Full"][("val_seen", "spl")].rank == 1
    assert cell["w/o TMA & co_1"][("val_seen", "spl")].rank == 2
    assert cell["Random"][("val_seen", "spl")].rank is None
    assert cell["w/o TMA & co_1"][("test_unseen", "spl")] is None
    assert cell["Random"][("test_unseen", "spl")].rank == 2  # two rows ran it
    md = to_markdown(table)
    assert (
        "| Ours Full | **14.70** | **17.30** | <u>16.62</u> | **20.44** | **28.11** | **42.37** |"
        in md
    )
    assert "| w/o TMA & co_1 | <u>11.57</u> |" in md and "| - | - |" in md


def test_lower_is_better_for_ne_and_ties_share_a_rank() -> None:
    data = summary()
    data.loc[
        (data.system == "Random") & (data.metric == "success") & (data.split == "test_unseen"),
        "mean",
    ] = 42.371
    table = build_table(data, TABLE_II, MetricConventions(), rows=["Ours Full", "Random"], digits=2)
    assert table.cells["Ours Full"][("test_unseen", "ne_m")].rank == 1
    assert table.cells["Random"][("test_unseen", "ne_m")].rank == 2
    # 42.37 is shown for both rows: when every row ties, nothing is marked.
    assert table.cells["Random"][("test_unseen", "success")].rank is None
    assert table.cells["Ours Full"][("test_unseen", "success")].rank is None
    data.loc[
        (data.system == "Random") & (data.metric == "spl") & (data.split == "val_seen"), "mean"
    ] = 14.7
    tied = build_table(data, TABLE_I, MetricConventions()).cells
    assert (
        tied["Random"][("val_seen", "spl")].rank == 1
        and tied["Ours Full"][("val_seen", "spl")].rank == 1
    )
    assert tied["w/o TMA & co_1"][("val_seen", "spl")].rank == 2
    assert "NE/m ↓" in to_markdown(table) and r"$\downarrow$" in to_latex(table)


def test_confidence_intervals_in_every_format() -> None:
    table = build_table(summary(True), TABLE_II, MetricConventions(threshold_m=3.0), show_ci=True)
    assert "28.11 [27.11, 29.61]" in to_markdown(table)
    assert r"\textbf{28.11}\,{\scriptsize[27.11, 29.61]}" in to_latex(table)
    lines = to_csv(table).splitlines()
    assert lines[0].startswith("# conventions: {") and '"threshold_m":3.0' in lines[0]
    rows = list(csv.DictReader(io.StringIO("\n".join(lines[1:]))))
    full = next(r for r in rows if r["LLM"] == "Ours Full")
    assert float(full["test_unseen:spl"]) == 28.11
    assert float(full["test_unseen:spl:ci_high"]) == pytest.approx(29.61)
    with pytest.raises(MetricInputError, match="confidence intervals"):
        build_table(summary(), TABLE_II, MetricConventions(), show_ci=True)


def test_rows_follow_the_caller_and_unknown_rows_fail() -> None:
    table = build_table(summary(), TABLE_I, MetricConventions(), rows=["Random", "Ours Full"])
    assert table.rows == ("Random", "Ours Full")
    with pytest.raises(MetricInputError, match="GPT-5"):
        build_table(summary(), TABLE_I, MetricConventions(), rows=["GPT-5"])
