"""A loopback HTTP server speaking the OpenAI chat-completions protocol, with scripted faults.

For tests, benchmarks and offline demonstrations of the ``openai`` backend: it runs on
127.0.0.1 and needs no key.

Each request to ``POST /v1/chat/completions`` takes the next :class:`Reply` of the script:
an answer, an HTTP error status (with headers, e.g. Retry-After), a hang longer than the
client's timeout, a malformed JSON body, a body cut short, no choices but the usage, a
body of any content type as given (``raw``), an error echoing the API key in every
escaping (``echo_key``), or an answer sent one byte at a
time (``trickle``: each byte well within any read timeout, the whole far past it). A reply
with a ``task`` waits for a request of that task; requests it does not match, and all
requests once the script is used up, are answered as the offline ``rule`` backend would, so
a whole agent can run against the server. Images in a request are decoded as a real server
would (``images`` of each kept request: MIME type, size, pixel shape or the decoding
error). The server knows a request's task only from its task data, which the ``openai``
backend sends to test servers only when told to (``send_task_data``); a request without
task data gets a plain text answer. Every request is kept in ``requests`` (parsed JSON
body, headers and task) for the test to inspect.

``python -m skyvln_eval.llm.loopback --latency-s 0.2`` serves from a process of its own
(the first line it prints is the base URL; it stops when its standard input closes), for
benchmarks whose client must not share its interpreter with the server, as no remote
model does.

``structured`` makes the server treat ``response_format`` as real servers do: ``"all"``
accepts every form, ``"llama_cpp"`` answers the ``json_schema`` form with HTTP 500 naming
``response_format`` (as llama.cpp's server does) and accepts ``json_object``, ``"none"``
refuses any ``response_format`` with HTTP 400. ``parameters="openai_reasoning"`` makes
it refuse decoding parameters as OpenAI's reasoning models (o1, o3, gpt-5) do, with their
error bodies (HTTP 400 with ``param`` and ``code``): ``max_tokens`` (they take
``max_completion_tokens``), a ``temperature`` or ``top_p`` other than 1, and ``stop``.
"""

from __future__ import annotations

import argparse
import base64
import binascii
import contextlib
import json
import sys
import threading
import time
import urllib.parse
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, Literal

import cv2
import numpy as np

from skyvln_eval.llm.openai_request import TASK_DATA_FIELD
from skyvln_eval.llm.rule import RuleBackend
from skyvln_eval.llm.types import GenerationConfig, Message

ReplyKind = Literal[
    "answer",
    "status",
    "hang",
    "malformed",
    "truncated",
    "trickle",
    "refuse_schema",
    "refusal",
    "error_body",
    "no_choices",
    "raw",
    "echo_key",
    "rule",
]
StructuredMimic = Literal["all", "llama_cpp", "none"]
ParameterMimic = Literal["all", "openai_reasoning"]
#: The usage object of every answer unless a reply says otherwise.
USAGE: dict[str, Any] = {"prompt_tokens": 100, "completion_tokens": 20, "total_tokens": 120}


@dataclass(frozen=True)
class Reply:
    kind: ReplyKind
    content: str = ""
    status: int = 200
    headers: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0
    task: str | None = None
    finish_reason: str | None = "stop"
    content_type: str = "application/json"
    usage: dict[str, Any] | None = field(default_factory=lambda: dict(USAGE))
    #: A refusal's message content beside its ``refusal`` (``None``: content null).
    content_beside: str | None = None


def answer(
    content: str,
    task: str | None = None,
    finish_reason: str | None = "stop",
    usage: dict[str, Any] | None = USAGE,
) -> Reply:
    """An answer; ``finish_reason="length"`` says it was cut off at ``max_tokens`` (``None``:
    the server gives no reason, as some do); ``usage`` is the usage object sent (``None``:
    none)."""
    kept = None if usage is None else dict(usage)
    return Reply("answer", content=content, task=task, finish_reason=finish_reason, usage=kept)


def raw(body: str, content_type: str = "application/json", code: int = 200) -> Reply:
    """``body`` as it is, with that content type and status: a gateway's HTML page, a
    JSON body cut off or not JSON at all."""
    return Reply("raw", content=body, status=code, content_type=content_type)


def echo_key(code: int = 400) -> Reply:
    """HTTP ``code`` whose body echoes the request's API key in every form a server may
    write it (see :func:`key_forms`), in legal JSON, as servers that quote a wrong key do."""
    return Reply("echo_key", status=code)


def refusal(text: str, task: str | None = None, content: str | None = None) -> Reply:
    """The model declines, as OpenAI's structured outputs report it: the reason in the
    message's ``refusal``, no content (or ``content`` beside it, as a server may send)."""
    return Reply("refusal", content=text, task=task, content_beside=content)


def error_body(message: str, task: str | None = None) -> Reply:
    """HTTP 200 with an error object and no choices, as gateways (OpenRouter) answer when
    the model behind them failed."""
    return Reply("error_body", content=message, task=task)


def no_choices(task: str | None = None) -> Reply:
    """HTTP 200 with an empty ``choices`` list but a ``usage`` object (100 prompt and 20
    completion tokens): the server billed a request it gave no answer to."""
    return Reply("no_choices", task=task)


def status(code: int, task: str | None = None, message: str = "", **headers: str) -> Reply:
    """An HTTP error; ``message`` is the error body's message (default: the server's)."""
    fixed = {k.replace("_", "-"): v for k, v in headers.items()}
    return Reply("status", content=message, status=code, headers=fixed, task=task)


def hang(seconds: float, task: str | None = None) -> Reply:
    return Reply("hang", seconds=seconds, task=task)


def malformed(task: str | None = None) -> Reply:
    return Reply("malformed", task=task)


def truncated(task: str | None = None) -> Reply:
    return Reply("truncated", task=task)


def trickle(content: str, seconds_per_byte: float, task: str | None = None) -> Reply:
    """An answer whose whole response (status line, headers, body) goes out one byte at a
    time, ``seconds_per_byte`` apart: every read of the client succeeds within its read
    timeout while the response as a whole takes as long as the server likes."""
    return Reply("trickle", content=content, seconds=seconds_per_byte, task=task)


def rule(task: str | None = None) -> Reply:
    """Answer as the rule backend would (what unmatched requests get anyway)."""
    return Reply("rule", task=task)


def refuse_schema(content: str) -> Reply:
    """HTTP 400 when the request carries ``response_format``, else ``content``."""
    return Reply("refuse_schema", content=content)


def key_forms(key: str) -> dict[str, str]:
    """The forms :func:`echo_key` writes the key in: as sent, JSON-escaped with ``/`` as
    ``\\/``, every character ``\\uXXXX``-escaped, half of them so (mixed), URL-encoded
    as a path (``quote``) and as a form field (``quote_plus``), and in base64 as a server
    that echoes the ``Authorization`` header may show it: the key's own (standard, and
    URL-safe without padding) and the token of Basic auth with the key as password."""
    slashed = json.dumps(key)[1:-1].replace("/", "\\/")
    mixed = "".join(f"\\u{ord(c):04x}" if k % 2 else json.dumps(c)[1:-1] for k, c in enumerate(key))
    return {
        "exact": key,
        "json_slash": slashed,
        "unicode": "".join(f"\\u{ord(c):04X}" for c in key),
        "mixed": mixed,
        "url": urllib.parse.quote(key, safe=""),
        "url_plus": urllib.parse.quote_plus(key),
        "base64": base64.b64encode(key.encode()).decode(),
        "base64_url": base64.urlsafe_b64encode(key.encode()).decode().rstrip("="),
        "basic_auth": base64.b64encode(f"user:{key}".encode()).decode(),
    }


def _key_echo_body(authorization: str) -> bytes:
    """A JSON error body naming the key of ``authorization`` in every form of
    :func:`key_forms` (written by hand: ``json.dumps`` would pick one escaping)."""
    forms = key_forms(authorization.removeprefix("Bearer "))
    fields = ", ".join(f'"{name}": "{form}"' for name, form in forms.items())
    text = (
        '{"error": {"message": "Incorrect API key provided: '
        + forms["json_slash"]
        + " (Authorization: Basic "
        + forms["basic_auth"]
        + ')", '
        + fields
        + ', "code": "invalid_api_key"}}'
    )
    return text.encode("utf-8")


def _images(body: dict[str, Any]) -> list[dict[str, Any]]:
    """Every image of the request, decoded as a real server would have to: its MIME type,
    byte size and pixel shape, or the reason it could not be decoded."""
    out = []
    for message in body.get("messages", []):
        content = message.get("content")
        for part in content if isinstance(content, list) else []:
            if part.get("type") != "image_url":
                continue
            url = str(part.get("image_url", {}).get("url", ""))
            head, _, data = url.partition(",")
            info: dict[str, Any] = {"mime_type": head.removeprefix("data:").split(";")[0]}
            try:
                raw = base64.b64decode(data, validate=True)
                pixels = cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_COLOR)
                info["bytes"] = len(raw)
                info["shape"] = None if pixels is None else list(pixels.shape)
                info["error"] = None if pixels is not None else "not a decodable image"
            except (ValueError, binascii.Error) as error:
                info["error"] = f"not base64: {error}"
            out.append(info)
    return out


def _task_data(body: dict[str, Any]) -> dict[str, Any] | None:
    data = body.get(TASK_DATA_FIELD)
    return data if isinstance(data, dict) and "task" in data else None


def _format_refusal(body: dict[str, Any], structured: StructuredMimic) -> tuple[int, str] | None:
    """The (status, message) a real server of that kind gives the request's format, if any."""
    fmt = body.get("response_format")
    if fmt is None or structured == "all":
        return None
    if structured == "none":
        return 400, "response_format is not supported by this server"
    if fmt.get("type") == "json_schema":  # llama.cpp's server
        return 500, "Internal error: response_format type json_schema is not supported"
    return None


def _parameter_refusal(body: dict[str, Any], parameters: ParameterMimic) -> dict[str, Any] | None:
    """The HTTP 400 error object an OpenAI reasoning model gives the request, if any."""
    if parameters == "all":
        return None
    if "max_tokens" in body:
        return {
            "message": "Unsupported parameter: 'max_tokens' is not supported with this model. "
            "Use 'max_completion_tokens' instead.",
            "type": "invalid_request_error",
            "param": "max_tokens",
            "code": "unsupported_parameter",
        }
    for name in ("temperature", "top_p"):
        if name in body and body[name] != 1:
            return {
                "message": f"Unsupported value: '{name}' does not support {body[name]} with "
                "this model. Only the default (1) value is supported.",
                "type": "invalid_request_error",
                "param": name,
                "code": "unsupported_value",
            }
    if "stop" in body:
        return {
            "message": "Unsupported parameter: 'stop' is not supported with this model.",
            "type": "invalid_request_error",
            "param": "stop",
            "code": "unsupported_parameter",
        }
    return None


def _completion_body(
    content: str | None,
    model: str,
    finish_reason: str | None = "stop",
    refused: str | None = None,
    usage: dict[str, Any] | None = USAGE,
) -> bytes:
    message: dict[str, Any] = {"role": "assistant", "content": content}
    if refused is not None:
        message["refusal"] = refused
    body = {
        "id": "chatcmpl-fake",
        "object": "chat.completion",
        "created": 0,
        "model": model,
        "choices": [
            {
                "index": 0,
                "message": message,
                "finish_reason": finish_reason,
            }
        ],
    }
    if usage is not None:
        body["usage"] = usage
    return json.dumps(body).encode()


class _QuietServer(ThreadingHTTPServer):
    """A client that went away mid-request (timed out, interrupted) is no server fault."""

    def handle_error(self, request: Any, client_address: Any) -> None:
        if not isinstance(sys.exc_info()[1], ConnectionError):
            super().handle_error(request, client_address)


#: The one endpoint the server answers (OpenAI's chat completions under ``base_url``).
CHAT_PATH = "/v1/chat/completions"


class LoopbackOpenAIServer:
    """``with LoopbackOpenAIServer(script) as server:``; ``server.base_url`` ends in /v1.

    It answers only POST /v1/chat/completions with a bearer key (any), as a real server."""

    def __init__(
        self,
        script: list[Reply] | None = None,
        error_message: str = "injected",
        latency_s: float = 0.0,
        structured: StructuredMimic = "all",
        parameters: ParameterMimic = "all",
    ) -> None:
        """``latency_s`` delays every answer, as a remote model's response time would."""
        self.script = list(script or [])
        self.latency_s = latency_s
        self.structured = structured
        self.parameters = parameters
        self.requests: list[dict[str, Any]] = []
        self._lock = threading.Lock()
        outer = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"
            # Headers and body go out in two writes; with Nagle's algorithm on, the body
            # then waits for the client's delayed ACK (~40 ms a reply on Linux), which real
            # servers (uvicorn, llama.cpp) avoid by setting TCP_NODELAY as this does.
            disable_nagle_algorithm = True

            def log_message(self, format: str, *args: Any) -> None:  # keep test output quiet
                pass

            def _send(
                self,
                code: int,
                body: bytes,
                headers: dict[str, str] | None = None,
                content_type: str = "application/json",
            ) -> None:
                self.send_response(code)
                self.send_header("Content-Type", content_type)
                self.send_header("Content-Length", str(len(body)))
                for key, value in (headers or {}).items():
                    self.send_header(key, value)
                self.end_headers()
                self.wfile.write(body)

            def _error(
                self,
                code: int,
                headers: dict[str, str] | None = None,
                message: str = "",
                error: dict[str, Any] | None = None,
            ) -> None:
                text = message or f"{error_message} HTTP {code}"
                body = {"error": error or {"message": text, "type": "test"}}
                self._send(code, json.dumps(body).encode(), headers)

            def _trickle(self, body: bytes, seconds_per_byte: float) -> None:
                head = (
                    "HTTP/1.1 200 OK\r\nContent-Type: application/json\r\n"
                    f"Content-Length: {len(body)}\r\n\r\n"
                ).encode("ascii")
                with contextlib.suppress(OSError):  # the client gave up and closed
                    for k, byte in enumerate(head + body):
                        if k:
                            time.sleep(seconds_per_byte)
                        self.wfile.write(bytes([byte]))
                self.close_connection = True

            def do_POST(self) -> None:
                length = int(self.headers.get("Content-Length", "0"))
                raw = self.rfile.read(length)
                # As a real server: only its chat endpoint, and only with a key (OpenAI's
                # answers 401 without one; llama.cpp and vLLM take any). A client that
                # posted elsewhere or sent no key passed every test against an earlier
                # version of this server, which answered any request.
                if self.path.split("?")[0].rstrip("/") != CHAT_PATH:
                    self._error(404, message=f"no such endpoint: POST {self.path}")
                    return
                if not self.headers.get("Authorization", "").startswith("Bearer "):
                    self._error(401, message="missing bearer token (Authorization header)")
                    return
                body = json.loads(raw or b"{}")
                data = _task_data(body)
                task = None if data is None else str(data["task"])
                with outer._lock:
                    outer.requests.append(
                        {
                            "body": body,
                            "headers": dict(self.headers),
                            "task": task,
                            "images": _images(body),
                        }
                    )
                    head = outer.script[0] if outer.script else None
                    reply = Reply("rule")
                    if head is not None and head.task in (None, task):
                        reply = head
                    # A request the model refuses (its format, a parameter) is turned down
                    # before any answer is made: the scripted answer waits for the next.
                    refusal = _format_refusal(body, outer.structured)
                    refused = _parameter_refusal(body, outer.parameters)
                    refusing = reply.kind in ("rule", "answer", "refusal") and (
                        refusal is not None or refused is not None
                    )
                    if reply is head and not refusing:
                        outer.script.pop(0)
                model = str(body.get("model", "fake"))
                if outer.latency_s:
                    time.sleep(outer.latency_s)
                if refusing and refused is not None:
                    self._error(400, error=refused)
                elif refusing and refusal is not None:
                    self._error(refusal[0], message=refusal[1])
                elif reply.kind == "rule":
                    if data is None:  # nothing to answer from: a plain answer
                        text = "Hello from the loopback server."
                    else:
                        request = [Message("user", "", task_data=data)]
                        text = RuleBackend().generate(request, GenerationConfig()).text
                    self._send(200, _completion_body(text, model))
                elif reply.kind == "error_body":
                    failed = {"error": {"message": reply.content, "code": 502}}
                    self._send(200, json.dumps(failed).encode())
                elif reply.kind == "no_choices":
                    empty = json.loads(_completion_body("", model)) | {"choices": []}
                    self._send(200, json.dumps(empty).encode())
                elif reply.kind == "refusal":
                    self._send(
                        200, _completion_body(reply.content_beside, model, refused=reply.content)
                    )
                elif reply.kind == "answer":
                    self._send(
                        200,
                        _completion_body(
                            reply.content, model, reply.finish_reason, None, reply.usage
                        ),
                    )
                elif reply.kind == "raw":
                    self._send(reply.status, reply.content.encode(), None, reply.content_type)
                elif reply.kind == "echo_key":
                    self._send(reply.status, _key_echo_body(self.headers.get("Authorization", "")))
                elif reply.kind == "refuse_schema":
                    if "response_format" in body:
                        self._error(400)
                    else:
                        self._send(200, _completion_body(reply.content, model))
                elif reply.kind == "status":
                    self._error(reply.status, reply.headers, reply.content)
                elif reply.kind == "hang":
                    time.sleep(reply.seconds)
                    with contextlib.suppress(OSError):  # the client has gone
                        self._send(200, _completion_body("too late", model))
                elif reply.kind == "trickle":
                    self._trickle(_completion_body(reply.content, model), reply.seconds)
                elif reply.kind == "malformed":
                    self._send(200, b'{"id": "chatcmpl-fake", "choices": [{"index": 0, "mess')
                elif reply.kind == "truncated":
                    full = _completion_body("cut short", model)
                    self.send_response(200)
                    self.send_header("Content-Type", "application/json")
                    self.send_header("Content-Length", str(len(full)))
                    self.end_headers()
                    self.wfile.write(full[: len(full) // 3])
                    self.wfile.flush()
                    self.close_connection = True
                    self.connection.shutdown(2)

        self._server = _QuietServer(("127.0.0.1", 0), Handler)
        self._server.daemon_threads = True
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)

    @property
    def base_url(self) -> str:
        host, port = self._server.server_address[:2]
        host_text = host.decode() if isinstance(host, bytes) else str(host)
        return f"http://{host_text}:{port}/v1"

    def __enter__(self) -> LoopbackOpenAIServer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._server.shutdown()
        self._server.server_close()
        self._thread.join(timeout=5)


def main(argv: list[str] | None = None) -> None:
    """Serve until standard input closes; print the base URL first (see the module doc)."""
    parser = argparse.ArgumentParser(description="A loopback OpenAI-compatible server.")
    parser.add_argument("--latency-s", type=float, default=0.0, help="delay of every answer")
    parser.add_argument("--structured", choices=("all", "llama_cpp", "none"), default="all")
    args = parser.parse_args(argv)
    with LoopbackOpenAIServer(latency_s=args.latency_s, structured=args.structured) as server:
        print(server.base_url, flush=True)
        sys.stdin.read()


if __name__ == "__main__":
    main()
