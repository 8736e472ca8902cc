"""Round trip: read_episode(convert(episode)) == episode, for the sample and random records."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skyvln_eval.avdn import SPLITS, Episode, load_split, parse_record
from skyvln_eval.converters import (
    DEFAULT_OPTIONS,
    ConvertOptions,
    episode_metadata,
    read_episode,
    read_episode_bytes,
    read_log,
    read_log_bytes,
)
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.batch import episode_file_name
from skyvln_eval.errors import AvdnValidationError, DataError
from tests.conftest import make_record
from tests.converters.conftest import ConvertedSample, convert_to_bytes, synthetic_world

WORLD = synthetic_world()


@pytest.mark.parametrize("mode", ["andh", "andh-full"])
@pytest.mark.parametrize("split", SPLITS)
def test_every_sample_episode_round_trips(
    converted_sample: ConvertedSample, split: str, mode: str
) -> None:
    episodes = converted_sample.episodes[(split, mode)]
    report = converted_sample.reports[(split, mode)]
    assert episodes, "the sample has episodes in every split and mode"
    assert report.count("converted") == len(episodes) and not report.failed
    for episode in episodes:
        path = report.out_dir / episode_file_name(episode.episode_id)
        back = read_episode(path)
        assert back == episode
        # The records are the source JSON's values exactly, not just equal once typed.
        assert [r.to_json_dict() for r in back.records] == [
            r.to_json_dict() for r in episode.records
        ]


def test_inequality_is_detected(converted_sample: ConvertedSample) -> None:
    """Guard for the round-trip test: Episode == really compares the records."""
    a, b = converted_sample.episodes[("val_seen", "andh")][:2]
    assert (
        read_episode(
            converted_sample.reports[("val_seen", "andh")].out_dir / f"{a.episode_id}.mcap"
        )
        != b
    )


def test_sample_logs_hold_every_layer(converted_sample: ConvertedSample) -> None:
    episode = converted_sample.episodes[("val_seen", "andh-full")][0]
    log = read_log(
        converted_sample.reports[("val_seen", "andh-full")].out_dir / f"{episode.episode_id}.mcap"
    )
    views = len(episode.gt_path_corners)
    counts = log.summary().topic_counts
    assert counts[t.TOPIC_GT_OBSERVATION] == views
    assert counts[t.TOPIC_GPS] == views
    assert counts[t.TOPIC_TF] == views + 1  # plus the fixed drone -> camera transform
    assert counts[t.TOPIC_DIALOG] == counts[t.TOPIC_DIALOG_LOG] == len(episode.dialog())
    for topic in (t.TOPIC_MAP_TILE, t.TOPIC_GT_PATH, t.TOPIC_GT_VIEWS, t.TOPIC_START_POSE):
        assert counts[topic] == 1
    assert log.profile == t.MCAP_PROFILE and log.library == t.MCAP_LIBRARY
    # Static content first, then time order.
    times = [m.log_time_ns for m in log.messages]
    assert times == sorted(times)
    assert [m.sequence for m in log.messages] == list(range(len(log.messages)))
    first_timed = next(i for i, m in enumerate(log.messages) if m.topic == t.TOPIC_GPS)
    static = {m.topic for m in log.messages[:first_timed]}
    assert {t.TOPIC_MAP_TILE, t.TOPIC_GT_PATH, t.TOPIC_GT_VIEWS, t.TOPIC_START_POSE} <= static


text = st.text(st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=40)
utterance = st.builds(lambda q, i: f"[QUE] {q} [INS] {i}", text, text)


@st.composite
def valid_records(draw: st.DrawFn) -> dict[str, Any]:
    """Random valid AVDN records: geometry, dialog, optional keys, unknown extra keys."""
    heading = draw(st.floats(0.0, 359.999, allow_nan=False))
    rounds = draw(st.integers(1, 4))
    record = make_record(
        route_index=f"{draw(st.integers(0, 999))}_{rounds}",
        n_views=draw(st.integers(1, 6)),
        heading=heading,
        instructions=draw(st.one_of(utterance, text.map(lambda s: "[INS] " + s))),
        pre_dialogs=draw(st.lists(utterance, min_size=rounds - 1, max_size=rounds - 1)),
        attention_list=draw(
            st.lists(
                st.tuples(
                    st.floats(30.001, 30.009), st.floats(40.001, 40.009), st.integers(1, 60)
                ).map(lambda c: [[c[0], c[1]], c[2]]),
                max_size=3,
            )
        ),
    )
    if draw(st.booleans()):
        del record["destination"]
    if draw(st.booleans()):
        del record["last_round_idx"]
    if draw(st.booleans()):
        record["annotator_note"] = draw(st.one_of(text, st.integers(), st.none()))
    return record


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(raw=valid_records(), observations=st.booleans())
def test_random_valid_records_round_trip(raw: dict[str, Any], observations: bool) -> None:
    record = parse_record(raw)
    episode = Episode(split="val_unseen", mode="andh", records=(record,))
    options = ConvertOptions(observations=observations, map_tile_max_side_px=64)
    back = read_episode_bytes(convert_to_bytes(episode, WORLD, options))
    assert back == episode
    assert back.records[0].to_json_dict() == json.loads(json.dumps(raw))
    assert back.dialog() == episode.dialog()


@settings(max_examples=15, deadline=None)
@given(rounds=st.integers(1, 4), seed=st.integers(0, 2**31))
def test_random_full_trajectories_round_trip(rounds: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    records = tuple(
        parse_record(
            make_record(
                route_index=f"7_{r}",
                last_round_idx=rounds,
                heading=float(rng.uniform(0, 360)),
                n_views=int(rng.integers(2, 5)),
                instructions=f"[QUE] where {r}? [INS] go {r}",
                pre_dialogs=[f"[INS] earlier {k}" for k in range(1, r)],
            )
        )
        for r in range(1, rounds + 1)
    )
    episode = Episode(split="train", mode="andh-full", records=records)
    data = convert_to_bytes(episode, None)
    assert read_episode_bytes(data) == episode
    # Round r's dialog is given at round r's first view on the episode clock.
    turns = [m.decode() for m in read_log_bytes(data).topic(t.TOPIC_DIALOG)]
    first_view = np.cumsum([0] + [len(r.gt_path_corners) for r in records])
    for turn in turns:
        start_ns = int(first_view[turn["round_index"] - 1]) * 1_000_000_000
        assert turn["timestamp"] == {"sec": start_ns // 10**9, "nsec": 0}


def test_floats_survive_exactly(tmp_path: Path) -> None:
    """Shortest-repr floats and awkward values come back bit for bit."""
    raw = make_record(angle=0.1 + 0.2, lng_ratio=1e-5 * (1 + 2**-40))
    raw["extra_float"] = 5e-324
    back = read_episode_bytes(
        convert_to_bytes(Episode("val_seen", "andh", (parse_record(raw),)), None)
    )
    source = back.records[0].to_json_dict()
    assert source["angle"] == 0.1 + 0.2 == 0.30000000000000004
    assert source["extra_float"] == 5e-324 and source["lng_ratio"] == raw["lng_ratio"]


def test_the_records_in_a_log_are_strict_json() -> None:
    """NaN in an unknown key is refused on reading (validation), and on writing too for a
    record made in Python: the metadata's records once held a bare NaN, which JSON.parse
    and orjson reject."""
    raw = make_record()
    raw["extra"] = [1.0, {"deep": math.nan}]
    with pytest.raises(AvdnValidationError, match=r"field 'extra\[1\]\['deep'\]': NaN"):
        parse_record(raw)
    made = replace(parse_record(make_record()), extra={"extra": math.inf}, source=None)
    with pytest.raises(DataError, match="episode 1913__0_1: records are not strict JSON"):
        episode_metadata(Episode("val_seen", "andh", (made,)), DEFAULT_OPTIONS)


def test_loaded_dataset_round_trip_through_files(dataset_factory: Any, tmp_path: Path) -> None:
    """The AVDN reader's own episodes (from a file on disk) equal what comes back."""
    root = dataset_factory({"val_seen": [make_record(route_index="4_1", pre_dialogs=[])]})
    episode = load_split(root, "val_seen").episodes("andh")[0]
    path = tmp_path / "e.mcap"
    path.write_bytes(convert_to_bytes(episode, None))
    assert read_episode(path) == episode
