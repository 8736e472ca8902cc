"""HSD: sectors of known boxes, descriptors, candidate ranking, asking TrackBack memory."""

from __future__ import annotations

import json
import threading
from collections.abc import Sequence
from typing import Any

import pytest

from skyvln_eval.agent.hsd import (
    SECTOR_NAMES,
    SpatialDescriptor,
    coarse_position,
    fine_entry,
    relative_bearing_deg,
    sector_of,
)
from skyvln_eval.agent.perception import Panorama, Sighting
from skyvln_eval.agent.subgoals import SubGoal
from skyvln_eval.llm import (
    Completion,
    GenerationConfig,
    LLMClient,
    LLMConfig,
    Message,
    create_backend,
)
from skyvln_eval.llm.rule import RuleBackend
from skyvln_eval.llm.simple import ScriptedBackend
from skyvln_eval.llm.taskdata import read_task_data

SIZE = (224, 224)


@pytest.mark.parametrize(
    ("box", "sector"),
    [
        ((0, 0, 30, 30), 0),
        ((100, 10, 124, 40), 1),
        ((200, 0, 224, 20), 2),
        ((10, 100, 40, 124), 3),
        ((100, 100, 124, 124), 4),
        ((180, 90, 224, 130), 5),
        ((0, 200, 20, 224), 6),
        ((100, 190, 124, 224), 7),
        ((200, 200, 224, 224), 8),
        ((0, 0, 224, 224), 4),  # a box filling the view is centred
        ((138, 0, 158, 10), 1),  # centre x = 148 < 2 * 224 / 3 = 149.3: the middle column
        ((140, 0, 160, 10), 2),  # centre x = 150: the right column
    ],
)
def test_sectors_of_known_boxes(box: tuple[int, int, int, int], sector: int) -> None:
    assert sector_of(box, SIZE) == sector


def test_coarse_positions_and_names() -> None:
    assert SECTOR_NAMES[0] == "upper-left" and SECTOR_NAMES[8] == "lower-right"
    assert coarse_position((0, 200, 20, 224), SIZE) == "left"
    assert coarse_position((100, 0, 124, 20), SIZE) == "centre"
    assert coarse_position((200, 100, 224, 124), SIZE) == "right"
    assert relative_bearing_deg(10.0, 350.0) == pytest.approx(20.0)
    assert relative_bearing_deg(350.0, 10.0) == pytest.approx(-20.0)


def sighting(
    lid: str,
    label: str,
    caption: str,
    east: float,
    north: float,
    box=(100, 100, 124, 124),
    score=0.9,
) -> Sighting:
    import math

    bearing = math.degrees(math.atan2(east, north)) % 360.0
    return Sighting(
        landmark_id=lid, label=label, caption=caption, score=score, view_index=0, view_name="front",
        view_heading_deg=0.0, box_px=box, image_size_px=SIZE, x_m=500 + east, y_m=500 + north,
        east_m=east, north_m=north, distance_m=math.hypot(east, north), bearing_deg=bearing,
        size_m=20.0,
    )  # fmt: skip


PANORAMA = Panorama(
    views=(),
    sightings=(
        sighting(
            "L1",
            "restaurant",
            "a small restaurant with a black roof",
            0.0,
            120.0,
            box=(10, 10, 40, 40),
        ),
        sighting(
            "L2",
            "restaurant",
            "a small restaurant with a red roof",
            80.0,
            60.0,
            box=(180, 150, 220, 200),
        ),
        sighting("L3", "church", "a church with a cross-shaped red roof", -60.0, -10.0, score=0.8),
    ),
)


def test_fine_entries_carry_sector_distance_and_bearing_and_coarse_ones_do_not() -> None:
    entry = fine_entry(PANORAMA.sightings[1], heading_deg=30.0)
    assert entry["sector"] == 8 and entry["sector_name"] == "lower-right"
    # Whole metres and degrees, as the prose says them (53.13 deg -> 53).
    assert (entry["distance_m"], entry["bearing_deg"], entry["relative_bearing_deg"]) == (
        100,
        53,
        23,
    )
    coarse = SpatialDescriptor(LLMClient(ScriptedBackend()), LLMConfig(), enabled=False)
    [first, *_] = coarse.entries(PANORAMA, 30.0)
    assert first == {
        "id": "L1",
        "label": "restaurant",
        # The detector's caption is perception's, not HSD's: w/o HSD keeps it.
        "caption": "a small restaurant with a black roof",
        "view": "front",
        "position": "left",
        "score": 0.9,
    }
    assert "sector" not in coarse.text(coarse.entries(PANORAMA, 30.0))


def test_hsd_describes_each_candidate_then_ranks_them() -> None:
    client = LLMClient(create_backend("rule"))
    hsd = SpatialDescriptor(client, LLMConfig(), enabled=True, top_k=3)
    goal = SubGoal("destination", landmark="a small restaurant with a red roof")
    result = hsd.match([goal], PANORAMA, 0.0, memory_notes=None)
    [match] = result.matches
    assert match.best == "L2" and match.confidence >= 0.5
    assert [c.entry["id"] for c in match.candidates][:2] == ["L2", "L1"]
    described = {c.entry["id"]: c.match for c in match.candidates}
    assert described["L2"] == "strong" and described["L1"] == "weak"  # the roof colour differs
    modules = [r.module for r in result.records]
    assert modules.count("hsd_describe") == len(match.candidates) and modules[-1] == "hsd_rank"


#: Two churches alike, 20 m and 150 m ahead.
TWINS = Panorama(
    views=(),
    sightings=(
        sighting("L1", "church", "a church with a cross-shaped red roof", 0.0, 20.0),
        sighting("L2", "church", "a church with a cross-shaped red roof", 0.0, 150.0),
    ),
)


def test_hsd_asks_memory_when_candidates_tie_and_the_memory_decides() -> None:
    asked: list[list[str]] = []

    def notes(ids: list[str], phrase: str) -> dict[str, str]:
        asked.append(list(ids))
        return {"L1": "recognised at the start from an earlier round, so already reached"}

    hsd = SpatialDescriptor(LLMClient(create_backend("rule")), LLMConfig(), enabled=True)
    goal = SubGoal("destination", landmark="a church with a cross-shaped red roof")
    [match] = hsd.match([goal], TWINS, 0.0, memory_notes=notes).matches
    assert asked == [["L1", "L2"]] and match.asked_memory and match.ambiguous
    assert match.best == "L2"
    [alone] = hsd.match([goal], TWINS, 0.0, memory_notes=None).matches
    assert not alone.asked_memory


def test_an_unusable_ranking_falls_back_to_the_proposal_order_and_is_recorded() -> None:
    describe = json.dumps({"description": "looks right", "match": "strong"})
    script = [describe, describe, describe, "I think L2 is best!", "Really, L2."]
    hsd = SpatialDescriptor(LLMClient(ScriptedBackend(script)), LLMConfig(), enabled=True)
    goal = SubGoal("destination", landmark="a small restaurant with a red roof")
    result = hsd.match([goal], PANORAMA, 0.0, memory_notes=None)
    [match] = result.matches
    assert match.error is not None and "not a JSON object" in match.error
    assert match.best == match.candidates[0].entry["id"] == "L2"
    assert result.records[-1].error is not None and result.records[-1].error.startswith(
        "invalid output"
    )
    assert [r.repair for r in result.records[-2:]] == [False, True]  # asked again once
    [failure] = result.failures  # and the fallback is on record
    assert failure.module == "hsd_rank" and failure.substitute == "proposal order"


def test_the_ranking_schema_offers_exactly_the_calls_candidates() -> None:
    """A grammar-constrained decoder can only name a candidate of the call, and whatever
    it writes under the schema the parser accepts."""
    describe = json.dumps({"description": "looks right", "match": "strong"})
    schemas: list[dict[str, Any]] = []

    class Recording(ScriptedBackend):
        def generate(self, messages: Sequence[Message], config: GenerationConfig) -> Completion:
            schemas.append(config.json_schema or {})
            return super().generate(messages, config)

    ranked = json.dumps({"ranking": ["L3", "L1"], "best": None, "confidence": 0.2})
    backend = Recording([describe] * 3 + [ranked])
    hsd = SpatialDescriptor(LLMClient(backend), LLMConfig(), enabled=True)
    goal = SubGoal("destination", landmark="a small restaurant with a red roof")
    [match] = hsd.match([goal], PANORAMA, 0.0, memory_notes=None).matches
    ids = sorted(c.entry["id"] for c in match.candidates)
    rank = schemas[-1]["properties"]
    assert sorted(rank["ranking"]["items"]["enum"]) == ids == ["L1", "L2", "L3"]
    assert rank["ranking"]["maxItems"] == 3 and sorted(rank["best"]["anyOf"][0]["enum"]) == ids
    assert match.error is None and match.best is None  # as ranked: none fits


def test_hsd_off_makes_no_calls() -> None:
    backend = ScriptedBackend()
    hsd = SpatialDescriptor(LLMClient(backend), LLMConfig(), enabled=False)
    result = hsd.match([SubGoal("destination", landmark="a church")], PANORAMA, 0.0, None)
    assert result.matches == [] and result.records == [] and backend.calls == []


class _RoundsBackend(ScriptedBackend):
    """Answers as the rule backend, but each call waits until ``parties[task]`` calls of
    its task are in flight together: calls made one after another time out."""

    def __init__(self, parties: dict[str, int]) -> None:
        super().__init__()
        self.rule = create_backend("rule")
        self.barriers = {task: threading.Barrier(n, timeout=10.0) for task, n in parties.items()}

    def generate(self, messages, config):  # type: ignore[no-untyped-def]
        task = read_task_data(messages)["task"]
        self.barriers[task].wait()  # BrokenBarrierError if the round does not come together
        self.calls.append(list(messages))
        return self.rule.generate(messages, config)


def test_hsd_asks_for_every_phrase_at_once_describing_then_ranking() -> None:
    # Two phrases, three candidates each: six descriptions in one round, two rankings in the
    # next, whatever the number of phrases (a decision waits for two answers, not four).
    goals = [
        SubGoal("destination", landmark="a small restaurant with a red roof"),
        SubGoal("pass", landmark="a church with a cross-shaped red roof"),
    ]
    hsd = SpatialDescriptor(LLMClient(create_backend("rule")), LLMConfig(), top_k=3)
    proposals = [len(hsd.propose(g.landmark or "", PANORAMA, 0.0)) for g in goals]
    backend = _RoundsBackend({"hsd_describe": sum(proposals), "hsd_rank": len(goals)})
    client = LLMClient(backend, max_concurrency=8)
    result = SpatialDescriptor(client, LLMConfig(), top_k=3).match(goals, PANORAMA, 0.0, None)
    assert [m.phrase for m in result.matches] == [g.landmark for g in goals]
    assert all(r.outcome == "ok" for r in result.records)
    # Records read one phrase after another: its descriptions, then its ranking.
    modules = [r.module for r in result.records]
    expected = []
    for n in proposals:
        expected += ["hsd_describe"] * n + ["hsd_rank"]
    assert modules == expected
    # The same matches as the serial rule backend gives.
    serial = SpatialDescriptor(LLMClient(create_backend("rule"), max_concurrency=1), LLMConfig())
    assert serial.match(goals, PANORAMA, 0.0, None).matches == result.matches


class _ThreadNotingRule(RuleBackend):
    """The rule backend, noting the thread each call is made in."""

    def __init__(self) -> None:
        super().__init__()
        self.threads: list[str] = []

    def generate(self, messages, config):  # type: ignore[no-untyped-def]
        self.threads.append(threading.current_thread().name)
        return super().generate(messages, config)


def test_hsd_calls_a_backend_that_answers_in_process_one_after_another() -> None:
    # The rule backend computes its answers under the interpreter's lock: threads would
    # only take turns, so HSD's calls stay in the calling thread (no pool per decision).
    goals = [
        SubGoal("destination", landmark="a small restaurant with a red roof"),
        SubGoal("pass", landmark="a church with a cross-shaped red roof"),
    ]
    backend = _ThreadNotingRule()
    assert backend.answers_in_process and not ScriptedBackend().answers_in_process
    result = SpatialDescriptor(LLMClient(backend, max_concurrency=8), LLMConfig(), top_k=3).match(
        goals, PANORAMA, 0.0, None
    )
    assert len(backend.threads) > len(goals)  # several descriptions, then the rankings
    assert set(backend.threads) == {threading.current_thread().name}
    assert [m.phrase for m in result.matches] == [g.landmark for g in goals]


def test_candidates_whose_descriptions_failed_are_no_tie_to_ask_about() -> None:
    # Twins left undescribed (every description unusable) read as 'unknown' alike:
    # that is a module failure, not two places that match equally well.
    ranking = json.dumps({"ranking": ["L1", "L2"], "best": "L1", "confidence": 0.6})
    script = ["no idea"] * 4 + [ranking]
    hsd = SpatialDescriptor(LLMClient(ScriptedBackend(script)), LLMConfig(), enabled=True)
    goal = SubGoal("destination", landmark="a church with a cross-shaped red roof")
    [match] = hsd.match([goal], TWINS, 0.0, memory_notes=None).matches
    assert {c.match for c in match.candidates} == {"unknown"}
    assert not match.ambiguous
    # Described alike, they are a tie.
    [described] = hsd_rule().match([goal], TWINS, 0.0, memory_notes=None).matches
    assert described.ambiguous


def hsd_rule() -> SpatialDescriptor:
    return SpatialDescriptor(LLMClient(create_backend("rule")), LLMConfig(), enabled=True)


@pytest.mark.parametrize(
    ("level", "ambiguous"), [("strong", True), ("partial", True), ("weak", False), ("none", False)]
)
def test_only_candidates_that_fit_alike_are_a_tie_to_ask_about(level: str, ambiguous: bool) -> None:
    # Two places that hardly fit the phrase (weak) or not at all (none) are no reason to ask
    # "which of these two?": the question would say they "look equally like" it.
    described = json.dumps({"description": "compared", "match": level})
    ranking = json.dumps({"ranking": ["L1", "L2"], "best": None, "confidence": 0.1})
    script = [described, described, ranking]
    hsd = SpatialDescriptor(LLMClient(ScriptedBackend(script)), LLMConfig(), enabled=True)
    goal = SubGoal("destination", landmark="a church with a cross-shaped red roof")
    [match] = hsd.match([goal], TWINS, 0.0, memory_notes=None).matches
    assert [c.match for c in match.candidates] == [level, level]
    assert match.ambiguous is ambiguous
