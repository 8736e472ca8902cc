"""The layout reproduce writes beside its scores (tables.json), with its interval unit."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from skyvln_eval.errors import DataError
from skyvln_eval.harness.plan import load_plan
from skyvln_eval.reports.table_layout import (
    ReproducedTables,
    TableLayout,
    read_layout,
    write_layout,
)


def test_the_interval_unit_goes_with_the_layout_and_older_files_mean_episodes(
    tmp_path: Path,
) -> None:
    layout = ReproducedTables(
        {"table1": TableLayout(("Full †",), ("a note",))}, 1000, 0, (), "trajectory"
    )
    path = write_layout(tmp_path, layout)
    assert read_layout(path) == layout
    data = json.loads(path.read_text())
    del data["ci_unit"]  # written before the field existed: its intervals were over episodes
    path.write_text(json.dumps(data))
    assert read_layout(path).ci_unit == "episode"
    path.write_text(json.dumps({**data, "ci_unit": "map"}))
    with pytest.raises(DataError, match="field 'ci_unit' must be one of episode, trajectory"):
        read_layout(path)
    assert load_plan("default").ci_unit == "trajectory"  # rounds of a dialog share a route


def test_a_table_over_a_plans_own_split_is_remade_over_it(tmp_path: Path) -> None:
    # An audit: a plan with table2.split val_unseen ran every run, then stopped before
    # Table II ("table2 is over 'test_unseen'"). Its layout says the split, and `table`
    # on its scores makes the table reproduce made.
    from typer.testing import CliRunner

    from skyvln_eval.cli import app
    from skyvln_eval.metrics import MetricConventions, score_results
    from skyvln_eval.metrics.scores_io import write_scores
    from tests.metrics.helpers import result, square

    goal = [square(0, 0), square(0, 120)]
    results = [
        result(goal, goal, system=s, split="val_unseen", episode_id=f"1913__{k}_1")
        for s in ("rule", "model")
        for k in range(2)
    ]
    conventions = MetricConventions()
    scores_dir = tmp_path / "scores"
    scores_dir.mkdir()
    write_scores(scores_dir / "scores.csv", score_results(results, conventions), conventions)
    table2 = TableLayout(("model", "rule"), (), ("val_unseen",))
    layout = ReproducedTables({"table2": table2}, 1000, 0, ())
    assert read_layout(write_layout(scores_dir, layout)) == layout
    made = CliRunner().invoke(app, ["table", str(scores_dir / "scores.csv"), "--kind", "table2"])
    assert made.exit_code == 0, made.output
    assert "Unseen Validation SR/%" in made.output and "Unseen Testing" not in made.output
