"""The SkyVLN agent and baselines end to end on a toy town: ablations, backtracking, configs."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from skyvln_eval.agent import AgentConfig, Detection, Detector, FlyTo, Stop, build_agent
from skyvln_eval.agent.motion import ACTION_SPACE, action_space
from skyvln_eval.agent.perception import Perception, PerceptionConfig
from skyvln_eval.agent.skyvln import SkyVLNAgent
from skyvln_eval.errors import ConfigError, UnknownNameError
from skyvln_eval.harness import OfficialRollout, run_official_episode
from skyvln_eval.harness.commander import SimulatedCommander
from skyvln_eval.harness.oracle import ground_truth_oracle
from skyvln_eval.llm import GenerationConfig, LLMClient, LLMConfig, create_backend, read_task_data
from skyvln_eval.llm.rule import RuleBackend
from skyvln_eval.llm.types import Completion, Message
from skyvln_eval.metrics import view_success
from skyvln_eval.sensing import CameraImages, SemanticClass
from tests.toy_worlds import town_episode, town_world

RED = "Go north. The destination is a small restaurant with a red roof."
PERFECT = {"detector": {"miss_rate": 0.0, "false_positive_rate": 0.0}}


class RecordingRule(RuleBackend):
    """The rule backend, keeping the task data of every request and the text sent."""

    def __init__(self) -> None:
        super().__init__()
        self.requests: list[tuple[dict[str, object], list[Message]]] = []

    def generate(self, messages: Sequence[Message], config: GenerationConfig) -> Completion:
        self.requests.append((read_task_data(messages), list(messages)))
        return super().generate(messages, config)


def run(
    config: AgentConfig,
    instruction: str = RED,
    max_steps: int = 10,
    backend: RuleBackend | None = None,
) -> OfficialRollout:
    episode = town_episode(instruction)
    agent = build_agent(config, LLMClient(backend or RuleBackend()))
    return run_official_episode(agent, episode, town_world(), max_steps=max_steps)


def motion_states(config: AgentConfig) -> list[dict[str, object]]:
    backend = RecordingRule()
    run(config, backend=backend)
    return [data for data, _ in backend.requests if data["task"] == "motion"]


def test_the_full_agent_finds_the_described_landmark_and_stops_over_it() -> None:
    rollout = run(AgentConfig.model_validate(PERFECT))
    assert view_success(rollout.final_view, town_episode(RED).gt_end_view)
    assert rollout.stop_reason == "stop" and isinstance(rollout.actions[0], FlyTo)
    modules = {r.module for r in rollout.llm_calls}
    assert {"subgoals", "hsd_describe", "hsd_rank", "motion"} <= modules
    assert all(r.backend == "rule" and r.cost_usd == 0.0 for r in rollout.llm_calls)
    match = rollout.traces[0]["hsd_matches"]["a small restaurant with a red roof"]
    first = {s["id"]: s for s in rollout.traces[0]["sightings"]}[match["best"]]
    # Matched from what the camera saw (a red-roofed restaurant), not from the dataset's
    # description of the landmark.
    assert first["caption"] == "a restaurant with a red roof" and "sector" in first


def test_without_hsd_the_descriptor_is_coarse_and_nothing_is_ranked() -> None:
    rollout = run(AgentConfig.model_validate({**PERFECT, "hsd": False}))
    assert not {"hsd_describe", "hsd_rank"} & {r.module for r in rollout.llm_calls}
    state = motion_states(AgentConfig.model_validate({**PERFECT, "hsd": False}))[0]
    assert state["descriptor"] == "coarse" and state["matches"] == {}
    landmarks = state["landmarks"]
    assert isinstance(landmarks, list) and landmarks
    assert all(set(e) == {"id", "label", "caption", "view", "position", "score"} for e in landmarks)


def test_without_tbma_there_is_no_memory_of_the_path() -> None:
    rollout = run(AgentConfig.model_validate({**PERFECT, "tbma": False}))
    assert all(t["memory"] is None for t in rollout.traces)
    state = motion_states(AgentConfig.model_validate({**PERFECT, "tbma": False}))[0]
    assert state["memory"] is None and state["odometry"] is None
    with_memory = motion_states(AgentConfig.model_validate(PERFECT))[0]
    assert with_memory["odometry"] is not None and with_memory["memory"] is not None


def test_the_ranking_prompt_tells_the_model_every_value_the_stand_in_ranks_by() -> None:
    """The rule stand-in ranks HSD's candidates by their distance and bearing against the
    route's direction and distance to go: the prose says each of them, so a model is
    told as much as the stand-in reads from the task data."""
    backend = RecordingRule()
    run(AgentConfig.model_validate(PERFECT), backend=backend)
    ranks = [(data, messages) for data, messages in backend.requests if data["task"] == "hsd_rank"]
    assert ranks
    for data, messages in ranks:
        text = messages[-1].text
        assert f"Your heading: {data['heading_deg']:.1f} deg." in text
        hint = data["route_hint"]
        assert isinstance(hint, dict) and hint["direction_deg"] is not None  # "Go north."
        assert f"the route heads {hint['direction_deg']:.0f} deg" in text
        candidates = data["candidates"]
        assert isinstance(candidates, list) and candidates
        for c in candidates:
            line = next(line for line in text.splitlines() if line.startswith(f"- {c['id']}:"))
            assert f"{c['distance_m']:.0f} m away at bearing {c['bearing_deg']:.0f} deg" in line
            # No more precise than the prose (an audit: 83.4 m in the data, "83 m" told).
            assert c["distance_m"] == round(c["distance_m"])
            assert c["bearing_deg"] == round(c["bearing_deg"])
        remaining = hint.get("remaining_m")
        assert remaining is None or remaining == round(remaining)
    entries = [e for data, _ in backend.requests for e in data.get("landmarks") or []]
    assert entries
    for e in entries:
        for key in ("distance_m", "bearing_deg", "relative_bearing_deg", "size_m"):
            assert e[key] == round(e[key]), (key, e)
        assert e["score"] == round(e["score"], 2)


def test_the_motion_prompt_says_how_many_actions_were_taken() -> None:
    """The stand-in reckons the distance flown without memory from the task data's
    ``step``: the prose says it too (an audit found only the actions left there)."""
    backend = RecordingRule()
    run(AgentConfig.model_validate({**PERFECT, "tbma": False}), backend=backend)
    motions = [(data, msgs) for data, msgs in backend.requests if data["task"] == "motion"]
    assert len(motions) >= 2
    for data, messages in motions:
        told = f"Actions taken: {data['step']}. Actions left before the episode ends: "
        assert f"{told}{data['actions_left']}." in messages[-1].text


def motion_texts(config: AgentConfig) -> list[str]:
    """The text of every motion request of an episode (the user message's prose)."""
    backend = RecordingRule()
    run(config, backend=backend)
    module = "navgpt" if config.name == "navgpt" else "motion"
    return [messages[-1].text for data, messages in backend.requests if data["task"] == module]


@pytest.mark.parametrize("name", ["skyvln", "navgpt"])
def test_decision_prompts_begin_with_what_stays_the_same_through_the_episode(name: str) -> None:
    # A server that keeps the previous prompt's computed prefix (llama.cpp; hosted prompt
    # caches) then computes only what changed: the action space and the commander's words
    # come first, the feedback and the pose (which change at every step) after them.
    texts = motion_texts(AgentConfig.model_validate({**PERFECT, "name": name}))
    assert len(texts) >= 2
    heads = {re.split("## Feedback|## Your drone", text)[0] for text in texts}
    assert len(heads) == 1  # the same text before the feedback or the pose at every step
    [head] = heads
    # The actions its schema allows: the NavGPT-style baseline names no landmark ids.
    actions = ACTION_SPACE if name == "skyvln" else action_space(fly_to=False)
    assert head.startswith(actions) and RED in head
    assert ("fly_to" in head) is (name == "skyvln")
    assert len({text[len(head) :] for text in texts}) == len(texts)  # the rest changes


class OneFakeRestaurant(Detector):
    """Sees only the ordinary red house at (230, 230) and takes it for a red restaurant,
    except from closer than 70 m, where the mistake shows."""

    name = "fake"

    def detect(self, images: CameraImages, phrases: Sequence[str] = ()) -> list[Detection]:
        assert images.semantic is not None and images.instance is not None
        assert images.depth_m is not None
        v, u = np.nonzero((images.semantic == SemanticClass.BUILDING) & (images.instance == 0))
        points = images.points_enu(u, v)
        near = np.hypot(points[:, 0] - 230.0, points[:, 1] - 230.0) < 12.0
        if near.sum() < 10 or float(np.median(images.depth_m[v[near], u[near]])) < 70.0:
            return []
        mask = np.zeros(images.depth_m.shape, bool)
        mask[v[near], u[near]] = True
        rows, cols = np.nonzero(mask)
        box = (int(cols.min()), int(rows.min()), int(cols.max()) + 1, int(rows.max()) + 1)
        return [Detection("restaurant", box, 0.8, "a small restaurant with a red roof", mask)]


def fooled_agent(tbma: bool) -> SkyVLNAgent:
    config = LLMConfig()
    perception = Perception(PerceptionConfig(), OneFakeRestaurant())
    return SkyVLNAgent(LLMClient(create_backend("rule")), perception, config, tbma=tbma)


def test_tbma_backtracks_when_the_landmark_is_not_there_and_asks_a_question() -> None:
    episode = town_episode(RED)
    rollout = run_official_episode(fooled_agent(tbma=True), episode, town_world())
    wrong = next(i for i, t in enumerate(rollout.traces) if t["way_back"])
    way_back = rollout.traces[wrong]["way_back"]
    assert "was not there when I arrived" in way_back["reason"]
    assert way_back["target"].startswith("P") and way_back["path"][-1] == way_back["target"]
    assert "clarify" in {r.module for r in rollout.llm_calls}
    assert rollout.traces[wrong]["clarification_question"].endswith("?")
    back = rollout.actions[wrong]
    assert isinstance(back, FlyTo) and back.landmark == way_back["target"]
    # The memory keeps the mistake: the fake restaurant is never flown to again.
    fake = rollout.actions[0]
    assert isinstance(fake, FlyTo)
    later = [a for a in rollout.actions[wrong + 1 :] if isinstance(a, FlyTo)]
    assert all(a.landmark != fake.landmark for a in later)


def test_without_tbma_the_agent_falls_for_the_same_mistake_again() -> None:
    rollout = run_official_episode(fooled_agent(tbma=False), town_episode(RED), town_world())
    targets = [a.landmark for a in rollout.actions if isinstance(a, FlyTo)]
    assert not any(t["way_back"] for t in rollout.traces)
    assert (
        len(targets) >= 3 and len(set(targets)) == 1
    )  # back to the phantom each time it reappears


def test_baselines_are_built_by_name_and_the_ground_truth_only_by_the_harness() -> None:
    episode = town_episode(RED)
    with pytest.raises(ConfigError, match="oracle the harness builds"):
        build_agent(AgentConfig(name="ground_truth"))
    gt = run_official_episode(ground_truth_oracle(episode), episode, town_world())
    assert view_success(gt.final_view, episode.gt_end_view) and isinstance(gt.actions[-1], Stop)
    assert ground_truth_oracle(episode).settings()["oracle"] is True
    random = run_official_episode(
        build_agent(AgentConfig(name="random", seed=3)), episode, town_world()
    )
    again = run_official_episode(
        build_agent(AgentConfig(name="random", seed=3)), episode, town_world()
    )
    assert [a.type for a in random.actions] == [a.type for a in again.actions]  # seeded
    navgpt = run(AgentConfig.model_validate({**PERFECT, "name": "navgpt"}))
    assert {r.module for r in navgpt.llm_calls} == {"navgpt"}
    assert not any(isinstance(a, FlyTo) for a in navgpt.actions)  # nothing to name


def test_agent_configs_are_validated_with_the_field_named(tmp_path: Path) -> None:
    with pytest.raises(UnknownNameError, match="Did you mean 'skyvln'"):
        build_agent(AgentConfig(name="skyvn"))
    bad = tmp_path / "agent.yaml"
    bad.write_text("name: skyvln\nhsd: false\nperception:\n  headings: 0\n")
    with pytest.raises(ConfigError, match=r"agent.yaml: perception\.headings"):
        AgentConfig.from_yaml(bad)
    bad.write_text("name: skyvln\nllm:\n  backend: rule\n  api_key: secret\n")
    with pytest.raises(ConfigError, match=r"llm\.api_key"):
        AgentConfig.from_yaml(bad)
    good = tmp_path / "good.yaml"
    good.write_text("name: skyvln\ntbma: false\ndetector:\n  miss_rate: 0.2\n")
    config = AgentConfig.from_yaml(good)
    agent = build_agent(config)
    settings = agent.settings()
    assert settings["tbma"] is False and settings["perception"]["detector"]["miss_rate"] == 0.2
    assert "rule-based (not an LLM)" in settings["backend"]


def test_importing_the_agent_imports_no_optional_heavy_dependency() -> None:
    import subprocess
    import sys

    from tests.conftest import REPO

    code = (
        "import sys, skyvln_eval.agent, skyvln_eval.harness, skyvln_eval.sim.camera\n"
        "print([m for m in ('openai', 'transformers', 'torch', 'ray') if m in sys.modules])"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO
    )
    assert out.stdout.strip() == "[]"


def test_without_tbma_the_ranking_is_not_told_a_distance_left_it_cannot_know() -> None:
    # Without memory the agent does not know how far it has come: the whole distance of
    # the instruction, said as "left to fly" at every step, was false after the first.
    instruction = "Fly north for 200 meters. The destination is a small restaurant with a red roof."
    for tbma, told in ((False, False), (True, True)):
        backend = RecordingRule()
        run(AgentConfig.model_validate({**PERFECT, "tbma": tbma}), instruction, backend=backend)
        ranks = [(d, m) for d, m in backend.requests if d["task"] == "hsd_rank"]
        assert ranks
        hints = [d["route_hint"]["remaining_m"] for d, _ in ranks]  # type: ignore[index]
        assert any(h is not None for h in hints) is told, hints
        assert any("m of it to fly" in m[-1].text for _, m in ranks) is told


def test_each_prompt_says_a_thing_once() -> None:
    backend = RecordingRule()
    run(AgentConfig.model_validate(PERFECT), backend=backend)
    motions = [m[-1].text for d, m in backend.requests if d["task"] == "motion"]
    assert motions
    for text in motions:  # the metres flown: the odometry's line, not the memory's too
        assert text.count(" m through ") == 0 and text.count("Flown ") <= 1
    for data, messages in backend.requests:
        if data["task"] != "hsd_rank":
            continue
        for line in messages[-1].text.splitlines():  # a candidate's place, once
            assert line.count("m away at bearing") <= 1, line


def test_without_tbma_there_is_no_memory_node_to_fly_to() -> None:
    texts = motion_texts(AgentConfig.model_validate({**PERFECT, "tbma": False}))
    assert texts and all("or a memory node" not in text for text in texts)
    assert all(
        "or a memory node" in text for text in motion_texts(AgentConfig.model_validate(PERFECT))
    )


def test_the_navgpt_prompt_says_the_last_outcome_once() -> None:
    texts = motion_texts(AgentConfig.model_validate({**PERFECT, "name": "navgpt"}))
    later = texts[1:]
    assert later
    for text in later:  # the last action's feedback: in the Feedback block only
        history = text.split("## History\n")[1].split("## Feedback")[0].strip().splitlines()
        assert " -> " not in history[-1], history
        assert all(" -> " in line for line in history[:-1]), history  # earlier outcomes stay


def test_the_commanders_answer_is_followed_from_where_it_was_given() -> None:
    # The fooled agent asks a question after its wasted flight; the answer's way and
    # distance are said from where the drone is then, so the odometry restarts there
    # (it had kept counting from the episode's start: the answer's "100 m east" was then
    # planned from the start, and the distance flown before it counted against it).
    backend = RecordingRule()
    agent = SkyVLNAgent(
        LLMClient(backend), Perception(PerceptionConfig(), OneFakeRestaurant()), LLMConfig()
    )
    episode = town_episode(RED)
    commander = SimulatedCommander(episode, town_world(), max_questions=1, seed=1)
    rollout = run_official_episode(agent, episode, town_world(), commander=commander)
    assert commander.answered == 1
    motions = [(data, messages) for data, messages in backend.requests if data["task"] == "motion"]
    # The first decision after the answer: its dialog has a new round.
    answered = next(
        k for k, (data, _) in enumerate(motions) if data["dialog"] != motions[0][0]["dialog"]
    )
    before, after = motions[answered - 1][0]["odometry"], motions[answered][0]["odometry"]
    assert before["travelled_m"] > 0.0
    assert after["travelled_m"] == 0.0
    assert (after["start_east_m"], after["start_north_m"]) == (0.0, 0.0)
    assert "Flown 0 m since the current instruction was given" in motions[answered][1][-1].text
    assert len(rollout.views) > answered
