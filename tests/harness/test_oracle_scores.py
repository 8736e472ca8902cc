"""The ground-truth oracle's rows say so, through results and scores, to the table command."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pandas as pd
from typer.testing import CliRunner

from skyvln_eval.avdn import load_split
from skyvln_eval.cli import app
from skyvln_eval.harness import RunConfig, run
from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.metrics import read_results, score_results
from skyvln_eval.metrics.scores_io import read_scores

MakeConfig = Callable[..., RunConfig]
runner = CliRunner()


def test_a_table_made_from_scores_never_ranks_the_oracle(
    tmp_path: Path, small_config: MakeConfig
) -> None:
    systems = {"GT replay": "ground_truth", "Random": "random", "NavGPT-style": "navgpt"}
    for system, agent in systems.items():
        config = small_config(system=system, agent={"name": agent}, write_logs=False)
        assert run(config, tmp_path / agent).complete
    oracle_rows = read_results(tmp_path / "ground_truth" / RESULTS_FILE)
    assert [r.extra["oracle"] for r in oracle_rows] == [True, True]
    assert not any(r.extra["oracle"] for r in read_results(tmp_path / "random" / RESULTS_FILE))
    # Which detector found the landmarks: only an agent that perceives has one.
    detectors = {
        agent: {r.extra["detector"] for r in read_results(tmp_path / agent / RESULTS_FILE)}
        for agent in systems.values()
    }
    assert detectors == {"ground_truth": {None}, "random": {None}, "navgpt": {"simulated"}}

    out = tmp_path / "scores"
    runs = [str(tmp_path / agent) for agent in systems.values()]
    scored = runner.invoke(app, ["score", *runs, "--out", str(out), "--resamples", "0"])
    assert scored.exit_code == 0, scored.output
    scores, _ = read_scores(out / "scores.csv")
    by_system = scores.groupby("system")["oracle"].agg(list).to_dict()
    assert by_system == {"GT replay": [True, True], "NavGPT-style": [False, False],
                         "Random": [False, False]}  # fmt: skip
    # A label without the word says what flew it wherever the system is shown.
    # (The terminal table may wrap the label onto a second line.)
    names = [line.split("│")[1].strip() for line in scored.output.splitlines() if "│" in line]
    # NavGPT-style's LLM calls went to the rule stand-in: marked as in the tables.
    assert " ".join(names) == "GT replay (oracle) NavGPT-style † Random", names
    assert "(oracle): run by the harness's ground-truth oracle" in scored.output
    assert "† LLM modules answered by the rule-based stand-in (not an LLM)" in scored.output
    summary = pd.read_csv(out / "summary.csv", comment="#")
    assert summary.groupby("system")["oracle"].all().to_dict() == {
        "GT replay": True, "NavGPT-style": False, "Random": False}  # fmt: skip

    table = runner.invoke(app, ["table", str(out / "scores.csv"), "--kind", "table1"])
    assert table.exit_code == 0, table.output
    lines = table.output.splitlines()
    oracle = next(line for line in lines if line.startswith("| GT replay (oracle) |"))
    assert "100.00" in oracle and "**" not in oracle and "<u>" not in oracle
    # The agents are ranked among themselves: on SR the better of two is bold.
    # NavGPT-style's LLM calls were answered by the rule stand-in: its row says so.
    agents = [line for line in lines if line.startswith(("| Random |", "| NavGPT-style † |"))]
    assert len(agents) == 2 and "† LLM modules answered by the rule-based" in table.output
    assert sum("**" in line for line in agents) >= 1
    assert "Not ranked (a reference, not a competitor): GT replay (oracle)." in table.output
    assert "(oracle): run by the harness's ground-truth oracle" in table.output


def test_score_takes_a_folder_of_runs_and_refuses_options_it_would_ignore(
    tmp_path: Path, small_config: MakeConfig
) -> None:
    runs = tmp_path / "runs"  # as reproduce's runs/<system>: one run directory per split
    for split in ("val_seen", "val_unseen"):
        config = small_config(agent={"name": "random"}, splits=(split,), write_logs=False)
        assert run(config, runs / split).complete
    out = tmp_path / "scores"
    scored = runner.invoke(app, ["score", str(runs), "--out", str(out), "--resamples", "0"])
    assert scored.exit_code == 0, scored.output
    scores, _ = read_scores(out / "scores.csv")
    assert sorted(scores["split"]) == ["val_seen", "val_seen", "val_unseen", "val_unseen"]
    # Run rows carry their own split, mode and system: an option for predictions is refused.
    for option in (["--split", "val_unseen"], ["--system", "renamed"], ["--mode", "andh-full"]):
        refused = runner.invoke(app, ["score", str(runs), "--out", str(out), *option])
        assert "only for predictions files" in str(refused.exception)
    typo = runner.invoke(app, ["score", str(runs), "--out", str(out), "--mode", "andhh"])
    assert "--mode must be 'andh' or 'andh-full'" in str(typo.exception)
    # Table II is over test_unseen, which these scores lack: an error, not a table of dashes.
    table2 = runner.invoke(app, ["table", str(out / "scores.csv"), "--kind", "table2"])
    assert "table2 is over 'test_unseen'" in str(table2.exception)


def test_an_andh_full_run_gives_each_round_its_views_and_replays_every_route(
    tmp_path: Path, small_config: MakeConfig
) -> None:
    # An audit: with one round's 10 views for the whole dialog, the replay of val_unseen's
    # first trajectories scored SR 66.7% (a 15-view route ran out of views).
    config = small_config(
        system="GT replay", episode_mode="andh-full", limit=3, agent={"name": "ground_truth"}
    )
    run(config, tmp_path / "run")
    rows = read_results(tmp_path / "run" / RESULTS_FILE)
    assert len(rows) == 3 and any(len(r.visited_views) > 10 for r in rows)
    dialogs = {e.episode_id: e for e in load_split(config.data, "val_unseen").episodes("andh-full")}
    assert all(r.extra["rounds_flown"] == len(dialogs[r.episode_id].records) for r in rows)
    assert all(len(r.visited_views) <= 10 * r.extra["rounds_flown"] for r in rows)
    scores = score_results(rows)
    assert scores["success"].tolist() == [1.0, 1.0, 1.0]
