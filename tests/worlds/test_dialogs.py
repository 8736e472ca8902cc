"""The synthetic commander's language: families of frames, disjoint between seen and unseen
splits, facts rendered again byte for byte, and answers to clarification questions."""

from __future__ import annotations

import re
import string
from pathlib import Path

import numpy as np
import pytest

from skyvln_eval.avdn import SPLITS, load_split
from skyvln_eval.errors import UnknownNameError
from skyvln_eval.worlds.sample import (
    FAMILIES,
    SPLIT_FAMILIES,
    AnswerFacts,
    commander_answer,
    held_out_families,
    load_dialogs,
    rephrase_records,
    seen_families,
)
from skyvln_eval.worlds.sample.cache import dataset_dir_name
from skyvln_eval.worlds.sample.dialogs import DIALOG_VERSION
from skyvln_eval.worlds.sample.phrasebook import SLOTS, TOPICS, all_frames
from skyvln_eval.worlds.sample.pilot import FLIGHT_VERSION
from skyvln_eval.worlds.sample.wording import (
    compass_colloquial,
    compass_erly,
    compass_spaced,
    compass_ward,
    number_words,
    words,
)

SEEN = ("train", "val_seen")
UNSEEN = ("val_unseen", "test_unseen")


def test_the_phrasebook_has_families_of_frames_over_every_topic() -> None:
    frames = all_frames()
    assert len(frames) >= 30
    assert len({f.frame_id for f in frames}) == len(frames)
    assert {"destination", "direction", "distance", "landmark", "correction", "answer"} <= set(
        TOPICS
    )
    for family in FAMILIES.values():
        assert set(family.frames) == set(SLOTS), family.name  # every family can say anything
    # No two families share a frame's words: a family is a manner of speaking of its own.
    for slot in SLOTS:
        templates = [family.frames[slot] for family in FAMILIES.values()]
        assert len(set(templates)) == len(templates), slot


def test_the_split_table_keeps_seen_and_unseen_families_apart() -> None:
    assert set(SPLIT_FAMILIES) == set(SPLITS)
    seen = {f for s in SEEN for f in SPLIT_FAMILIES[s]}
    unseen = {f for s in UNSEEN for f in SPLIT_FAMILIES[s]}
    assert seen and unseen and not seen & unseen
    assert set(seen_families()) == seen and set(held_out_families()) == unseen
    # val_unseen and test_unseen do not share families either: tuning on one says nothing
    # about the other's words.
    assert not set(SPLIT_FAMILIES["val_unseen"]) & set(SPLIT_FAMILIES["test_unseen"])


def test_no_frame_used_in_an_unseen_split_occurs_in_a_seen_split(sample_dir: Path) -> None:
    sources = load_dialogs(sample_dir)
    used = {split: sources.frames_used(split) for split in SPLITS}
    seen_frames = used["train"] | used["val_seen"]
    for split in UNSEEN:
        assert used[split], split
        assert not used[split] & seen_frames, split
    for split, frames in used.items():  # each split speaks only its own families
        assert {sources.frame_families[f] for f in frames} <= set(SPLIT_FAMILIES[split]), split
    assert sources.split_families == SPLIT_FAMILIES


def _literals(template: str) -> list[str]:
    """The fixed words of a frame, between its placeholders."""
    pieces = [lit for lit, _, _, _ in string.Formatter().parse(template)]
    return [p.strip(" ,;:.?").lower() for p in pieces if len(p.strip(" ,;:.?")) >= 3]


def test_the_recorded_frames_are_the_words_of_each_record(sample_dir: Path) -> None:
    sources = load_dialogs(sample_dir)
    templates = {f.frame_id: f.template for f in all_frames()}
    checked = 0
    for split in SPLITS:
        records = {r.episode_id: r for r in load_split(sample_dir, split).records}
        for t in sources.trajectories[split]:
            for k, frames in enumerate(t.frames):
                text = records[f"{t.map_name}__{t.trajectory}_{k + 1}"].instructions.lower()
                for frame in frames:
                    for literal in _literals(templates[frame]):
                        assert literal in text, (frame, literal, text)
                        checked += 1
    assert checked > 300


def test_a_frame_s_article_agrees_with_the_word_filled_in(sample_dir: Path) -> None:
    """ "proceed in a {dir_erly} direction" says "an easterly" (it said "a easterly")."""
    texts = [
        turn
        for split in SPLITS
        for r in load_split(sample_dir, split).records
        for turn in (r.instructions, *r.pre_dialogs)
    ]
    assert not [t for t in texts if re.search(r"\b[Aa] easterly", t)]
    assert any(re.search(r"\ban easterly\b", t) for t in texts)  # the case occurs


def test_facts_rendered_again_give_the_annotations_back_byte_for_byte(sample_dir: Path) -> None:
    sources = load_dialogs(sample_dir)
    for split in SPLITS:
        records = load_split(sample_dir, split).records
        again = rephrase_records(records, sources, split, SPLIT_FAMILIES[split])
        assert [r.instructions for r in again] == [r.instructions for r in records]
        assert [r.pre_dialogs for r in again] == [r.pre_dialogs for r in records]


def test_the_same_routes_can_be_phrased_by_held_out_families(sample_dir: Path) -> None:
    sources = load_dialogs(sample_dir)
    records = load_split(sample_dir, "val_seen").records
    other = rephrase_records(records, sources, "val_seen", held_out_families())
    changed = sum(a.instructions != b.instructions for a, b in zip(records, other, strict=True))
    assert changed == len(records)
    for a, b in zip(records, other, strict=True):
        assert a.episode_id == b.episode_id
        assert np.array_equal(a.gt_path_corners, b.gt_path_corners)
        assert b.instructions.startswith("[QUE] " if a.round_index > 1 else "[INS] ")
        assert len(b.pre_dialogs) == len(a.pre_dialogs)
    with pytest.raises(UnknownNameError, match="Did you mean 'plain'"):
        rephrase_records(records, sources, "val_seen", ["plian"])


def test_numbers_and_compass_points_are_written_in_several_forms() -> None:
    assert number_words(150) == "one hundred and fifty"
    assert number_words(150, a_hundred=True) == "a hundred and fifty"
    assert number_words(250, with_and=False) == "two hundred fifty"
    assert number_words(1050) == "one thousand and fifty"
    assert number_words(45) == "forty-five"
    assert words("meters", a_hundred=True)(500) == "half a kilometer"
    assert compass_spaced("northeast") == "north east"
    assert compass_erly("southwest") == "south-westerly" and compass_erly("east") == "easterly"
    assert compass_ward("north") == "northward"
    assert compass_colloquial("north") == "up north"
    assert compass_colloquial("southeast") == "down to the southeast"


def test_the_sample_folder_name_carries_the_dialog_version() -> None:
    from skyvln_eval.worlds.sample import SAMPLE_SPEC

    assert DIALOG_VERSION >= 2
    assert f"f{FLIGHT_VERSION}d{DIALOG_VERSION}-" in dataset_dir_name(SAMPLE_SPEC)


def test_the_commander_answers_a_clarification_question_from_route_facts() -> None:
    facts = AnswerFacts("north", 180.0, "a small restaurant with a red roof")
    answer = commander_answer(facts, ["plain"], seed=1)
    assert answer.text == (
        "Go on, go north. After about 200 meters you will reach a small restaurant with a red roof."
    )
    assert answer.frames == ("plain/answer.which_way", "plain/head", "plain/next.distance")
    assert commander_answer(facts, ["plain", "chatty"], seed=4) == commander_answer(
        facts, ["plain", "chatty"], seed=4
    )
    # A wrong heading opens with a correction; a turn is said as left / right.
    corrected = commander_answer(AnswerFacts("left", wrong_heading="west"), ["formal"], seed=0)
    assert corrected.text == "Negative, do not continue westward. Turn left at this point."
    destination = AnswerFacts("east", 320.0, "an oval stadium", is_destination=True)
    texts = {commander_answer(destination, held_out_families(), seed=s).text for s in range(12)}
    assert len(texts) > 3  # different families and forms of numbers and compass points
    for text in texts:
        assert "an oval stadium" in text
        assert re.search(r"300|three hundred|0\.3", text), text


def test_dialogs_file_version_is_checked_on_read(sample_dir: Path, tmp_path: Path) -> None:
    import json

    from skyvln_eval.errors import DataError, FormatVersionError

    with pytest.raises(DataError, match="only the synthetic datasets have one"):
        load_dialogs(tmp_path)
    data = json.loads((sample_dir / "DIALOGS.json").read_text())
    (tmp_path / "DIALOGS.json").write_text(json.dumps({**data, "version": 1}))
    with pytest.raises(FormatVersionError, match="Regenerate the dataset"):
        load_dialogs(tmp_path)
