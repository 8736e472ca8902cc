"""What the scores, the plan and the printouts refuse or say, where a table would
otherwise show a number that is not what it claims: a row cut short, a cell that is not
a number, a split no table has, two rows of a plan in one folder; the score printout's
error cells, stand-in markers and answers from the cache, an interval note that names the
cells of each method."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner, Result

from skyvln_eval.cli import app
from skyvln_eval.errors import ConfigError, DataError, ResultRecordError
from skyvln_eval.harness.plan import load_plan, planned_runs
from skyvln_eval.llm_records import LlmCall
from skyvln_eval.metrics import MetricConventions, score_results
from skyvln_eval.metrics.results_io import write_results
from skyvln_eval.metrics.scores_io import read_scores, scores_warnings, write_scores
from skyvln_eval.reports import TABLE_II, paper_table, to_markdown
from skyvln_eval.reports.tables import RANK_MARKS
from tests.metrics.helpers import result, square
from tests.reports.test_paper_tables import GOAL, _scores


def _written(tmp_path: Path) -> tuple[Path, list[str]]:
    path = tmp_path / "scores.csv"
    write_scores(path, _scores(), MetricConventions())
    return path, path.read_text().split("\n")


def test_a_scores_row_cut_short_is_refused_naming_its_line(tmp_path: Path) -> None:
    path, lines = _written(tmp_path)
    # The last row cut after its status: pandas would read the rest as empty, so the
    # row would keep its success and lose its status_error (an 'error' cell from nothing).
    last = len([line for line in lines if line]) - 1
    lines[last] = ",".join(lines[last].split(",")[:16])
    path.write_text("\n".join(lines))
    with pytest.raises(DataError, match=rf"line {last + 1} has 16 of the header's \d+ cells"):
        read_scores(path)


def test_a_scores_cell_that_is_not_a_number_names_its_line_episode_and_column(
    tmp_path: Path,
) -> None:
    path, lines = _written(tmp_path)
    header = lines[2].split(",")
    row = lines[3].split(",")
    row[header.index("success")] = "abc"
    lines[3] = ",".join(row)
    path.write_text("\n".join(lines))
    with pytest.raises(ResultRecordError) as refused:
        read_scores(path)
    issue = refused.value.issue
    assert (issue.line, issue.field, issue.episode_id) == (4, "success", row[3])
    assert "'abc' is not a number" in str(refused.value)


def test_a_split_no_table_has_is_refused_in_results_and_in_scores(tmp_path: Path) -> None:
    with pytest.raises(ResultRecordError, match="field 'split': must be one of"):
        result(GOAL, GOAL, split="val_unknown")
    path, lines = _written(tmp_path)
    lines[3] = lines[3].replace("test_unseen", "val_unknown", 1)
    path.write_text("\n".join(lines))
    with pytest.raises(ResultRecordError, match="'val_unknown' is not one of") as refused:
        read_scores(path)
    assert refused.value.issue.line == 4


def test_two_rows_of_a_plan_in_one_run_folder_are_refused(tmp_path: Path) -> None:
    plan = load_plan("default", limit=1)
    systems = plan.table1.systems
    twice = plan.model_copy(
        update={"table1": plan.table1.model_copy(update={"systems": (*systems, systems[0])})}
    )
    with pytest.raises(ConfigError, match=rf"table1 row '{systems[0].label}' and table1 row "):
        planned_runs(twice, tmp_path, 1, "serial")
    alike = systems[0].model_copy(update={"label": systems[0].label.upper()})
    slugs = plan.model_copy(
        update={"table1": plan.table1.model_copy(update={"systems": (*systems, alike)})}
    )
    with pytest.raises(ConfigError, match="labels alike as folder names"):
        planned_runs(slugs, tmp_path, 1, "serial")


def test_the_score_printout_shows_errors_and_stand_ins_as_the_tables_do(tmp_path: Path) -> None:
    results = tmp_path / "results.jsonl"
    rows = [
        result(GOAL, GOAL, "error", system="dead", episode_id=f"1913__{k}_1", split="val_seen")
        for k in range(2)
    ]
    rows += [
        result(
            GOAL,
            GOAL,
            system="rule",
            episode_id=f"1913__{k}_1",
            split="val_seen",
            extra={"llm_backend": "rule"},
        )
        for k in range(2)
    ]
    write_results(results, rows)
    scored = CliRunner().invoke(
        app, ["score", str(results), "--out", str(tmp_path / "s"), "--resamples", "0"]
    )
    assert scored.exit_code == 0, scored.output
    table_rows = {
        line.split("│")[1].strip(): line for line in scored.output.splitlines() if "│" in line
    }
    # Every episode of 'dead' ended in error: its path metrics say so, not "0.00" or a
    # distance, while its error share is a number (100%).
    dead = [cell.strip() for cell in table_rows["dead"].split("│")[4:-1]]
    assert "error" in dead and "100.00" in dead and "0.00" not in dead[:3]
    assert "rule †" in table_rows
    assert "† LLM modules answered by the rule-based stand-in" in scored.output
    assert "'error': every episode of the cell did." in scored.output


def _score(results: Path, out: Path) -> Result:
    return CliRunner().invoke(app, ["score", str(results), "--out", str(out), "--resamples", "0"])


def test_the_score_printout_says_which_costs_came_from_the_cache(tmp_path: Path) -> None:
    """As Table II's note and the run's progress line do: a replayed answer counts the
    cost of the call that made it (an audit: the printout's Cost column said nothing)."""

    def call(cached: bool) -> LlmCall:
        return LlmCall(module="motion", backend="openai", model="m", cost_usd=0.01, cached=cached)

    rows = [
        result(GOAL, GOAL, system="replayed", episode_id=f"1913__{k}_1", llm_calls=calls)
        for k, calls in enumerate([(call(True), call(False)), (call(True), call(True))])
    ]
    rows += [result(GOAL, GOAL, system="paid", llm_calls=(call(False),))]
    write_results(tmp_path / "results.jsonl", rows)
    scored = _score(tmp_path / "results.jsonl", tmp_path / "s")
    assert scored.exit_code == 0, scored.output
    text = " ".join(scored.output.split())  # the console wraps long lines
    assert "Replayed from the response cache (their Cost is that of the calls that made" in text
    assert "replayed on val_seen: 75% of the LLM calls." in text
    assert "paid on" not in text  # a row with no cached answer is not named
    write_results(tmp_path / "paid.jsonl", rows[2:])
    paid = _score(tmp_path / "paid.jsonl", tmp_path / "p")
    assert paid.exit_code == 0 and "response cache" not in paid.output


def _two_models() -> pd.DataFrame:
    """Two models over 4 test_unseen episodes each: 'a' succeeds in every other one, 'b'
    never does."""
    scores = score_results(
        [
            result(
                GOAL if k % 2 else [square(0, 0)],
                GOAL,
                system=name,
                split="test_unseen",
                episode_id=f"19{t}__{k}_1",
                extra={"llm_backend": "openai:m"},
            )
            for name, t in (("a", 1), ("b", 2))
            for k in range(4)
        ],
        MetricConventions(),
    )
    scores.loc[scores.system == "b", "success"] = 0.0
    return scores


def test_an_interval_note_names_the_cells_of_a_columns_less_common_method() -> None:
    # a's SR varies (a bootstrap), b's is 0 throughout (no bootstrap: another method).
    md = to_markdown(paper_table(_two_models(), TABLE_II, MetricConventions(), show_ci=True))
    note = md.split("Brackets")[1]
    assert "SR/% (" in note and " on Unseen Testing" in note  # one method names its cells


def test_a_table_of_references_alone_does_not_explain_marks_it_lacks() -> None:
    references = _scores()[lambda s: s.system == "rule"]
    md = to_markdown(paper_table(references, TABLE_II, MetricConventions()))
    assert RANK_MARKS not in md
    assert RANK_MARKS in to_markdown(paper_table(_two_models(), TABLE_II, MetricConventions()))


def test_paths_longer_than_avdns_limit_are_warned_of_in_the_scores(tmp_path: Path) -> None:
    # OSR counts every view: a 20-view path is scored beyond the paper's protocol (10).
    long_path = [square(0, 0)] + [square(0, 10 * k) for k in range(1, 20)]
    rows = [result(long_path, GOAL, episode_id="1913__0_1"), result(GOAL, GOAL, "ok", "1913__1_1")]
    results = tmp_path / "results.jsonl"
    write_results(results, rows)
    out = tmp_path / "s"
    scored = CliRunner().invoke(app, ["score", str(results), "--out", str(out), "--resamples", "0"])
    assert scored.exit_code == 0, scored.output
    warning = f"{results}: 1 episode(s) visited more views than AVDN's max_action_len (10 per"
    assert any(w.startswith(warning) for w in scores_warnings(read_scores(out / "scores.csv")[0]))
    assert any(
        "allows (up to 20)" in w for w in scores_warnings(read_scores(out / "scores.csv")[0])
    )


def test_an_andh_full_path_is_allowed_ten_views_per_dialog_round(tmp_path: Path) -> None:
    # The budget of a whole dialog is a round's per round: a 15-view flight of two rounds
    # is within the protocol, a 25-view one is not (and a row that does not say how many
    # rounds it flew is not judged).
    def flight(views: int, episode_id: str, **extra: int) -> object:
        path = [square(0, 0)] + [square(0, 10 * k) for k in range(1, views)]
        return result(path, GOAL, episode_id=episode_id, mode="andh-full", extra=extra)

    rows = [
        flight(15, "1913__0_1", rounds_flown=2),
        flight(25, "1913__1_1", rounds_flown=2),
        flight(40, "1913__2_1"),
    ]
    results = tmp_path / "results.jsonl"
    write_results(results, rows)  # type: ignore[arg-type]
    out = tmp_path / "s"
    scored = CliRunner().invoke(app, ["score", str(results), "--out", str(out), "--resamples", "0"])
    assert scored.exit_code == 0, scored.output
    (warning,) = [w for w in scores_warnings(read_scores(out / "scores.csv")[0]) if "AVDN" in w]
    assert (
        "1 episode(s) visited more views" in warning and "counted: 20) allows (up to 25)" in warning
    )
