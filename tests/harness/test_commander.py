"""A commander in the loop: the agent's questions are answered from the ground truth, in the
generator's language, within a budget; the answer joins the dialog the agent sees."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from skyvln_eval.agent import AgentConfig, build_agent
from skyvln_eval.avdn.records import Episode
from skyvln_eval.harness import RunConfig, run, run_official_episode
from skyvln_eval.harness.commander import SimulatedCommander
from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.metrics import MetricConventions, read_results, score_results, view_success
from skyvln_eval.worlds.sample.phrasebook import all_frames
from tests.toy_worlds import town_episode, town_world

# Two restaurants in town: "a restaurant" does not say which one is meant.
VAGUE = "Go north. The destination is a restaurant."
PERFECT = {"detector": {"miss_rate": 0.0, "false_positive_rate": 0.0, "confusion_rate": 0.0}}


def test_hsd_ambiguity_makes_the_agent_ask_and_the_answer_settles_it() -> None:
    episode, world = town_episode(VAGUE), town_world()
    commander = SimulatedCommander(episode, world, max_questions=2, seed=1)
    agent = build_agent(AgentConfig.model_validate(PERFECT))
    rollout = run_official_episode(agent, episode, world, commander=commander)
    [asked, *_] = rollout.questions
    assert asked["step"] == 0 and asked["question"].endswith("?")
    assert "restaurant" in rollout.traces[0]["clarification_question"]
    # The commander answered from the ground truth: where the red restaurant is.
    assert asked["answer"] is not None and "red roof" in asked["answer"]
    # The answer reached the agent as a new round, and it planned again from it.
    replans = [e for t in rollout.traces[1:] for e in t["exchanges"] if e["module"] == "subgoals"]
    assert replans and asked["answer"] in replans[0]["prompt"][-1]["text"]
    assert view_success(rollout.final_view, episode.gt_end_view)


def test_without_a_commander_questions_stay_unanswered_and_the_budget_holds() -> None:
    episode, world = town_episode(VAGUE), town_world()
    agent = build_agent(AgentConfig.model_validate(PERFECT))
    alone = run_official_episode(agent, episode, world)
    assert alone.questions and all(q["answer"] is None for q in alone.questions)
    commander = SimulatedCommander(episode, world, max_questions=0)
    assert commander.answer(0, "Which one?", episode.start_view) == ()
    once = SimulatedCommander(episode, world, max_questions=1, seed=3)
    first = once.answer(0, "Which one?", episode.start_view)
    assert [t.speaker for t in first] == ["follower", "commander"]
    assert first[0].round_index == first[1].round_index == 2  # a new round after round 1
    assert once.answer(1, "And now?", episode.start_view) == ()  # over budget


def test_runs_record_questions_and_the_scores_count_them(tmp_path: Path, sample_dir: Path) -> None:
    config = RunConfig(
        system="asks",
        data=str(sample_dir),
        splits=("val_unseen",),
        limit=4,
        executor="serial",
        commander={"max_questions": 1},  # type: ignore[arg-type]
    )
    run(config, tmp_path / "run")
    results = read_results(tmp_path / "run" / RESULTS_FILE)
    scores = score_results(results, MetricConventions())
    for result, (_, row) in zip(results, scores.iterrows(), strict=True):
        questions = result.extra["questions"]
        assert row.questions_asked == len(questions)
        assert row.questions_answered == sum(q["answer"] is not None for q in questions) <= 1


def test_only_the_last_round_ends_at_the_destination() -> None:
    """An intermediate round's end is where that round's instruction leads, not the
    destination: the commander says how far to go, and does not call a landmark there the
    destination (it did, 158 m short of the real one, on the sample's 9101__6_1)."""
    last, world = town_episode(VAGUE), town_world()
    [record] = last.records
    earlier = Episode("toy", "andh", (dataclasses.replace(record, last_round_idx=3),))
    unknown = Episode("toy", "andh", (dataclasses.replace(record, last_round_idx=None),))
    answers = {
        name: SimulatedCommander(e, world, seed=5).answer(0, "Where now?", e.start_view)[1].text
        for name, e in (("last", last), ("earlier", earlier), ("unknown", unknown))
    }
    assert "red roof" in answers["last"], answers
    for name in ("earlier", "unknown"):  # the way to go, and nothing called the end
        assert "red roof" not in answers[name] and "north" in answers[name].lower(), answers


def test_a_drone_already_over_the_goal_is_told_to_stop_not_to_fly_on() -> None:
    episode, world = town_episode(VAGUE), town_world()
    for seed in range(8):  # whichever seen family answers
        commander = SimulatedCommander(episode, world, seed=seed)
        [_, there] = commander.answer(0, "Here?", episode.gt_end_view)
        [_, far] = commander.answer(1, "Here?", episode.start_view)
        assert there.text in ARRIVED, there.text
        assert far.text not in ARRIVED and "north" in far.text.lower(), far.text
    # Near, not there: the goal's centre in the view but the views overlapping too little
    # for a success (an audit: told "stop here" 62 m from the goal, the agent failed).
    goal = np.asarray(episode.gt_end_view, dtype=np.float64)
    edge = np.linalg.norm(goal[0] - goal[1])
    shift = np.array([0.4 * edge, 0.0])  # along a side: 0.4 of an edge
    near = goal + shift
    assert not view_success(near, goal)
    assert np.linalg.norm(near.mean(axis=0) - goal.mean(axis=0)) < edge / 2  # was "there"
    [_, told] = SimulatedCommander(episode, world, seed=0).answer(0, "Here?", near)
    assert told.text not in ARRIVED, told.text


#: Every family's answer to a follower who is there, as the commander says it.
ARRIVED = {f"{frame.template}." for frame in all_frames() if frame.slot == "answer.arrived"}
