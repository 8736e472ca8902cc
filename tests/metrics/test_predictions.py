"""Predictions made elsewhere: the official .npy (safely unpickled), JSON, ground truth."""

from __future__ import annotations

import io
import json
import os
import pickle
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from skyvln_eval.avdn import hull_iou, point_in_view_strict
from skyvln_eval.errors import (
    DataError,
    IncompleteRunError,
    NoGroundTruthError,
    ResultRecordError,
    UnsafePickleError,
)
from skyvln_eval.metrics import (
    ground_truth_episodes,
    read_predictions,
    results_from_predictions,
    score_results,
    summarise,
    write_predictions_json,
)
from tests.conftest import FIXTURES, REPO, SHARED_FIXTURES, make_record

FULL_ROLLOUTS = "avdn_test_unseen_official_rollouts.json"


def load_rollouts() -> list[dict[str, Any]]:
    """All 897 official rollouts from ../shared (beside a clone, or two levels up from a
    worktree), else the project's 40-episode copy of them."""
    for folder in (SHARED_FIXTURES, REPO.parents[1] / "shared" / "fixtures"):
        if (folder / FULL_ROLLOUTS).is_file():
            return json.loads((folder / FULL_ROLLOUTS).read_text())
    return json.loads((FIXTURES / "avdn_official_rollouts_subset.json").read_text())


def save_official_npy(path: Path, rollouts: list[dict[str, Any]]) -> None:
    """Write rollouts as the official agent does: np.save of {instr_id: defaultdict}."""
    results = {}
    for ep in rollouts:
        traj: defaultdict[str, Any] = defaultdict(list)
        traj["instr_id"] = ep["instr_id"]
        traj["num_dia"] = ep["num_dia"]
        traj["path_corners"] = [
            (np.array(corners), np.int64(heading) if k else int(heading))
            for k, (corners, heading) in enumerate(
                zip(ep["path_corners"], ep["path_headings"], strict=True)
            )
        ]
        traj["gt_path_corners"] = [np.array(ep["start_view"])]
        for action in ep["actions"]:
            traj["actions"].append(
                [np.array(action["waypoint"], np.float32), np.float32(action["altitude"])]
            )
        traj["progress"] = [float(p) for p in ep["progress"]]
        results[ep["instr_id"]] = traj
    np.save(path, results, allow_pickle=True)


def test_official_rollouts_score_end_to_end_through_the_official_reader(tmp_path: Path) -> None:
    rollouts = load_rollouts()
    path = tmp_path / "output_test_result.npy"
    save_official_npy(path, rollouts)
    predictions = read_predictions(path)
    assert len(predictions) == len(rollouts)
    # The start as its own goal (the real test_unseen withholds the rest of the route).
    gt = {ep["instr_id"]: np.array([ep["start_view"]] * 2) for ep in rollouts}
    results = results_from_predictions(predictions, gt, "official ET-HAA", "test_unseen")
    scores = score_results(results)
    # Independent per-episode check with the dense official functions.
    for ep, row in zip(rollouts, scores.itertuples(), strict=True):
        last, goal = np.array(ep["path_corners"][-1]), np.array(ep["start_view"])
        iou = hull_iou(last, goal)
        success = (
            iou >= 0.4
            and point_in_view_strict(goal.mean(0), last)
            and point_in_view_strict(last.mean(0), goal)
        )
        assert row.success == float(success), ep["instr_id"]
        # The scorer works relative to the view (shapely on absolute degrees near 46 N
        # rounds at ~4e-12 here); decisions near the 0.4 threshold use shapely itself.
        assert row.final_iou == pytest.approx(iou, abs=1e-11)
        assert row.n_views == len(ep["path_corners"])
    # The start is visited and is the goal, so every episode is an oracle success; D_net = 0.
    assert scores.oracle_success.eq(1.0).all()
    assert scores.spl.eq(0.0).all()
    summary = summarise(scores, ["success", "ne_m"]).set_index("metric")
    assert 0 < summary.loc["success", "mean"] < 100
    assert summary.loc["success", "n"] == len(rollouts)


def test_a_malicious_pickle_is_refused_without_running(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"

    class Evil:
        def __reduce__(self) -> tuple:
            return (os.system, (f"touch {marker}",))

    class EvilEval:  # a builtin, but not one of the allowed constructors
        def __reduce__(self) -> tuple:
            return (eval, (f"open({str(marker)!r}, 'w')",))

    for payload, name in ((Evil(), "system"), (EvilEval(), "builtins.eval")):
        buf = io.BytesIO()
        np.lib.format.write_array_header_1_0(
            buf, {"descr": "|O", "fortran_order": False, "shape": ()}
        )
        pickle.dump({"1__1_1": {"path_corners": [payload]}}, buf, protocol=3)
        path = tmp_path / "evil.npy"
        path.write_bytes(buf.getvalue())  # the header writer includes the magic
        with pytest.raises(UnsafePickleError, match=name):
            read_predictions(path)
        assert not marker.exists()


def test_json_predictions_round_trip_and_completeness(tmp_path: Path) -> None:
    rollouts = load_rollouts()[:5]
    npy = tmp_path / "p.npy"
    save_official_npy(npy, rollouts)
    predictions = read_predictions(npy)
    path = tmp_path / "p.json"
    write_predictions_json(path, predictions)
    back = read_predictions(path)
    assert list(back) == list(predictions)
    for key in back:
        np.testing.assert_array_equal(back[key].path_corners, predictions[key].path_corners)
    gt = {ep["instr_id"]: np.array([ep["start_view"]]) for ep in rollouts}
    gt["9999__1_1"] = gt[rollouts[0]["instr_id"]]
    del back[rollouts[1]["instr_id"]]
    with pytest.raises(
        IncompleteRunError, match=f"2 missing episode\\(s\\): {rollouts[1]['instr_id']}, 9999__1_1"
    ):
        results_from_predictions(back, gt, "x", "test_unseen")


def test_json_predictions_say_which_episodes_failed_and_nothing_of_llm_costs(
    tmp_path: Path,
) -> None:
    """An 'error' episode (with or without its text, with or without views) is scored as a
    failure and keeps its reason; the LLM columns of predictions are unknown, not 0."""
    rollouts = load_rollouts()[:3]
    start = {ep["instr_id"]: ep["start_view"] for ep in rollouts}
    ids = list(start)
    data = {
        "format": "skyvln-eval.predictions",
        "version": 1,
        "episodes": {
            ids[0]: {"path_corners": [start[ids[0]]]},
            ids[1]: {"path_corners": [], "status": "error", "error": "agent crashed"},
            ids[2]: {"path_corners": [start[ids[2]]], "status": "error"},
        },
    }
    path = tmp_path / "p.json"
    path.write_text(json.dumps(data))
    predictions = read_predictions(path)
    assert predictions[ids[1]].error == "agent crashed"
    assert predictions[ids[2]].error == f"status 'error' in {path}"
    write_predictions_json(tmp_path / "again.json", predictions)
    again = read_predictions(tmp_path / "again.json")
    assert [(p.status, p.error) for p in again.values()] == [
        (p.status, p.error) for p in predictions.values()
    ]
    gt = {eid: np.array([view, view]) for eid, view in start.items()}
    scores = score_results(results_from_predictions(predictions, gt, "ext", "test_unseen"))
    assert scores.set_index("episode_id").loc[ids[1:], "success"].tolist() == [0.0, 0.0]
    for column in ("llm_cost_usd", "llm_latency_s", "llm_calls", "questions_asked"):
        assert scores[column].isna().all(), column
    summary = summarise(scores, ["llm_cost_usd", "llm_latency_s"], n_resamples=0, warn_errors=False)
    assert summary["mean"].isna().all() and list(summary["n"]) == [3, 3]

    data["episodes"][ids[0]]["error"] = "but it says ok"
    path.write_text(json.dumps(data))
    with pytest.raises(ResultRecordError, match=r"field 'error'.*needs status 'error'"):
        read_predictions(path)


def test_real_test_unseen_without_ground_truth_cannot_be_scored(
    dataset_factory: Callable[..., Path],
) -> None:
    root = dataset_factory(
        {"test_unseen": [make_record(n_views=1), make_record(route_index="1_1", n_views=1)]}
    )
    with pytest.raises(NoGroundTruthError, match="no ground truth for 2 episode"):
        ground_truth_episodes(root, "test_unseen")
    root = dataset_factory({"val_seen": [make_record()]})
    assert [e.episode_id for e in ground_truth_episodes(root, "val_seen")] == ["1913__0_1"]


def test_json_predictions_refuse_what_json_reads_as_another_number(tmp_path: Path) -> None:
    # A `true` corner scored as 1.0 degree (a path of 2,046 km), "37.77" as 37.77, and an
    # episode listed twice kept its last entry: each scored without a word.
    rollouts = load_rollouts()[:2]
    npy = tmp_path / "p.npy"
    save_official_npy(npy, rollouts)
    path = tmp_path / "p.json"
    write_predictions_json(path, read_predictions(npy))
    good = json.loads(path.read_text())
    first = rollouts[0]["instr_id"]
    for bad, shown in ((True, "true"), ("37.77", "string '37.77'")):
        data = json.loads(json.dumps(good))
        data["episodes"][first]["path_corners"][0][2][1] = bad
        path.write_text(json.dumps(data))
        with pytest.raises(ResultRecordError) as info:
            read_predictions(path)
        message = str(info.value)
        assert "field 'path_corners[0][2][1]'" in message and str(path) in message
        assert f"expected a number, got {shown}" in message
    text = json.dumps(good)
    entry = json.dumps(good["episodes"][first])
    path.write_text(text.replace(f'"{first}": {entry}', f'"{first}": {entry}, "{first}": {entry}'))
    with pytest.raises(DataError, match=f"'episodes' lists episode\\(s\\) more than once: {first}"):
        read_predictions(path)
    path.write_text(text.replace('"status": ', '"status": "error", "status": ', 1))
    with pytest.raises(DataError, match="key\\(s\\) given more than once: status"):
        read_predictions(path)


def test_prediction_errors_name_the_file_and_the_view(tmp_path: Path) -> None:
    rollouts = json.loads(json.dumps(load_rollouts()[:2]))
    first = rollouts[0]["instr_id"]
    # A view of 4x3 numbers in an official .npy was "path_corners[0] ... got ndarray".
    rollouts[0]["path_corners"][1] = [[*corner, 0.0] for corner in rollouts[0]["path_corners"][1]]
    npy = tmp_path / "p.npy"
    save_official_npy(npy, rollouts)
    with pytest.raises(ResultRecordError) as info:
        read_predictions(npy)
    message = str(info.value)
    assert str(npy) in message and "field 'path_corners[1]'" in message
    assert "a view is 4 [lat, lng] corners, got an array of shape (4, 3)" in message
    # An 'ok' path without even its start view: the file's problem, said as such.
    path = tmp_path / "p.json"
    path.write_text(
        json.dumps(
            {"format": "skyvln-eval.predictions", "version": 1,
             "episodes": {first: {"path_corners": [], "status": "ok"}}}
        )
    )  # fmt: skip
    with pytest.raises(ResultRecordError, match="at least its start view") as empty:
        read_predictions(path)
    assert str(path) in str(empty.value)
    # A path that starts elsewhere names the file too.
    good = load_rollouts()[:1]
    save_official_npy(npy, good)
    elsewhere = {good[0]["instr_id"]: np.array([good[0]["start_view"]]) + 0.01}
    with pytest.raises(DataError, match="does not begin with the episode's start view") as moved:
        results_from_predictions(read_predictions(npy), elsewhere, "x", "test_unseen")
    assert f"predictions of 'x' on test_unseen ({npy})" in str(moved.value)


def test_a_number_python_will_not_read_is_no_predictions_file(tmp_path: Path) -> None:
    # An integer of 5000 digits was a raw ValueError traceback.
    path = tmp_path / "preds.json"
    path.write_text('{"format": "skyvln-eval.predictions", "version": ' + "1" * 5000 + "}")
    with pytest.raises(DataError, match=r"preds.json: not valid JSON \(Exceeds the limit"):
        read_predictions(path)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (  # one corner moved 0.001 degrees: scored SR 1
            lambda v: v[0].__setitem__(0, v[0][0] + 0.001),
            "view is not square (sides 183.1, 100.0, 100.0, 204.1 m, diagonals 250.6, 141.4 m)",
        ),
        (  # four identical corners: accepted as a view
            lambda v: v.__setitem__(slice(None), [v[0]] * 4),
            "degenerate view: an edge is shorter than 1.0 m (sides 0.0, 0.0, 0.0, 0.0 m)",
        ),
        (  # 1 degree north of the map: scored with NE 111,300 m
            lambda v: v.__setitem__(slice(None), [[lat + 1.0, lng] for lat, lng in v]),
            "view lies outside the map bounds gps_botm_left..gps_top_right",
        ),
    ],
)
def test_a_predicted_view_the_annotation_checks_refuse_is_refused(
    dataset_factory: Callable[..., Path],
    tmp_path: Path,
    change: Callable[[list[list[float]]], None],
    message: str,
) -> None:
    root = dataset_factory({"val_seen": [make_record(), make_record(route_index="1_1")]})
    episodes = ground_truth_episodes(root, "val_seen")
    views = {e.episode_id: e.gt_path_corners.tolist() for e in episodes}
    change(views["1913__1_1"][-1])
    path = tmp_path / "p.json"
    path.write_text(
        json.dumps(
            {"format": "skyvln-eval.predictions", "version": 1,
             "episodes": {eid: {"path_corners": v} for eid, v in views.items()}}
        )
    )  # fmt: skip
    with pytest.raises(ResultRecordError) as info:
        results_from_predictions(read_predictions(path), episodes, "x", "val_seen")
    assert str(info.value) == f"{path} (episode 1913__1_1), field 'path_corners[2]': {message}"
    # The ground truth's own views are valid predictions, scored as before.
    views["1913__1_1"] = [e.gt_path_corners.tolist() for e in episodes][1]
    path.write_text(
        json.dumps(
            {"format": "skyvln-eval.predictions", "version": 1,
             "episodes": {eid: {"path_corners": v} for eid, v in views.items()}}
        )
    )  # fmt: skip
    results = results_from_predictions(read_predictions(path), episodes, "x", "val_seen")
    assert score_results(results).success.tolist() == [1.0, 1.0]
