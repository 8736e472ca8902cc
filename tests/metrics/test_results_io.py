"""EpisodeResult files: lossless round trips, version checks, located errors."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from skyvln_eval.errors import DataError, FormatVersionError, ResultRecordError
from skyvln_eval.llm_records import ModuleFailure
from skyvln_eval.metrics import ControlSummary, LlmCall, read_results, write_results
from tests.metrics.helpers import result, square


def rich_results() -> list:
    rng = np.random.default_rng(0)
    control = ControlSummary(
        controller="nmpc", scenario="dynamic", steps=120, duration_s=11.9, collision_steps=0,
        min_clearance_m=1.25, constraint_violation_steps=0, solve_failures=1,
        rmse_x_m=0.1, rmse_y_m=0.2, rmse_z_m=0.05, rmse_roll_rad=0.01, rmse_pitch_rad=0.02,
        rmse_yaw_rad=0.03, solve_time_mean_ms=0.4, solve_time_p50_ms=0.35,
        solve_time_p95_ms=0.9, solve_time_max_ms=2.5,
    )  # fmt: skip
    calls = (
        LlmCall(
            module="subgoals",
            backend="openai",
            model="gpt-4o",
            prompt_tokens=812,
            completion_tokens=64,
            cost_usd=0.0031,
            latency_s=1.7,
            temperature=0.0,
            max_tokens=1024,
            finish_reason="stop",
            structured_output="json_schema",
        ),
        LlmCall(
            module="motion",
            backend="rule",
            model="rule-v1",
            outcome="failed",
            error="timeout",
            attempt=2,
            final=False,
            latency_s=0.001,
            queue_s=0.25,
        ),
        LlmCall(
            module="motion",
            backend="rule",
            model="rule-v1",
            outcome="invalid",
            error="invalid output: not JSON",
            repair=True,
            prompt_tokens=3,
            completion_tokens=None,
            cached=True,
        ),
    )
    failures = (
        ModuleFailure(step_index=2, module="motion", reason="no JSON", substitute="stop action"),
    )
    views = np.stack([square(*rng.normal(0, 50, 2), 100) for _ in range(4)]) + rng.normal(
        0, 1e-9, (4, 4, 2)
    )
    return [
        result(views, views[[0, 3]], control=control, control_log="logs/a.parquet", llm_calls=calls,
               decisions=3, module_failures=failures, status="degraded",
               extra={"seed": 3, "config": {"hsd": True}}),
        result(np.zeros((0, 4, 2)), views[:1], status="error", error="controller diverged",
               episode_id="1913__1_2", system="w/o HSD"),
    ]  # fmt: skip


@pytest.mark.parametrize("suffix", [".jsonl", ".parquet"])
def test_results_round_trip_bit_for_bit(tmp_path: Path, suffix: str) -> None:
    results = rich_results()
    path = tmp_path / f"run{suffix}"
    write_results(path, results)
    back = read_results(path)
    assert back == results
    assert back[0].visited_views.tobytes() == results[0].visited_views.tobytes()
    first = path.read_bytes()
    write_results(path, back)
    assert path.read_bytes() == first  # byte-identical for identical input


def test_version_and_format_are_checked(tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    write_results(path, rich_results())
    lines = path.read_text().splitlines()
    lines[0] = json.dumps({"format": "skyvln-eval.episode-results", "version": 99})
    path.write_text("\n".join(lines))
    with pytest.raises(FormatVersionError, match="99"):
        read_results(path)
    path.write_text("{}\n")
    with pytest.raises(DataError, match="not an episode-results file"):
        read_results(path)
    path.write_bytes(b'{"format": 1}\n\x89PNG\r\n')  # not text: a message, not a traceback
    with pytest.raises(DataError, match=r"not UTF-8 text: byte 0x89 on line 2"):
        read_results(path)


def test_bad_rows_are_located(tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    write_results(path, rich_results())
    lines = path.read_text().splitlines()
    row = json.loads(lines[2])
    row["status"] = "crashed"
    lines[2] = json.dumps(row)
    path.write_text("\n".join(lines))
    with pytest.raises(
        ResultRecordError,
        match=r"run.jsonl, record 1 on line 3 \(episode 1913__1_2\), field 'status'",
    ):
        read_results(path)
    row["status"] = "error"
    row["llm_calls"] = [{"module": "motion", "backend": "x", "model": "y", "prompt_tokens": -1,
                         "completion_tokens": 0, "cost_usd": 0.0, "latency_s": 0.0}]  # fmt: skip
    lines[2] = json.dumps(row)
    path.write_text("\n".join(lines))
    with pytest.raises(ResultRecordError, match=r"llm_calls\[0\]\.prompt_tokens"):
        read_results(path)
    row["llm_calls"] = []
    # [lng, lat] for [lat, lng] (San Francisco): scored, NE was 25,215 km.
    row["gt_path_corners"][0] = [[-122.4, 37.7], [-122.4, 37.8], [-122.3, 37.8], [-122.3, 37.7]]
    lines[2] = json.dumps(row)
    path.write_text("\n".join(lines))
    with pytest.raises(ResultRecordError, match=r"gt_path_corners\[0\]\[0\]\[0\].*swapped"):
        read_results(path)
    square = [[37.7, -122.4], [37.8, -122.4], [37.8, -122.3], [37.7, -122.3]]
    row["gt_path_corners"] = [square, square[:3]]  # its second view has three corners
    lines[2] = json.dumps(row)
    path.write_text("\n".join(lines))
    with pytest.raises(
        ResultRecordError, match=r"gt_path_corners\[1\].*4 \[lat, lng\] corners, got 3"
    ):
        read_results(path)
    lines[2] = "[1, 2]"  # the record itself is wrong: no field to name, and none named
    path.write_text("\n".join(lines))
    with pytest.raises(ResultRecordError) as not_an_object:
        read_results(path)
    assert "field" not in str(not_an_object.value)
    assert "record 1 on line 3: expected a JSON object, got list" in str(not_an_object.value)
    row["gt_path_corners"] = [square]
    full = json.loads(lines[1])["control"]
    assert full is not None
    for control, message in (
        ("fast", "field 'control': must be a JSON object or null"),
        ({"controller": "nmpc"}, r"field 'control': missing required key\(s\) \['scenario'"),
        ({**full, "speed": 1}, r"field 'control': unknown key\(s\) \['speed'\]"),
    ):  # a TypeError inside: the field was named nowhere
        lines[2] = json.dumps({**row, "control": control})
        path.write_text("\n".join(lines))
        with pytest.raises(ResultRecordError, match=message):
            read_results(path)


def test_a_last_row_cut_short_says_it_was_a_killed_write_and_what_to_do(tmp_path: Path) -> None:
    # An audit: "record 3 on line 5: not valid JSON", with no cause and no way out.
    path = tmp_path / "results.jsonl"
    write_results(path, rich_results())
    text = path.read_text()
    path.write_text(text[: len(text) - 40])  # the last row's write cut short
    with pytest.raises(DataError, match=r"has no line end: a write cut short.*resume the run"):
        read_results(path)
    lines = text.splitlines()  # a broken row with its line end is no cut write: not said
    lines[1] = lines[1][:30]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError) as refused:
        read_results(path)
    assert "not valid JSON" in str(refused.value) and "cut short" not in str(refused.value)


def test_duplicates_and_unknown_suffixes_are_refused(tmp_path: Path) -> None:
    one = rich_results()[0]
    with pytest.raises(ResultRecordError, match="duplicate"):
        write_results(tmp_path / "x.jsonl", [one, one])
    with pytest.raises(DataError, match="unknown results format"):
        write_results(tmp_path / "x.csv", [one])


def test_a_row_that_only_records_the_run_stopping_is_no_episode(tmp_path: Path) -> None:
    # An audit read a run stopped by an HTTP 401 with read_results: the stop row came
    # back as an ordinary 'error' episode, and the episodes that never ran were invisible.
    from skyvln_eval.errors import IncompleteRunError

    g = [square(0, 0), square(100, 0)]
    rows = [
        result(g, g, episode_id="e0"),
        result(g[:1], g, episode_id="e1", status="error", extra={"fatal": "HTTP 401: refused"}),
    ]
    path = tmp_path / "results.jsonl"
    write_results(path, rows)
    with pytest.raises(IncompleteRunError) as stopped:
        read_results(path)
    message = str(stopped.value)
    assert f"results file {path} is incomplete: 1 missing episode(s): val_seen/e1" in message
    assert "only record that the run stopped there (HTTP 401: refused)" in message
    assert "allow_incomplete=True" in message and "run_results" in message
    assert [r.episode_id for r in read_results(path, allow_incomplete=True)] == ["e0"]


def test_a_directory_is_not_a_missing_file(tmp_path: Path) -> None:
    with pytest.raises(DataError) as folder:
        read_results(tmp_path)
    assert f"{tmp_path}: a directory, not a results file; pass the file in it " in str(folder.value)
    assert str(tmp_path / "results.jsonl") in str(folder.value)
    assert "run_results" in str(folder.value)


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        # A path without its start view was scored as a shorter path: a higher SPL.
        (lambda row: row["visited_views"].pop(0), r"field 'visited_views\[0\]': must be the"),
        # Scores are made of these: a hand edit was a traceback in score.
        (lambda row: row["extra"].update(wall_s="slow"), r"'extra.wall_s': must be a number"),
        (lambda row: row["extra"].update(wall_s=-100), r"'extra.wall_s': must be a number"),
        (lambda row: row["extra"].update(questions="abc"), r"'extra.questions': must be a list"),
        (lambda row: row["extra"].update(oracle="no"), r"'extra.oracle': must be true or false"),
        (lambda row: row["extra"].update(llm_backend=5), r"'extra.llm_backend': must be a str"),
        (
            lambda row: row.update(error="boom"),
            r"'error': the episode is 'degraded', which has no error",
        ),
    ],
    ids=["no-start", "wall-text", "wall-negative", "questions", "oracle", "backend", "error"],
)
def test_rows_whose_scores_would_be_wrong_are_refused_naming_line_and_field(
    tmp_path: Path, edit: Any, needle: str
) -> None:
    path = tmp_path / "run.jsonl"
    write_results(path, rich_results())
    lines = path.read_text().splitlines()
    row = json.loads(lines[1])
    edit(row)
    lines[1] = json.dumps(row)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ResultRecordError, match=r"run.jsonl, record 0 on line 2 .*" + needle):
        read_results(path)


def test_a_key_given_twice_or_an_unreadable_number_is_no_usable_row(tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    write_results(path, rich_results())
    lines = path.read_text().splitlines()
    twice = lines[1].replace('"status": "degraded"', '"status": "error", "status": "degraded"')
    assert twice != lines[1]
    huge = lines[1].replace('"decisions": 3', '"decisions": ' + "9" * 5000)
    for line, needle in ((twice, "the key 'status' is given twice"), (huge, "Exceeds the limit")):
        path.write_text("\n".join([lines[0], line, *lines[2:]]) + "\n")
        with pytest.raises(ResultRecordError, match=rf"line 2: not usable JSON: .*{needle}"):
            read_results(path)
