"""One way to make Table I and II from scores: `table`, `reproduce` and notebooks agree.

A review found `skyvln-eval table` summarising only the table's own columns: Table I of
a dead endpoint showed SR 0.00 with no 'error' (the cells' error counts come from
``status_error``), Table II showed 'n/a' where `reproduce` showed a cost's lower bound,
and ranked the rule stand-in as the best backend; rows over different numbers of
episodes, and costs replayed from the cache, were not told.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from skyvln_eval.cli import app
from skyvln_eval.errors import MetricInputError
from skyvln_eval.llm_records import LlmCall
from skyvln_eval.metrics import MetricConventions, score_results
from skyvln_eval.metrics.scores_io import read_scores, write_scores
from skyvln_eval.reports import TABLE_I, TABLE_II, paper_table, to_markdown
from skyvln_eval.reports.paper_tables import oracle_label
from tests.metrics.helpers import result, square

GOAL = [square(0, 0), square(0, 120)]


def _call(cached: bool = False, ok: bool = True) -> LlmCall:
    if not ok:
        return LlmCall(
            module="action", backend="openai", model="m", outcome="failed", error="HTTP 500"
        )
    return LlmCall(
        module="action",
        backend="openai",
        model="m",
        prompt_tokens=100,
        completion_tokens=10,
        cost_usd=0.001,
        latency_s=0.5,
        cached=cached,
    )


def _scores() -> pd.DataFrame:
    """test_unseen: a model (2 episodes, half its calls from the cache), the rule
    stand-in (3 episodes, best SR) and a dead endpoint (2 episodes, all error)."""
    results = []
    for k in range(2):
        results.append(
            result(
                [square(0, 0), square(0, 60), square(0, 120)],
                GOAL,
                system="gemma",
                split="test_unseen",
                episode_id=f"1913__{k}_1",
                extra={
                    "llm_backend": "openai:gemma",
                    "questions": [{"step": 0, "answer": "go north"}] * k,
                },
                llm_calls=(_call(), _call(cached=True)),
            )
        )
        results.append(
            result(
                [square(0, 0)],
                GOAL,
                "error",
                system="dead",
                split="test_unseen",
                episode_id=f"1913__{k}_1",
                extra={"llm_backend": "openai:dead"},
                llm_calls=(_call(ok=False),),
            )
        )
    for k in range(3):
        results.append(
            result(
                GOAL,
                GOAL,
                system="rule",
                split="test_unseen",
                episode_id=f"1913__{k}_1",
                extra={"llm_backend": "rule"},
            )
        )
    return score_results(results, MetricConventions())


def test_table_ii_marks_errors_references_unequal_episodes_and_cache_replays() -> None:
    table = paper_table(_scores(), TABLE_II, MetricConventions())
    md = to_markdown(table)
    assert "| dead | error | error | error |" in md
    rule = table.cells["rule †"][("test_unseen", "success")]
    assert rule is not None and rule.mean == 100.0 and rule.rank is None  # a reference
    assert "Not ranked (a reference, not a competitor): rule †." in md
    assert "† LLM modules answered by the rule-based stand-in (not an LLM)." in md
    assert "Unseen Testing: gemma 2, dead 2, rule † 3." in md
    # A label that says what answered it (reproduce's Table II rows) is not marked again.
    named = _scores().replace({"system": {"rule": "rule-based (not an LLM)"}})
    again = to_markdown(paper_table(named, TABLE_II, MetricConventions()))
    assert "| rule-based (not an LLM) |" in again and "† LLM modules" not in again
    assert "Replayed from the response cache" in md and "gemma on Unseen Testing: 50%" in md
    assert "answered by the simulated commander, who knows the goal" in md
    assert "gemma 1 in 1 of 2 episodes" in md
    # Over another split (an audit compared backends on val_seen: refused, no way round):
    # the same table, its rule row still a reference and the dead endpoint's cells 'error'.
    on_seen = _scores().assign(split="val_seen")
    with pytest.raises(MetricInputError, match=r"only 'val_seen' \(a spec's \.over"):
        paper_table(on_seen, TABLE_II, MetricConventions())
    seen = to_markdown(paper_table(on_seen, TABLE_II.over("val_seen"), MetricConventions()))
    assert "Seen Validation SR/%" in seen and "Unseen Testing" not in seen
    assert "| dead | error | error | error |" in seen and "Not ranked" in seen
    with pytest.raises(MetricInputError, match="splits must be some of"):
        TABLE_II.over("validation")
    # Questions it did not answer (max_questions spent, or 0) were no help: no note.
    unanswered = _scores().assign(questions_answered=0.0)
    assert "simulated commander" not in to_markdown(
        paper_table(unanswered, TABLE_II, MetricConventions())
    )


def test_table_i_marks_a_stand_in_row_and_says_why() -> None:
    scores = _scores().replace({"split": {"test_unseen": "val_seen"}})
    table = paper_table(scores, TABLE_I, MetricConventions())
    assert "rule †" in table.rows and "gemma" in table.rows
    md = to_markdown(table)
    assert "† LLM modules answered by the rule-based stand-in (not an LLM)." in md
    assert "| dead | error | error |" in md
    # A label that already carries the marker (reproduce's) is not marked twice.
    marked = scores.replace({"system": {"rule": "Full †"}})
    again = paper_table(marked, TABLE_I, MetricConventions(), rows=["Full †", "gemma"])
    assert again.rows == ("Full †", "gemma")
    assert to_markdown(again).count("† LLM modules") == 1
    # A row on a real model says which, as reproduce's rows do (the row "Flaky" did not).
    flaky = scores.replace({"system": {"gemma": "Flaky"}})
    named = paper_table(flaky, TABLE_I, MetricConventions(), rows=["Flaky", "rule"])
    assert named.rows == ("Flaky (openai:gemma)", "rule †")
    assert "| dead | error | error |" in to_markdown(
        paper_table(flaky, TABLE_I, MetricConventions())
    )
    # The models' table (over test_unseen) does not rename its rows.
    models = _scores().replace({"system": {"gemma": "Flaky"}})
    assert "Flaky" in paper_table(models, TABLE_II, MetricConventions()).rows
    # Over scores without test_unseen it would be a table of dashes: refused, saying why.
    with pytest.raises(MetricInputError, match="table2 is over 'test_unseen'"):
        paper_table(flaky, TABLE_II, MetricConventions())


def test_the_table_command_makes_the_same_table(tmp_path: Path) -> None:
    path = tmp_path / "scores.csv"
    write_scores(path, _scores(), MetricConventions())
    assert read_scores(path)[0]["llm_backend"].tolist()[:1] == ["openai:dead"]
    outcome = CliRunner().invoke(app, ["table", str(path), "--kind", "table2"])
    assert outcome.exit_code == 0, outcome.output
    back, conventions = read_scores(path)
    assert outcome.output == to_markdown(paper_table(back, TABLE_II, conventions))
    assert "| dead | error | error | error |" in outcome.output
    table1 = CliRunner().invoke(
        app, ["table", str(path), "--kind", "table1"]
    )  # test_unseen only: SR/SPL columns of Unseen Testing
    assert table1.exit_code == 0, table1.output
    assert "| dead | - | - | - | - | error | error |" in table1.output


def test_scores_without_the_backend_column_read_and_rank_as_labelled(tmp_path: Path) -> None:
    # Files scored before results said what answered the LLM calls: no stand-in is known.
    path = tmp_path / "scores.csv"
    scores = _scores().drop(columns=["llm_backend"])
    # Every row over 2 episodes: rows over different numbers are not marked at all.
    scores = scores[~((scores["system"] == "rule") & (scores["episode_id"] == "1913__2_1"))]
    write_scores(path, scores, MetricConventions())
    back, conventions = read_scores(path)
    assert back["llm_backend"].isna().all()
    table = paper_table(back, TABLE_II, conventions)
    rule = table.cells["rule"][("test_unseen", "llm_cost_usd")]
    assert rule is not None and rule.rank == 1  # ranked: nothing says it is a stand-in
    assert "Not ranked" not in to_markdown(table)
    # Ranked rows over different numbers of episodes (rule 3, gemma 2) are not marked:
    # an audit found a row of 4 episodes marked best over one of 8.
    unequal = paper_table(_scores().drop(columns=["llm_backend"]), TABLE_II, conventions)
    md = to_markdown(unequal)
    assert all(cell is None or cell.rank is None for cell in unequal.cells["rule"].values())
    assert "**" not in md and "<u>" not in md
    assert "No best or second marked on Unseen Testing: its rows ran different" in md


def test_table_i_says_how_many_flights_crashed_and_how_they_were_scored() -> None:
    # An audit found a controller row with 29 of 30 flights crashed reading as an SR of
    # 30%, crashes landing in the destination's view scored as successes with SPL 1.
    from skyvln_eval.metrics import summarise_control
    from tests.metrics.test_safety_and_cost import control_log

    crashed = summarise_control(control_log("pid", "dynamic"))
    results = [
        result(GOAL, GOAL, system="w PID", episode_id=f"1913__{k}_1", control=crashed)
        for k in range(2)
    ] + [result(GOAL, GOAL, system="w PID", episode_id="1913__9_1")]
    scores = score_results(results, MetricConventions())
    md = to_markdown(paper_table(scores, TABLE_I, MetricConventions()))
    assert "| w PID | 33.33 | 33.33 |" in md  # the two crashed flights failed
    assert (
        "Episodes whose flight touched an obstacle, which count as failures (0 in SR and "
        "SPL; distances as flown, to the crash): w PID on Seen Validation 2 of 3." in md
    )
    lenient = MetricConventions(collision_fails=False)
    on_views = to_markdown(paper_table(score_results(results, lenient), TABLE_I, lenient))
    assert "| w PID | 100.00 | 100.00 |" in on_views
    assert "are scored on their views alone (--collisions-succeed)" in on_views


def test_a_stand_in_row_whose_marked_label_another_system_has_is_refused() -> None:
    # An audit tabled reproduce's scores ('w PID †') with its own rule-backend run 'w PID':
    # marked, the two became one row pooling both runs' episodes.
    import pytest

    from skyvln_eval.errors import MetricInputError

    scores = _scores().replace({"system": {"gemma": "rule †"}})
    with pytest.raises(MetricInputError, match=r"as 'rule †' \(it ran on a stand-in\), the label"):
        paper_table(scores, TABLE_I, MetricConventions())


def test_a_table_shows_itself_in_jupyter_as_its_markdown() -> None:
    table = paper_table(_scores(), TABLE_II, MetricConventions())
    assert table._repr_markdown_() == to_markdown(table)


def test_trajectory_intervals_say_how_many_trajectories_they_rest_on() -> None:
    scores = _scores()
    # The default, as summarise's, score's and table's: a dialog's rounds drawn together.
    md = to_markdown(paper_table(scores, TABLE_II, MetricConventions(), show_ci=True))
    assert "each over 2 to 3 trajectories" in md  # gemma and dead 2 dialogs, rule 3
    plain = to_markdown(
        paper_table(scores, TABLE_II, MetricConventions(), show_ci=True, ci_unit="episode")
    )
    assert "trajector" not in plain.split("Brackets")[1]


def test_degraded_episodes_are_counted_in_a_note() -> None:
    # Scored as flown, they are in the cell's numbers without a mark: the note says so.
    degraded = result(
        GOAL,
        GOAL,
        "degraded",
        system="gemma",
        split="test_unseen",
        episode_id="1913__2_1",
        extra={"llm_backend": "openai:gemma"},
        llm_calls=(_call(),),
    )
    scores = pd.concat([_scores(), score_results([degraded], MetricConventions())])
    md = to_markdown(paper_table(scores, TABLE_II, MetricConventions()))
    assert "Degraded episodes (a module's answer was unusable" in md
    assert "scored as flown): gemma on Unseen Testing 1 of 3." in md
    assert "Degraded episodes" not in to_markdown(
        paper_table(_scores(), TABLE_II, MetricConventions())
    )


def test_an_oracle_row_is_marked_unless_its_name_carries_the_mark() -> None:
    assert oracle_label("GT replay (oracle)") == "GT replay (oracle)"
    assert oracle_label("GT replay") == "GT replay (oracle)"
    # Containing the word is not the mark: the audit's row showed SR 100 unmarked.
    assert oracle_label("Non-oracle planner") == "Non-oracle planner (oracle)"


def test_rows_whose_landmarks_the_simulated_detector_found_say_so() -> None:
    # An audit: the simulated detector labels the simulator's landmark segmentation with
    # its true categories; a table did not say which rows rested on it.
    results = [
        result(
            [square(0, 0), square(0, 60)],
            GOAL,
            system=system,
            split="val_seen",
            episode_id=f"1913__{k}_1",
            extra={"detector": detector},
        )
        for system, detector in (
            ("Full", "simulated"),
            ("DINO", "grounding_dino:models/tiny"),
            ("PID", None),
        )
        for k in range(2)
    ]
    scores = score_results(results)
    said = scores.drop_duplicates("system").set_index("system").detector
    assert said["Full"] == "simulated" and said["DINO"] == "grounding_dino:models/tiny"
    assert pd.isna(said["PID"])
    md = to_markdown(paper_table(scores, TABLE_I, MetricConventions()))
    note = next(line for line in md.splitlines() if "simulated detector" in line)
    assert note.endswith("not a detector on pixels (Full).")
    # A detector on pixels is named with its weights (an audit: a random checkpoint's
    # rows read as a trained detector's, the model said nowhere).
    assert (
        "Landmarks found on the camera's RGB pixels by GroundingDINO, weights models/tiny (DINO)."
        in md
    )
    # Scores made before the column: nothing is said.
    assert "simulated detector" not in to_markdown(
        paper_table(scores.drop(columns="detector"), TABLE_I, MetricConventions())
    )
