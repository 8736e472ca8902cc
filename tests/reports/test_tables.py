"""Paper-style tables: shape, best / second marks, CIs, escaping, and a LaTeX golden file.

To update the golden file after an intended change, render ``golden_table()`` with
``to_latex`` and review the diff before committing it.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import pandas as pd
import pytest

from skyvln_eval.errors import MetricInputError
from skyvln_eval.metrics import MetricConventions, score_results, summarise
from skyvln_eval.reports import TABLE_I, TABLE_II, build_table, to_csv, to_latex, to_markdown
from skyvln_eval.reports.tables import Table, _ranks, latex_escape, nonzero_fixed
from tests.metrics.helpers import result, square

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
                row.update(
                    ci_low=value - 1.0, ci_high=value + 1.5, confidence=0.95, ci_method="bootstrap"
                )
            rows.append(row)
    return pd.DataFrame(rows)


def golden_table() -> str:
    table = build_table(summary(), TABLE_I, MetricConventions(), digits=2)
    return to_latex(table)


def csv_records(table: Table) -> list[dict[str, str]]:
    """The CSV's rows by column name (its '#' lines of conventions and notes left out)."""
    lines = [line for line in to_csv(table).splitlines() if not line.startswith("#")]
    return list(csv.DictReader(io.StringIO("\n".join(lines))))


def test_latex_table_i_matches_the_expected_file() -> None:
    assert golden_table() == (EXPECTED / "table1.tex").read_text()


def test_best_is_bold_and_second_underlined_per_column() -> None:
    table = build_table(summary(), TABLE_I, MetricConventions())
    cell = table.cells
    assert cell["Ours Full"][("val_seen", "spl")].rank == 1
    assert cell["w/o TMA & co_1"][("val_seen", "spl")].rank == 2
    assert cell["Random"][("val_seen", "spl")].rank is None
    assert cell["w/o TMA & co_1"][("test_unseen", "spl")] is None
    # Two rows ran it: the other is the worst too, and is not marked second best.
    assert cell["Random"][("test_unseen", "spl")].rank is None
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
    assert table.cells["Random"][("test_unseen", "ne_m")].rank is None  # second and worst
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
    # Two values shown: the lower is both second best and the worst, so it is not marked.
    assert tied["w/o TMA & co_1"][("val_seen", "spl")].rank is None
    assert "NE/m ↓" in to_markdown(table) and r"$\downarrow$" in to_latex(table)


def test_confidence_intervals_in_every_format() -> None:
    table = build_table(summary(True), TABLE_II, MetricConventions(threshold_m=3.0), show_ci=True)
    assert "28.11 [27.11, 29.61]" in to_markdown(table)
    assert r"\textbf{28.11}\,{\scriptsize[27.11, 29.61]}" in to_latex(table)
    lines = to_csv(table).splitlines()
    assert lines[0].startswith("# conventions: {") and '"threshold_m":3.0' in lines[0]
    # Each metric's unit: SR is a percent here, a fraction in scores.csv.
    assert lines[1].startswith("# columns: spl is SPL/%; success is SR/%; ne_m is NE/m;")
    data = [line for line in lines if not line.startswith("#")]  # conventions and notes
    rows = list(csv.DictReader(io.StringIO("\n".join(data))))
    full = next(r for r in rows if r["LLM"] == "Ours Full")
    assert float(full["test_unseen:spl"]) == 28.11
    assert float(full["test_unseen:spl:ci_high"]) == pytest.approx(29.61)
    with pytest.raises(MetricInputError, match="confidence intervals"):
        build_table(summary(), TABLE_II, MetricConventions(), show_ci=True)
    with pytest.raises(MetricInputError, match="do not say how they were made"):
        unsaid = summary(True).drop(columns="ci_method")
        build_table(unsaid, TABLE_II, MetricConventions(), show_ci=True)


def test_a_table_says_how_its_intervals_were_made_and_shows_a_missing_one_as_such() -> None:
    # One episode of "One": its SR has a Wilson interval, its SPL none (a bootstrap of
    # one value is that value); ten of "Ten": SR 0/10 is [0, 27.75], not [0, 0].
    g = [square(0, 0), square(100, 0)]
    results = [result([g[0], square(100, 0)], g, episode_id="e0", system="One")]
    results += [
        result([g[0], square(30 + k, 0)], g, episode_id=f"e{k}", system="Ten") for k in range(10)
    ]
    scores = score_results(results)
    data = summarise(scores, ["spl", "success"], n_resamples=200, ci_unit="episode")
    table = build_table(data, TABLE_I, MetricConventions(), show_ci=True)
    md = to_markdown(table)
    assert "| One | **100.00 [n/a]** | **100.00 [20.65, 100.00]** |" in md
    # Ten SPLs of 0 resample to 0 every time: no interval, not [0.00, 0.00].
    assert "| Ten | 0.00 [n/a] | 0.00 [0.00, 27.75] |" in md
    note = (
        "Brackets: 95% intervals; Wilson score interval, the episodes as trials: SR/%; "
        "[n/a]: no interval (a bootstrap needs episodes whose values differ)."
    )
    assert note in md and "bootstrap CI" not in md
    assert r"\textbf{100.00}\,{\scriptsize[n/a]}" in to_latex(table)
    assert note.replace("%", r"\%") in to_latex(table)
    lines = [line for line in to_csv(table).splitlines() if not line.startswith("#")]
    one = next(r for r in csv.DictReader(io.StringIO("\n".join(lines))) if r["Model"] == "One")
    assert (one["val_seen:spl:ci_low"], one["val_seen:spl:ci_high"]) == ("n/a", "n/a")
    assert float(one["val_seen:success:ci_low"]) == pytest.approx(20.65, abs=0.005)
    # Without intervals, nothing is said of them.
    assert "Brackets" not in to_markdown(build_table(data, TABLE_I, MetricConventions()))


def test_rows_follow_the_caller_and_unknown_rows_fail() -> None:
    table = build_table(summary(), TABLE_I, MetricConventions(), rows=["Random", "Ours Full"])
    assert table.rows == ("Random", "Ours Full")
    with pytest.raises(MetricInputError, match="GPT-5"):
        build_table(summary(), TABLE_I, MetricConventions(), rows=["GPT-5"])


def with_errors(data: pd.DataFrame, errors: dict[tuple[str, str], float]) -> pd.DataFrame:
    """``data`` with status_error rows (% of 100 episodes) for some (system, split)."""
    rows = [
        {"system": system, "split": split, "mode": "andh", "metric": "status_error",
         "unit": "%", "n": 100, "mean": share}
        for (system, split), share in errors.items()
    ]  # fmt: skip
    return pd.concat([data, pd.DataFrame(rows)], ignore_index=True)


def test_ranks_are_of_the_values_as_shown_small_ones_with_their_decimals() -> None:
    # Costs 0.00002 and 0.00004 show as 0.000020 and 0.000040: different, so one is best
    # (ranked at 4 decimals, both were 0.0000 and both were marked best).
    costs = {"A": 0.00002, "B": 0.00004, "C": 0.002}
    assert _ranks(costs, lower_is_better=True, digits=4) == {"A": 1, "B": 2}
    assert [nonzero_fixed(v, 4) for v in costs.values()] == ["0.000020", "0.000040", "0.0020"]


def test_a_cell_whose_every_episode_failed_says_error_and_is_not_ranked() -> None:
    # Ours Full's val_seen episodes all ended in error (a dead LLM endpoint): its scores
    # are those of failures; some of Random's val_unseen ones did.
    data = with_errors(summary(), {("Ours Full", "val_seen"): 100.0, ("Random", "val_unseen"): 3.0})
    table = build_table(data, TABLE_I, MetricConventions())
    dead = table.cells["Ours Full"][("val_seen", "spl")]
    assert dead.all_errors and dead.rank is None
    # The best left is w/o TMA; Random is the worst of the two and not marked.
    assert table.cells["w/o TMA & co_1"][("val_seen", "spl")].rank == 1
    md = to_markdown(table)
    assert "| Ours Full | error | error | <u>16.62</u> |" in md
    assert "| Random | 0.50 | 1.60 | 0.20⋄ | 1.00⋄ |" in md
    # 3 of Random's 100 ended in error, not all of them (the note once said "all of them
    # did: Random on Unseen Validation: 3 of 100").
    assert "'error': every episode of the cell did. Episodes that ended in error: " in md
    assert "Random on Unseen Validation 3 of 100; Ours Full on Seen Validation 100 of 100." in md
    assert "all of them did" not in md
    rows = list(csv.reader(io.StringIO(to_csv(table)), delimiter=","))
    assert rows[-1][:3] == ["Ours Full", "error", "error"]
    # The marker's counts are columns of the CSV too, for a script reading it.
    by_row = {r[table.spec.row_header]: r for r in csv_records(table)}
    assert by_row["Random"]["val_unseen:episodes"] == "100"
    assert by_row["Random"]["val_unseen:error_episodes"] == "3"
    assert by_row["Ours Full"]["val_seen:error_episodes"] == "100"
    latex = to_latex(table)
    assert r"0.20$^\diamond$" in latex and "error & error" in latex
    # With intervals: an error cell has none in the CSV either (it gave one, over failures).
    data = with_errors(summary(True), {("Ours Full", "val_seen"): 100.0})
    shown = build_table(data, TABLE_I, MetricConventions(), show_ci=True)
    dead_row = {r[shown.spec.row_header]: r for r in csv_records(shown)}["Ours Full"]
    assert dead_row["val_seen:spl"] == "error"
    assert (dead_row["val_seen:spl:ci_low"], dead_row["val_seen:spl:ci_high"]) == ("", "")
    assert dead_row["val_unseen:spl:ci_low"] != ""


def test_a_dead_endpoint_shows_its_health_numbers_but_is_never_ranked_on_them() -> None:
    # Ours Full's test_unseen episodes all errored fast: its LLM time is the lowest, yet it
    # is not the "fastest" (nor the best on any column) as it would be had they not.
    health = [
        {"system": system, "split": "test_unseen", "mode": "andh", "metric": "llm_latency_s",
         "unit": "s", "n": 100, "mean": seconds}
        for system, seconds in (("Ours Full", 0.3), ("Random", 5.0))
    ]  # fmt: skip
    measured = pd.concat([summary(), pd.DataFrame(health)], ignore_index=True)
    data = with_errors(
        measured, {("Ours Full", "test_unseen"): 100.0, ("Random", "test_unseen"): 0}
    )
    table = build_table(data, TABLE_II, MetricConventions())
    dead, alive = table.cells["Ours Full"], table.cells["Random"]
    assert dead[("test_unseen", "llm_latency_s")].mean == 0.3  # shown, as measured
    assert not dead[("test_unseen", "llm_latency_s")].all_errors
    assert {cell.rank for cell in dead.values() if cell is not None} == {None}
    assert alive[("test_unseen", "status_error")].rank is None  # nothing left to rank against
    assert "| Ours Full | error | error | error | - | - | - | 100.00 | - | 0.30 |" in to_markdown(
        table
    )
    healthy = with_errors(measured, {("Ours Full", "test_unseen"): 0, ("Random", "test_unseen"): 0})
    table = build_table(healthy, TABLE_II, MetricConventions())
    assert table.cells["Ours Full"][("test_unseen", "llm_latency_s")].rank == 1


def test_a_cost_known_only_from_below_shows_its_bound_and_is_not_ranked() -> None:
    # Ours Full's cost is unknown (failed attempts without a token count) but at least
    # 0.0014; Random's is known, 0.0020; neither is n/a, neither a ranked value.
    costs = [
        {"system": system, "split": "test_unseen", "mode": "andh", "metric": metric,
         "unit": "USD", "n": 100, "mean": value}
        for system, metric, value in (
            ("Ours Full", "llm_cost_usd", float("nan")),
            ("Ours Full", "llm_cost_lower_usd", 0.0014),
            ("Random", "llm_cost_usd", 0.002),
            ("Random", "llm_cost_lower_usd", 0.002),
        )
    ]  # fmt: skip
    data = pd.concat([summary(), pd.DataFrame(costs)], ignore_index=True)
    table = build_table(data, TABLE_II, MetricConventions())
    bounded = table.cells["Ours Full"][("test_unseen", "llm_cost_usd")]
    assert bounded is not None and bounded.lower_bound and bounded.rank is None
    md = to_markdown(table)
    assert "| ≥0.0014 |" in md and "| 0.0020 |" in md
    assert "≥: at least this much" in md and "Ours Full on Unseen Testing" in md
    assert r"$\geq$0.0014" in to_latex(table)
    row = next(r for r in csv.reader(io.StringIO(to_csv(table))) if r[0] == "Ours Full")
    assert "n/a" in row and not any("0.0014" in cell for cell in row)
    # A bound (or a cost) too small for the column's 4 decimals keeps two significant
    # digits: "≥0.0000" read as "at least nothing".
    tiny = data.copy()
    tiny.loc[tiny["metric"] == "llm_cost_lower_usd", "mean"] = 4.2e-5
    tiny.loc[(tiny["system"] == "Random") & (tiny["metric"] == "llm_cost_usd"), "mean"] = 4.2e-5
    md = to_markdown(build_table(tiny, TABLE_II, MetricConventions()))
    assert "| ≥0.000042 |" in md and "| 0.000042 |" in md and "0.0000 |" not in md
    # Its interval has the value's decimals: an audit saw "0.0019 [0.00, 0.00]".
    tiny.loc[tiny["metric"] == "llm_cost_usd", ["ci_low", "ci_high"]] = (3.1e-5, 5.06e-5)
    tiny = tiny.assign(ci_method="bootstrap", confidence=0.95)
    shown = to_markdown(build_table(tiny, TABLE_II, MetricConventions(), show_ci=True))
    assert "| 0.000042 [0.000031, 0.000051] |" in shown


def test_reference_rows_are_not_ranked_and_withheld_splits_say_so() -> None:
    data = summary()
    data = data[data.split != "test_unseen"]
    oracle = data[data.system == "Ours Full"].assign(system="GT replay (oracle)", mean=100.0)
    data = pd.concat([data, oracle], ignore_index=True)
    table = build_table(
        data,
        TABLE_I,
        MetricConventions(),
        unranked={"GT replay (oracle)"},
        withheld={"test_unseen"},
    )
    assert table.cells["GT replay (oracle)"][("val_seen", "spl")].rank is None
    assert table.cells["Ours Full"][("val_seen", "spl")].rank == 1
    md = to_markdown(table)
    assert "| GT replay (oracle) | 100.00 | 100.00 | 100.00 | 100.00 | withheld | withheld |" in md
    assert "Not ranked (a reference, not a competitor): GT replay (oracle)." in md
    assert "the ground truth of Unseen Testing is withheld" in md
    row = csv_records(table)[-1]
    assert row["test_unseen:spl"] == row["test_unseen:success"] == "withheld"
    assert "withheld & withheld" in to_latex(table)


def test_a_split_or_row_that_did_not_run_is_named_in_a_note() -> None:
    only_seen = summary()[lambda d: d.split == "val_seen"]
    table = build_table(only_seen, TABLE_I, MetricConventions())
    assert "-: no scores (no episode recorded): Unseen Validation; Unseen Testing." in to_markdown(
        table
    )
    table = build_table(summary(), TABLE_I, MetricConventions())
    assert "-: no scores (no episode recorded): w/o TMA & co_1 on Unseen Testing." in to_markdown(
        table
    )


def counted(data: pd.DataFrame, n: dict[tuple[str, str], int]) -> pd.DataFrame:
    """``data`` with error-free status_error rows saying each (system, split) ran n episodes."""
    rows = [
        {"system": system, "split": split, "mode": "andh", "metric": "status_error",
         "unit": "%", "n": episodes, "mean": 0.0}
        for (system, split), episodes in n.items()
    ]  # fmt: skip
    return pd.concat([data, pd.DataFrame(rows)], ignore_index=True)


def test_a_table_always_says_how_many_episodes_its_cells_are_over() -> None:
    every_cell = dict.fromkeys(VALUES, 30)
    table = build_table(counted(summary(), every_cell), TABLE_I, MetricConventions())
    assert "Each cell: 30 episodes." in to_markdown(table)
    assert "Each cell: 30 episodes." in to_latex(table)
    assert "different numbers" not in to_markdown(table)
    # Same count within each split, not across them: each split's count.
    by_split = {key: 20 if key[1] == "test_unseen" else 30 for key in VALUES}
    md = to_markdown(build_table(counted(summary(), by_split), TABLE_I, MetricConventions()))
    assert "Episodes per cell: Seen Validation 30; Unseen Validation 30; Unseen Testing 20." in md
    assert "Each cell:" not in md
    # Rows of a split that differ are named; the other splits keep their one count.
    uneven = every_cell | {("Random", "val_seen"): 29}
    md = to_markdown(build_table(counted(summary(), uneven), TABLE_I, MetricConventions()))
    assert "Episodes per cell: Unseen Validation 30; Unseen Testing 30." in md
    assert (
        "Rows ran different numbers of episodes: Seen Validation: Random 29, "
        "w/o TMA & co_1 30, Ours Full 30." in md
    )
    # A count the summary does not give is not claimed for every cell.
    partial = {key: n for key, n in every_cell.items() if key[0] != "Random"}
    md = to_markdown(build_table(counted(summary(), partial), TABLE_I, MetricConventions()))
    assert "Each cell:" not in md and "Episodes per cell: Unseen Validation" not in md


def test_latex_carries_the_caption_conventions_and_notes_of_the_markdown() -> None:
    data = with_errors(summary(), {("Random", "val_unseen"): 3.0})
    table = build_table(data, TABLE_I, MetricConventions(), notes=["† a row's 100% note"])
    md, latex = to_markdown(table), to_latex(table)
    caption = f"{TABLE_I.caption} Best in bold, second underlined."
    conventions = f"Conventions: {MetricConventions().describe()}."
    assert f"{caption} {conventions}" in md
    assert f"\\caption{{{latex_escape(caption)}}}" in latex
    # Below the tabular, one paragraph each: the conventions, then every note in order.
    block = latex.split("\\end{tabular}\n", 1)[1].splitlines()
    assert block[0] == r"\par\smallskip\footnotesize"
    assert block[1:-1] == [f"{latex_escape(t)}\\par" for t in (conventions, *table.notes)]
    assert block[-1] == r"\end{table}"
    assert len(table.notes) >= 2 and r"a row's 100\% note\par" in latex
    assert "NE $<$ 20 m" in latex  # not LaTeX's text-mode '<' (an inverted '!')


def test_a_row_without_scores_names_the_systems_there_are() -> None:
    data = summary()
    with pytest.raises(MetricInputError) as unknown:
        build_table(data, TABLE_I, MetricConventions(), rows=["Full"])
    systems = list(dict.fromkeys(data["system"]))
    assert f"no scores for system(s) 'Full'; the scores have the systems {systems[0]!r}" in str(
        unknown.value
    )
    many = pd.concat(
        [data.assign(system=f"S{k}") for k in range(20)], ignore_index=True
    )  # 20 systems: 12 named, the 8 others counted
    with pytest.raises(MetricInputError, match=r"'S11' and 8 more$"):
        build_table(many, TABLE_I, MetricConventions(), rows=["Full"])


def test_a_model_without_a_price_whose_calls_all_failed_has_no_lower_bound() -> None:
    # From an audit: every call of the unpriced model failed, so "every answered call is
    # priced" held vacuously and Table II showed "≥0.0000" with a note saying so.
    from skyvln_eval.llm_records import LlmCall

    g = [square(0, 0), square(50, 0)]
    failed = {"module": "motion", "backend": "openai", "outcome": "failed", "error": "HTTP 503"}
    dead = [LlmCall(model="dead", **failed)]  # type: ignore[arg-type]
    live = [
        LlmCall(model="live", final=False, **failed),  # type: ignore[arg-type]
        LlmCall(
            module="motion", backend="openai", model="live", attempt=2,
            prompt_tokens=100, completion_tokens=20, cost_usd=0.0014,
        ),
    ]  # fmt: skip
    results = [
        result(g, g, "error", f"d{k}", "Dead", "test_unseen", llm_calls=dead) for k in range(2)
    ] + [result(g, g, "ok", f"p{k}", "Priced", "test_unseen", llm_calls=live) for k in range(2)]
    metrics = ["spl", "success", "ne_m", "llm_cost_usd", "llm_cost_lower_usd"]
    data = summarise(score_results(results), metrics, warn_errors=False)
    md = to_markdown(build_table(data, TABLE_II, MetricConventions()))
    row = next(line for line in md.splitlines() if line.startswith("| Dead |"))
    assert "≥" not in row and "n/a" in row
    # The priced model's failed attempt leaves its cost known from below, and only its.
    assert "a provider may bill them: Priced on Unseen Testing." in md


def test_cells_round_halves_away_from_zero_as_a_reader_does() -> None:
    """Python's rounding showed 37.5 as 38 and 62.5 as 62 in one column (half to even)."""
    from skyvln_eval.reports.tables import fixed

    assert [fixed(v, 0) for v in (37.5, 62.5, -2.5)] == ["38", "63", "-3"]
    assert fixed(2.675, 2) == "2.68"  # its shortest repr, not its binary value 2.67499...
    assert fixed(-0.001, 2) == "0.00" and fixed(46.666666, 2) == "46.67"
    assert fixed(math.inf, 1) == "inf"


def test_a_rounding_residue_is_shown_as_zero_and_a_small_cost_is_not() -> None:
    # An oracle's NE of 6e-10 m showed as "0.00000000"; a cost of $0.00004 must not be 0.
    assert nonzero_fixed(5.9e-10, 2) == "0.00"
    assert nonzero_fixed(-3e-12, 2) == "0.00"
    assert nonzero_fixed(4e-5, 4) == "0.000040"
    assert nonzero_fixed(1.2e-8, 2) == "0.00000001"
