"""Splits, trajectories and episodes (ANDH and ANDH-Full), dialogs and withheld ground truth."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from skyvln_eval.avdn import SPLITS, AvdnRecord, DialogTurn, load_split, parse_utterances
from skyvln_eval.errors import AvdnValidationError, ConfigError, NoGroundTruthError
from tests.conftest import make_record


def trajectory(traj: str, rounds: int, map_name: str = "1913") -> list[dict]:
    records = []
    for r in range(1, rounds + 1):
        instructions = "[INS] go north." if r == 1 else f"[QUE] where now {r}? [INS] turn left {r}."
        records.append(
            make_record(
                map_name=map_name,
                route_index=f"{traj}_{r}",
                last_round_idx=rounds,
                instructions=instructions,
                pre_dialogs=[f"round {k}" for k in range(1, r)],
                n_views=2 + r,
            )
        )
    return records


def test_all_four_splits_load(dataset_factory: Callable[..., Path]) -> None:
    root = dataset_factory({split: trajectory("0", 1) for split in SPLITS})
    for split in SPLITS:
        loaded = load_split(root, split)
        assert loaded.split == split and len(loaded.records) == 1
        assert isinstance(loaded.records[0], AvdnRecord)


def test_trajectories_are_grouped_and_sorted_by_round_not_file_order(
    dataset_factory: Callable[..., Path],
) -> None:
    records = trajectory("3", 3) + trajectory("10", 2) + trajectory("2", 1, map_name="55")
    shuffled = [records[i] for i in (4, 1, 5, 0, 3, 2)]
    root = dataset_factory({"val_seen": shuffled}, maps=("1913", "55"))
    loaded = load_split(root, "val_seen")
    groups = loaded.trajectories()
    assert list(groups) == [("1913", "3"), ("1913", "10"), ("55", "2")]
    assert [r.round_index for r in groups[("1913", "3")]] == [1, 2, 3]

    andh = loaded.episodes("andh")
    assert [e.episode_id for e in andh] == [
        r["map_name"] + "__" + r["route_index"] for r in shuffled
    ]
    assert all(e.mode == "andh" and len(e.records) == 1 for e in andh)

    full = loaded.episodes("andh-full")
    assert [e.episode_id for e in full] == ["1913__3_1", "1913__10_1", "55__2_1"]
    first = full[0]
    assert [r.round_index for r in first.records] == [1, 2, 3]
    assert np.array_equal(first.start_view, first.records[0].gt_path_corners[0])
    assert np.array_equal(first.gt_end_view, first.records[-1].gt_path_corners[-1])
    assert len(first.gt_path_corners) == 3 + 4 + 5
    assert [t.speaker for t in first.dialog()] == [
        "commander",
        "follower",
        "commander",
        "follower",
        "commander",
    ]


def test_a_full_episode_holds_a_view_two_rounds_share_once(
    dataset_factory: Callable[..., Path],
) -> None:
    """Round 2 starts where round 1 ended (as AVDN's rounds do): that view is one
    reference point, not two; a round that starts elsewhere keeps all its views."""
    records = trajectory("4", 3)
    records[1]["gt_path_corners"][0] = records[0]["gt_path_corners"][-1]
    root = dataset_factory({"val_seen": records})
    (full,) = load_split(root, "val_seen").episodes("andh-full")
    assert len(full.gt_path_corners) == 3 + (4 - 1) + 5
    views = [v.tolist() for v in full.gt_path_corners]
    assert views == [
        *records[0]["gt_path_corners"],
        *records[1]["gt_path_corners"][1:],
        *records[2]["gt_path_corners"],
    ]
    # Round 2 starts from the view it shares with round 1 (the last of round 1), round 3
    # from its own first view, which follows round 2's last.
    assert full.round_starts() == {1: 0, 2: 2, 3: 3 + 3}


def test_incomplete_trajectory_cannot_form_a_full_episode(
    dataset_factory: Callable[..., Path],
) -> None:
    records = trajectory("0", 3)
    del records[1]
    root = dataset_factory({"val_seen": records + trajectory("1", 1)})
    loaded = load_split(root, "val_seen")
    with pytest.raises(AvdnValidationError, match=r"missing round\(s\) 2 \(last_round_idx 3 in "):
        loaded.episodes("andh-full")
    assert [e.episode_id for e in loaded.episodes("andh-full", skip_incomplete=True)] == [
        "1913__1_1"
    ]
    with pytest.raises(ConfigError, match="unknown episode mode"):
        loaded.episodes("full")  # type: ignore[arg-type]


def test_a_trajectory_claiming_a_billion_rounds_is_reported_briefly(
    dataset_factory: Callable[..., Path],
) -> None:
    # The missing rounds were listed one by one: a set of a billion ints, the run hung;
    # then counted ("[3, ..., 12] and 999999999988 more"), naming no record.
    records = trajectory("0", 2)
    records[1]["last_round_idx"] = 10**12
    loaded = load_split(dataset_factory({"val_seen": records}), "val_seen")
    with pytest.raises(AvdnValidationError) as info:
        loaded.episodes("andh-full")
    [issue] = info.value.issues
    assert issue.message == (
        "trajectory 1913/0 has rounds that disagree on last_round_idx (2 in 1913__0_1; "
        "1000000000000 in 1913__0_2); is missing round(s) 3-1000000000000 (last_round_idx "
        "1000000000000 in 1913__0_2; it holds 1913__0_1, 1913__0_2); it cannot form an "
        "ANDH-Full episode"
    )


def test_a_skipped_round_makes_its_trajectory_incomplete(
    dataset_factory: Callable[..., Path],
) -> None:
    # Without last_round_idx (it may be absent), rounds 1-2 alone looked whole: the
    # ANDH-Full episode ended at round 2's end instead of the real final view.
    records = trajectory("7", 3) + trajectory("8", 1)
    for record in records:
        del record["last_round_idx"]
    records[2]["angle"] = "north"
    root = dataset_factory({"val_seen": records})
    loaded = load_split(root, "val_seen", skip_invalid=True)
    with pytest.raises(
        AvdnValidationError, match=r"trajectory 1913/7 round 3 \(record 2\)"
    ) as info:
        loaded.episodes("andh-full")
    assert "field 'angle'" in str(info.value) and "skip_incomplete=True" in str(info.value)
    assert [
        (s.record_index, s.trajectory_index, s.round_index) for s in loaded.skipped_records
    ] == [(2, "7", 3)]
    assert [e.episode_id for e in loaded.episodes("andh-full", skip_incomplete=True)] == [
        "1913__8_1"
    ]
    assert len(loaded.episodes("andh")) == 3


def test_a_skipped_record_of_unreadable_trajectory_leaves_out_undeclared_ones(
    dataset_factory: Callable[..., Path],
) -> None:
    undeclared = trajectory("7", 2)
    for record in undeclared:
        del record["last_round_idx"]
    unreadable = trajectory("7", 3)[2] | {"route_index": "7-3"}
    other_map = trajectory("9", 1, map_name="55")
    for record in other_map:
        del record["last_round_idx"]
    records = undeclared + trajectory("5", 2) + other_map + [unreadable]
    root = dataset_factory({"val_seen": records}, maps=("1913", "55"))
    loaded = load_split(root, "val_seen", skip_invalid=True)
    full = loaded.episodes("andh-full", skip_incomplete=True)
    # Trajectory 5 declares its two rounds; map 55 is not the unreadable record's map.
    assert [e.episode_id for e in full] == ["1913__5_1", "55__9_1"]
    with pytest.raises(AvdnValidationError, match=r"invalid record\(s\) \[5\]"):
        loaded.episodes("andh-full")


def test_a_skipped_record_of_unreadable_map_leaves_out_only_its_trajectory_number(
    dataset_factory: Callable[..., Path],
) -> None:
    # Its map unreadable, its route_index '7_3' still says trajectory 7: trajectory 8,
    # which it cannot be the final round of, stays.
    records = trajectory("7", 2) + trajectory("8", 1)
    for record in records:
        del record["last_round_idx"]
    unreadable = trajectory("7", 3)[2] | {"map_name": 1913}
    root = dataset_factory({"val_seen": [*records, unreadable]})
    loaded = load_split(root, "val_seen", skip_invalid=True)
    assert [(s.map_name, s.trajectory_index) for s in loaded.skipped_records] == [(None, "7")]
    full = loaded.episodes("andh-full", skip_incomplete=True)
    assert [e.episode_id for e in full] == ["1913__8_1"]


def test_test_split_with_only_start_views_has_no_ground_truth(
    dataset_factory: Callable[..., Path],
) -> None:
    records = [make_record(route_index=f"{i}_1", n_views=1) for i in range(3)]
    root = dataset_factory({"test_unseen": records})
    loaded = load_split(root, "test_unseen")
    assert loaded.ground_truth_withheld
    assert not loaded.episodes()[0].has_ground_truth
    with pytest.raises(NoGroundTruthError, match="no ground truth for 3 episode") as info:
        loaded.require_ground_truth()
    assert "test server is closed" in str(info.value)


def test_record_properties(dataset_factory: Callable[..., Path]) -> None:
    root = dataset_factory(
        {"val_unseen": [make_record(route_index="12_2", angle=359.6, last_round_idx=2)]}
    )
    record = load_split(root, "val_unseen").records[0]
    assert record.episode_id == "1913__12_2"
    assert (record.trajectory_index, record.round_index) == ("12", 2)
    assert record.start_heading_deg == 0  # round(359.6) % 360
    assert record.georef.lat_ratio == 1e-5
    assert record.gt_path_corners.shape == (3, 4, 2)
    assert not record.gt_path_corners.flags.writeable


def test_dialog_parsing() -> None:
    turns = parse_utterances("[QUE] is it the church? [INS] yes, land there.", 2)
    assert turns == [
        DialogTurn(2, "follower", "is it the church?"),
        DialogTurn(2, "commander", "yes, land there."),
    ]
    assert parse_utterances("fly north", 1) == [DialogTurn(1, "commander", "fly north")]
    record = make_record(
        route_index="0_2", pre_dialogs=["[INS] go east."], instructions="[QUE] now? [INS] stop."
    )
    from skyvln_eval.avdn import parse_record

    dialog = parse_record(record).dialog()
    assert [(t.round_index, t.speaker) for t in dialog] == [
        (1, "commander"),
        (2, "follower"),
        (2, "commander"),
    ]
