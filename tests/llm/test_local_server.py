"""The real llama.cpp server: what it does with structured output and system messages (the
facts negotiation and ``system_role`` rest on), and the agent's calls answered by it."""

from __future__ import annotations

import contextlib
import functools
import json
import os
import re
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from skyvln_eval.agent.actions import Stop, decision_json_schema
from skyvln_eval.agent.calls import CUT_OFF_REQUEST, call_json
from skyvln_eval.agent.motion import SYSTEM_PROMPT, MotionGenerator
from skyvln_eval.agent.subgoals import (
    DialogText,
    parse_subgoals,
    phrase_words,
    subgoals_json_schema,
)
from skyvln_eval.llm import GenerationConfig, LLMClient, Message
from skyvln_eval.llm.config import LLMConfig, RepairPolicy, build_client
from skyvln_eval.llm.local_server import MODEL_ALIAS, find_local_llama, llm_settings

SCHEMA = {
    "type": "object",
    "properties": {"colour": {"type": "string", "enum": ["red", "blue"]}},
    "required": ["colour"],
}


def _post(
    base_url: str,
    response_format: dict[str, Any],
    prompt: str = "Pick a colour, answer in JSON.",
    max_tokens: int = 24,
) -> tuple[int, str]:
    body = {
        "model": MODEL_ALIAS,
        "messages": [{"role": "user", "content": prompt}],
        "max_tokens": max_tokens,
        "temperature": 0.0,
        "response_format": response_format,
    }
    request = urllib.request.Request(
        f"{base_url}/chat/completions",
        data=json.dumps(body).encode(),
        headers={"Content-Type": "application/json"},
    )
    try:
        with urllib.request.urlopen(request, timeout=120) as reply:
            return reply.status, reply.read().decode()
    except urllib.error.HTTPError as error:
        return error.code, error.read().decode("utf-8", "replace")


def test_real_server_refuses_strict_json_schema_and_constrains_json_object(
    local_llm_url: str,
) -> None:
    strict = {"type": "json_schema", "json_schema": {"name": "c", "schema": SCHEMA, "strict": True}}
    status, body = _post(local_llm_url, strict)
    # llama-cpp-python answers the OpenAI json_schema form with a server error, not a 400,
    # whose body names response_format: why negotiation reads 5xx bodies, not only 400s.
    assert status == 500 and "response_format" in body
    status, text = _post(local_llm_url, {"type": "json_object", "schema": SCHEMA})
    assert status == 200
    reply = json.loads(text)
    content = json.loads(reply["choices"][0]["message"]["content"], strict=False)
    assert content["colour"] in ("red", "blue")  # grammar-constrained to the enum
    assert reply["usage"]["prompt_tokens"] > 0


def test_the_sub_goal_grammar_lets_the_model_copy_only_the_dialogs_words(
    local_llm_url: str,
) -> None:
    """The per-dialog schema becomes the server's grammar (the server refuses patterns it
    cannot convert, e.g. "(?:"); every phrase written under it, even cut off, is made of
    the dialog's words (unconstrained, Gemma 3 270M wrote the landmark "}, {")."""
    dialog = DialogText((), None, "Go south past the bridge and stop at the gas station.")
    schema = subgoals_json_schema(dialog)
    prompt = f"Extract the sub-goals as JSON: {dialog.instruction}"
    status, text = _post(local_llm_url, {"type": "json_object", "schema": schema}, prompt, 60)
    assert status == 200, text
    content = json.loads(text)["choices"][0]["message"]["content"]
    # Landmarks, names and the context landmarks' complete strings, of a JSON maybe cut off.
    phrases = re.findall(r'"(?:landmark|name)"\s*:\s*"([^"]*)"', content)
    _, _, context = content.partition('"context_landmarks"')
    phrases += re.findall(r'"([^"]*)"', context)
    print(f"\nphrases written: {phrases}")
    assert phrases, content
    for phrase in phrases:
        assert phrase_words(phrase) and set(phrase_words(phrase)) <= dialog.words(), phrase


# The backend and the agent's calls against the real server, call by call: short prompts,
# a few seconds each, so that every test run checks them (the full agent on whole
# episodes, test_real_llm.py, takes minutes).


def _client(base_url: str, **overrides: Any) -> LLMClient:
    return build_client(LLMConfig(**llm_settings(base_url, timeout_s=180.0, **overrides)))


def test_the_system_prompt_reaches_a_model_without_a_system_role(local_llm_url: str) -> None:
    # As a system message, this server's gemma chat format leaves it out of the prompt (the
    # same prompt tokens with it and without: see skyvln_eval.llm.local_server).
    client = _client(local_llm_url, system_role=False)
    question = Message("user", "Which way is north?")
    config = GenerationConfig(max_tokens=16, timeout_s=180.0)
    alone = client.call("motion", [question], config).records[-1].prompt_tokens
    both = (
        client.call("motion", [Message("system", SYSTEM_PROMPT), question], config)
        .records[-1]
        .prompt_tokens
    )
    assert alone is not None and both is not None, "the server reports prompt tokens"
    print(f"\nsystem prompt of {len(SYSTEM_PROMPT)} characters: {both - alone} more prompt tokens")
    # Folded into the first user turn, all of it is read (a token per 2-6 characters).
    assert both - alone >= len(SYSTEM_PROMPT) / 8


def test_an_answer_cut_off_at_its_budget_is_detected_and_asked_for_with_more(
    local_llm_url: str,
) -> None:
    client = _client(local_llm_url)
    instruction = "Fly north past the church, turn left at the bridge, stop at the tower."
    dialog = DialogText((), None, instruction)
    config = GenerationConfig(
        max_tokens=16,
        timeout_s=180.0,
        json_schema=subgoals_json_schema(dialog),
        schema_name="subgoals",
    )
    messages = [
        Message("system", "Extract the sub-goals of a drone's instruction as JSON."),
        Message("user", instruction),
    ]
    parse = functools.partial(parse_subgoals, dialog=dialog)
    call = call_json(client, "subgoals", messages, config, parse, RepairPolicy())
    # llama.cpp refuses the strict json_schema form (HTTP 500): that request is recorded as
    # such, with its own time; the cut-off answer and its repair come after it.
    refused, first, second = call.records[:3]
    assert refused.outcome == "refused" and refused.structured_output == "json_schema"
    assert refused.latency_s > 0 and "HTTP 500" in (refused.error or "")
    assert first.finish_reason == "length" and first.outcome == "invalid"
    assert "max_tokens=16" in (first.error or "")
    assert second.repair and second.max_tokens == 32 and second.temperature == 0.7
    assert CUT_OFF_REQUEST.format(tokens=16) in call.exchanges[1]["prompt"][-1]["text"]
    assert call.value is not None or "no usable answer" in (call.error or "")


def test_real_decisions_are_parsed_or_refused_with_a_reason_the_repair_carries(
    local_llm_url: str,
) -> None:
    llm = LLMConfig(**llm_settings(local_llm_url, timeout_s=180.0))
    config = llm.generation("motion", json_schema=decision_json_schema(), schema_name="decision")
    motion = MotionGenerator(build_client(llm), replace(config, max_tokens=96), llm.repair_policy())
    prompts = [
        "The commander says: fly forward about 100 m, then stop at the parking lot. You fly "
        "60 m above the ground, heading 0 deg. 5 actions left.",
        "The commander says: turn left and fly to the white building with a red roof. "
        "Landmarks: L1, a white building with a red roof, 120 m away at bearing 270 deg. "
        "4 actions left.",
    ]
    for prompt in prompts:
        result = motion.decide(SYSTEM_PROMPT, prompt, {}, {"L1": (-120.0, 0.0)})
        outcomes = [(r.outcome, r.finish_reason, r.error) for r in result.records]
        print(f"\n{result.action} repaired={result.repaired} calls={outcomes}")
        assert all(r.outcome != "failed" for r in result.records), outcomes  # all answered
        for refused, asked_again in zip(result.exchanges, result.exchanges[1:], strict=False):
            # Whatever the grammar let through is accepted, or refused with the parser's
            # reason, and that reason goes back to the model.
            assert refused["error"] and refused["error"] in asked_again["prompt"][-1]["text"]
        if result.failure is None:
            assert result.records[-1].outcome == "ok"
        else:  # no usable answer: the fallback says why
            assert isinstance(result.action, Stop)
            assert result.exchanges[-1]["error"] in result.failure.reason


def test_a_prompt_longer_than_the_context_is_its_own_failure_and_not_retried(
    local_llm_url: str,
) -> None:
    client = _client(local_llm_url)
    result = client.call(
        "motion", [Message("user", "north east south west " * 3000)], GenerationConfig()
    )
    assert result.completion is None and len(result.records) == 1  # asked once
    record = result.records[0]
    assert record.outcome == "failed" and record.error is not None
    assert record.error.startswith("LLMContextOverflowError: the prompt does not fit")


def _children(pid: int) -> list[int]:
    """Processes whose parent is ``pid`` (from /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # ended while listed
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


@pytest.mark.skipif(sys.platform != "linux", reason="the server dies with its parent on Linux")
def test_the_server_ends_with_the_process_that_started_it_even_when_killed() -> None:
    """A kill -9 (or a SIGTERM, which Python answers by ending at once) of a benchmark or
    test run skips the ``finally`` that stops the server: it must end all the same."""
    llama = find_local_llama()
    if isinstance(llama, str):
        pytest.skip(f"no real local LLM: {llama}")
    code = (
        "import sys\n"
        "from skyvln_eval.llm.local_server import find_local_llama, local_llama_server\n"
        "with local_llama_server(find_local_llama(), n_threads=1) as url:\n"
        "    print(url, flush=True)\n"
        "    sys.stdin.read()\n"  # until killed
    )
    parent = subprocess.Popen(
        [sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    server = None
    try:
        assert parent.stdout is not None and parent.stdout.readline().startswith("http://")
        (server,) = _children(parent.pid)
        parent.kill()
        parent.wait()
        deadline = time.monotonic() + 30
        while Path(f"/proc/{server}").exists() and time.monotonic() < deadline:
            time.sleep(0.2)
            with contextlib.suppress(ChildProcessError):
                os.waitpid(server, os.WNOHANG)  # not ours: reaped by init, normally
        assert not Path(f"/proc/{server}").exists() or "Z" in _state(server)
    finally:
        parent.kill()
        if server is not None and _state(server) not in ("gone", "Z"):
            os.kill(server, signal.SIGKILL)  # the failure is asserted; no server is left


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "gone"
