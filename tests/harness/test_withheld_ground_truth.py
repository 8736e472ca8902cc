"""A split whose ground truth is withheld (the real AVDN test_unseen keeps only each
route's start view) runs, but is never scored: `run` says so, `score` refuses it, and
`reproduce` shows "withheld" in its column where a score of failures would have been."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import yaml
from typer.testing import CliRunner

from skyvln_eval.avdn.constants import annotation_file_name
from skyvln_eval.cli import app
from skyvln_eval.errors import NoGroundTruthError
from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.metrics import read_results


def _withheld_copy(sample_dir: Path, root: Path) -> Path:
    """The sample with test_unseen cut to start views, as the real release has it."""
    root.mkdir()
    for entry in sample_dir.iterdir():
        if entry.name != "annotations":
            (root / entry.name).symlink_to(entry)
    shutil.copytree(sample_dir / "annotations", root / "annotations")
    path = root / "annotations" / annotation_file_name("test_unseen")
    records = json.loads(path.read_text())
    for record in records:
        corners = record["gt_path_corners"]
        corners = json.loads(corners) if isinstance(corners, str) else corners
        record["gt_path_corners"] = corners[:1]
    path.write_text(json.dumps(records))
    return root


def test_a_split_without_ground_truth_runs_but_is_never_scored(
    tmp_path: Path, sample_dir: Path
) -> None:
    data = _withheld_copy(sample_dir, tmp_path / "avdn")
    oracle = {"label": "GT replay (oracle)", "mode": "official", "agent": {"name": "ground_truth"}}
    agent = {"label": "Random", "mode": "official", "agent": {"name": "random"}}
    plan = {
        "name": "withheld",
        "data": str(data),
        "limit": 2,
        "resamples": 20,
        "table1": {"splits": ["val_unseen", "test_unseen"], "systems": [agent, oracle]},
        "table2": {
            "split": "test_unseen",
            "system": {"label": "NavGPT", "mode": "official", "agent": {"name": "navgpt"}},
            "backends": [{"label": "rule-based (not an LLM)", "llm": {"backend": "rule"}}],
            "environment_variable": None,
        },
        "control_figures": {"controllers": [], "cases": []},
        "trajectory_figures": 0,
    }
    plan_path = tmp_path / "plan.yaml"
    plan_path.write_text(yaml.safe_dump(plan))
    out = tmp_path / "out"
    runner = CliRunner()
    args = ["reproduce", "--plan", str(plan_path), "--out", str(out), "--workers", "1"]
    done = runner.invoke(app, [*args, "--executor", "serial"])
    assert done.exit_code == 0, done.output

    table1 = (out / "tables" / "table1.md").read_text()
    random_row = next(line for line in table1.splitlines() if line.startswith("| Random"))
    assert random_row.endswith("| withheld | withheld |"), random_row
    assert "the ground truth of Unseen Testing is withheld" in table1
    # The oracle reaches every goal: a reference, never marked best.
    oracle_row = next(line for line in table1.splitlines() if line.startswith("| GT replay"))
    assert "100.00" in oracle_row and "**" not in oracle_row
    assert "Not ranked (a reference, not a competitor): GT replay (oracle)." in table1
    table2 = (out / "tables" / "table2.md").read_text()
    assert "withheld" in table2

    # The routes were flown and recorded, but cannot be scored.
    results_file = out / "runs" / "random" / "test_unseen" / RESULTS_FILE  # runs/<system>/<split>
    rows = [r for r in read_results(results_file) if r.split == "test_unseen"]
    assert len(rows) == 2 and not any(r.has_ground_truth for r in rows)
    refused = runner.invoke(app, ["score", str(results_file)])
    assert isinstance(refused.exception, NoGroundTruthError)  # the console script: exit 2
    assert "no ground truth for 2 episode(s)" in str(refused.exception)
    run_json = json.loads((results_file.parent / "run.json").read_text())
    assert any("have no ground truth" in note for note in run_json["notes"])
