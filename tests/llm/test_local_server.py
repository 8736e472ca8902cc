"""What the real llama.cpp server does with structured output: the facts negotiation rests on."""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from typing import Any

from skyvln_eval.llm.local_server import MODEL_ALIAS

SCHEMA = {
    "type": "object",
    "properties": {"colour": {"type": "string", "enum": ["red", "blue"]}},
    "required": ["colour"],
}


def _post(base_url: str, response_format: dict[str, Any]) -> tuple[int, str]:
    body = {
        "model": MODEL_ALIAS,
        "messages": [{"role": "user", "content": "Pick a colour, answer in JSON."}],
        "max_tokens": 24,
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
