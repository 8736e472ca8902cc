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
