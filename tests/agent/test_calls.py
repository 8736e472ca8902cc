"""Repair that can succeed: the reason and the answer go back, hotter, with more room when
the answer was cut off; a module that still gets nothing usable is a recorded failure."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import pytest

from skyvln_eval.agent import AgentConfig, build_agent
from skyvln_eval.agent.calls import JsonCall, call_json
from skyvln_eval.agent.subgoals import (
    DialogText,
    SubGoalPlan,
    parse_subgoals,
    subgoals_json_schema,
)
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.reader import read_log
from skyvln_eval.converters.validate import check_log
from skyvln_eval.harness import RunConfig, run, run_official_episode
from skyvln_eval.llm import LLMConfig, Message, RetryConfig, build_client
from skyvln_eval.llm.loopback import LoopbackOpenAIServer, Reply, answer, refusal, rule
from tests.toy_worlds import town_episode, town_world

RED = "Go north. The destination is a small restaurant with a red roof."
GOOD = json.dumps({"subgoals": [{"kind": "head", "direction": "north"}], "context_landmarks": []})


def _llm(base_url: str, **extra: object) -> LLMConfig:
    return LLMConfig(
        backend="openai:fake-model",
        base_url=base_url,
        timeout_s=5.0,
        retry=RetryConfig(max_attempts=2, initial_delay_s=0.0),
        send_task_data=True,
        **extra,  # type: ignore[arg-type]
    )


def _go_north(llm: LLMConfig) -> JsonCall[SubGoalPlan]:
    """The sub-goals of "Go north." asked of ``llm``, repaired as its config says."""
    dialog = DialogText((), None, "Go north.")
    schema = subgoals_json_schema(dialog)
    return call_json(
        build_client(llm),
        "subgoals",
        [Message("user", "Decompose: go north.")],
        llm.generation("subgoals", json_schema=schema, schema_name="subgoals"),
        functools.partial(parse_subgoals, dialog=dialog),
        llm.repair_policy(),
    )


@pytest.mark.parametrize(
    ("first_reply", "finish", "reason"),
    [
        # What the server's filter let through is not the model's answer, even if it parses.
        (answer(GOOD, finish_reason="content_filter"), "content_filter", "content filter"),
        # OpenAI's structured outputs: no content, the model's reason in ``refusal``.
        (refusal("I cannot help with drones."), "refusal", "declined to answer: 'I cannot"),
        # A server that sends a refusal and content: the content is no answer, even if it
        # parses; the refusal is what the model said.
        (
            refusal("I cannot help with drones.", content=GOOD),
            "refusal",
            "declined to answer: 'I cannot help with drones.\\n[content beside the refusal] {",
        ),
    ],
    ids=["content-filter", "refusal", "refusal-beside-content"],
)
def test_a_filtered_or_refused_answer_is_invalid_with_its_reason_and_repaired(
    first_reply: Reply, finish: str, reason: str
) -> None:
    with LoopbackOpenAIServer([first_reply, answer(GOOD)]) as server:
        call = _go_north(_llm(server.base_url))
    assert call.value is not None and call.repaired
    first, second = call.records
    assert (first.outcome, first.finish_reason) == ("invalid", finish)
    assert reason in (first.error or "")
    assert second.outcome == "ok" and second.repair


def test_a_cut_off_answer_is_asked_again_with_a_larger_budget() -> None:
    script = [answer('{"subgoals": [{"kind": "he', finish_reason="length"), answer(GOOD)]
    with LoopbackOpenAIServer(script) as server:
        call = _go_north(_llm(server.base_url, budgets={"subgoals": 100}, repair_temperature=0.9))
        bodies = [r["body"] for r in server.requests]
    assert call.value is not None and call.repaired
    assert [(b["max_tokens"], b["temperature"]) for b in bodies] == [(100, 0.0), (200, 0.9)]
    assert "cut off after 100 tokens" in bodies[1]["messages"][-1]["content"]
    first, second = call.records
    assert (first.outcome, first.finish_reason) == ("invalid", "length")
    assert "cut off at max_tokens=100" in (first.error or "")
    assert (second.outcome, second.repair, second.max_tokens) == ("ok", True, 200)


def test_sub_goals_that_stay_unusable_are_a_recorded_failure_not_an_empty_plan() -> None:
    cut = answer('{"subgoals": [', task="subgoals", finish_reason="length")
    with LoopbackOpenAIServer([cut, cut]) as server:
        config = AgentConfig(llm=_llm(server.base_url))
        rollout = run_official_episode(build_agent(config), town_episode(RED), town_world())
    subgoals = [c for c in rollout.llm_calls if c.module == "subgoals"]
    assert [c.outcome for c in subgoals] == ["invalid", "invalid"]
    [failure] = [f for f in rollout.failures if f.module == "subgoals"]
    assert failure.step_index == 0 and "cut off" in failure.reason
    assert failure.substitute.startswith("no sub-goals")
    assert rollout.traces[0]["failures"][0]["module"] == "subgoals"
    # The agent goes on from the commander's words, which every motion prompt carries.
    motion = next(e for e in rollout.traces[0]["exchanges"] if e["module"] == "motion")
    assert RED in motion["prompt"][-1]["text"]


def test_budgets_come_from_the_config_per_module() -> None:
    llm = LLMConfig(max_tokens=300, budgets={"subgoals": 2000})
    assert llm.generation("subgoals").max_tokens == 2000
    assert llm.generation("hsd_rank").max_tokens == 256  # not listed: its default budget
    assert llm.generation("detect").max_tokens == 300  # no default budget: max_tokens
    with pytest.raises(ValueError, match="budget of 'motion'"):
        LLMConfig(budgets={"motion": 5})


def test_the_run_log_records_every_attempt_with_tokens_latency_and_decoding(
    tmp_path: Path, sample_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SKYVLN_TEST_KEY", "sk-test")
    script = [answer("not JSON", task="navgpt"), rule(task="navgpt")]
    with LoopbackOpenAIServer(script) as server:
        llm = _llm(server.base_url, api_key_env="SKYVLN_TEST_KEY").model_dump()
        config = RunConfig(
            system="exchange",
            data=str(sample_dir),
            splits=("val_unseen",),
            limit=1,
            executor="serial",
            agent={"name": "navgpt", "llm": llm},  # type: ignore[arg-type]
        )
        report = run(config, tmp_path / "run")
    [log_path] = (tmp_path / "run" / "logs").rglob("*.mcap")
    check = check_log(log_path)
    assert not check.issues, check.issues  # every exchange valid against its schema (v2)
    exchanges = [m.decode() for m in read_log(log_path).topic(t.TOPIC_LLM_EXCHANGE)]
    first, repair = exchanges[0], exchanges[1]
    assert first["error"] is not None and first["calls"][0]["outcome"] == "invalid"
    assert repair["calls"][0]["repair"] is True and repair["error"] is None
    assert repair["decoding"]["temperature"] > first["decoding"]["temperature"]
    for exchange in exchanges:
        assert exchange["decoding"]["schema"] == "decision"
        [call] = exchange["calls"]
        assert call["prompt_tokens"] == 100 and call["completion_tokens"] == 20  # as served
        assert call["latency_s"] > 0 and call["finish_reason"] == "stop"
        assert call["attempt"] == 1 and call["structured_output"] == "json_schema"
        assert call["cost_usd"] is None  # the fake model has no price: unknown, not 0
    assert report.statuses == {"ok": 1}


def test_a_model_that_takes_images_gets_the_views_as_jpeg_and_the_log_names_them() -> None:
    with LoopbackOpenAIServer() as server:
        llm = _llm(server.base_url, takes_images=True, image_max_side_px=64)
        agent = build_agent(AgentConfig(name="navgpt", llm=llm))
        rollout = run_official_episode(agent, town_episode(RED), town_world(), max_steps=2)
        requests = server.requests
    [request] = [r for r in requests if r["task"] == "navgpt"]
    images = request["images"]
    assert len(images) == 5  # four views around and one straight down
    for image in images:  # each decodable by the server, and within the size cap
        assert image["error"] is None and image["mime_type"] == "image/jpeg"
        assert max(image["shape"][:2]) <= 64
    sent = rollout.traces[0]["exchanges"][0]["prompt"][-1]["images"]
    assert len(sent) == 5 and all(label.startswith("view ") for label in sent)
    assert any("below" in label for label in sent)
    # A model that does not take images gets none (and none are even encoded).
    with LoopbackOpenAIServer() as server:
        agent = build_agent(AgentConfig(name="navgpt", llm=_llm(server.base_url)))
        run_official_episode(agent, town_episode(RED), town_world(), max_steps=2)
        assert all(r["images"] == [] for r in server.requests)


def test_hsd_crops_go_as_jpeg_within_the_size_cap_too() -> None:
    # An audit: HSD's candidate crops went as full-size PNG whatever image_max_side_px said.
    with LoopbackOpenAIServer() as server:
        llm = _llm(server.base_url, takes_images=True, image_max_side_px=32)
        run_official_episode(build_agent(AgentConfig(llm=llm)), town_episode(RED), town_world())
        described = [r for r in server.requests if r["task"] == "hsd_describe"]
    assert described  # the red roof was a candidate to describe
    for request in described:
        [image] = request["images"]
        assert image["error"] is None and image["mime_type"] == "image/jpeg"
        assert max(image["shape"][:2]) <= 32


def test_each_decision_is_sent_a_schema_naming_only_the_landmarks_it_may_fly_to() -> None:
    with LoopbackOpenAIServer() as server:
        config = AgentConfig(llm=_llm(server.base_url))
        run_official_episode(build_agent(config), town_episode(RED), town_world())
        motion = [r for r in server.requests if r["task"] == "motion"]
    offered = []
    for request in motion:
        schema = request["body"]["response_format"]["json_schema"]["schema"]
        variants = {
            v["properties"]["type"]["enum"][0]: v for v in schema["properties"]["action"]["anyOf"]
        }
        ids = variants["fly_to"]["properties"]["landmark"]["enum"] if "fly_to" in variants else []
        prompt = request["body"]["messages"][-1]["content"]
        text = prompt if isinstance(prompt, str) else " ".join(p.get("text", "") for p in prompt)
        assert all(i in text for i in ids)  # ids the prompt lists, nothing else
        offered.append(len(ids))
    print(f"\nlandmark ids offered per decision: {offered}")
    assert motion and any(offered)  # landmarks were in view at some decision
