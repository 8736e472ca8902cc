"""The text panels of a recording, as pure functions of the logged messages.

Messages are read defensively: a field that is absent is left out, and fields the
formatter does not know (an LLM exchange's tokens, latency or status, a detection's box)
are shown as they are, so a newer log still shows everything it holds.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from typing import Any

#: LLMExchange fields shown in their own sections; any other field goes in the header.
_EXCHANGE_BODY = frozenset({"timestamp", "episode_id", "step_index", "module", "prompt"})
_EXCHANGE_BODY |= {"response", "error"}
#: Sighting fields used in a sighting's leading words; the rest follow as key=value.
_SIGHTING_HEAD = ("id", "label", "caption", "view", "sector", "sector_name")


#: Characters Markdown may read as markup anywhere in a line (CommonMark lets each be
#: escaped), and what makes a list, heading, quote or rule at a line's start.
_MARKUP = re.compile(r"([\\`*_\[\]<>#!|~])")
_LINE_START = re.compile(r"(?m)^(\s*(?:\d+)?)([-+=.)])")


def _plain(value: Any) -> str:
    """``value`` as a Markdown document shows text from a log (a model's thought, an
    answer's words, a speaker's, a detector's label): what could be markup escaped, so
    the text cannot forge a line of the document ("**Action:** ..." above the real one),
    a heading or an image link."""
    escaped = _MARKUP.sub(r"\\\1", _scalar(value))
    return _LINE_START.sub(lambda m: f"{m.group(1)}\\{m.group(2)}", escaped)


def _scalar(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, str | int | bool) or value is None:
        return str(value)
    return json.dumps(value, ensure_ascii=False, default=str)


def _flat(fields: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """Nested mappings one level flattened (``usage.prompt_tokens``), in their order."""
    out: list[tuple[str, Any]] = []
    for key, value in fields.items():
        if isinstance(value, Mapping):
            out += [(f"{prefix}{key}.{k}", v) for k, v in value.items()]
        else:
            out.append((f"{prefix}{key}", value))
    return out


def fenced(text: str) -> str:
    """Text in a Markdown code fence long enough not to be closed by the text itself."""
    fence = "```"
    while fence in text:
        fence += "`"
    return f"{fence}\n{text}\n{fence}"


def dialog_line(turn: Mapping[str, Any]) -> str:
    speaker = turn.get("speaker", "?")
    return f"[round {turn.get('round_index', '?')}] {speaker}: {turn.get('text', '')}"


def dialog_document(turns: Sequence[Mapping[str, Any]]) -> str:
    lines = ["# Dialog", ""] + [f"- {_plain(dialog_line(turn))}" for turn in turns]
    return "\n".join(lines) + "\n"


def sighting_line(entry: Mapping[str, Any]) -> str:
    """One HSD entry: ``L1 stadium (caption): view front, sector #2 upper-right; k=v ...``."""
    head = f"{entry.get('id', '?')} {entry.get('label', '?')}"
    if entry.get("caption"):
        head += f" ({entry['caption']})"
    where = []
    if "view" in entry:
        where.append(f"view {entry['view']}")
    if "sector" in entry:
        where.append(f"sector #{entry['sector']} {entry.get('sector_name', '')}".rstrip())
    rest = [(k, v) for k, v in _flat(entry) if k not in _SIGHTING_HEAD]
    extra = ", ".join(f"{k}={_scalar(v)}" for k, v in rest)
    return head + (": " + ", ".join(where) if where else "") + (f"; {extra}" if extra else "")


def hsd_document(step: Mapping[str, Any]) -> str:
    trace = step.get("trace") or {}
    lines = [f"# HSD, decision {step.get('step_index', '?')}", ""]
    sightings = trace.get("sightings") or []
    lines += [f"- {_plain(sighting_line(e))}" for e in sightings] or ["(no landmark seen)"]
    matches = trace.get("hsd_matches") or {}
    if matches:
        lines += ["", "## Matches", "", fenced(json.dumps(matches, indent=1, default=str))]
    return "\n".join(lines) + "\n"


def memory_document(step: Mapping[str, Any]) -> str:
    """The TrackBack memory graph of a decision: nodes, then edges, then the way back."""
    trace = step.get("trace") or {}
    memory = trace.get("memory")
    lines = [f"# TrackBack memory, decision {step.get('step_index', '?')}", ""]
    if not memory:
        return "\n".join([*lines, "(no memory: TBMA is off for this agent)"]) + "\n"
    lines.append(f"current node: {memory.get('current', '-')}")
    if "travelled_m" in memory:
        lines.append(f"travelled: {_scalar(memory['travelled_m'])} m")
    lines += ["", "## Nodes", ""]
    for node in memory.get("nodes", []):
        rest = ", ".join(
            f"{k}={_scalar(v)}" for k, v in node.items() if k != "id" and v is not None
        )
        lines.append(f"- {_plain(node.get('id', '?'))}: {_plain(rest)}")
    lines += ["", "## Edges", ""]
    for edge in memory.get("edges", []):
        rest = ", ".join(
            f"{k}={_scalar(v)}"
            for k, v in edge.items()
            if k not in ("from", "to") and v is not None
        )
        ends = f"{edge.get('from', '?')} -> {edge.get('to', '?')}"
        lines.append(f"- {_plain(ends)}: {_plain(rest)}")
    for key in ("way_back", "clarification_question"):
        if trace.get(key):
            lines += ["", f"## {key.replace('_', ' ')}", "", _plain(trace[key])]
    return "\n".join(lines) + "\n"


def step_document(step: Mapping[str, Any], t_s: float) -> str:
    """One decision: thought, action, feedback, sub-goals and what was repaired."""
    trace = step.get("trace") or {}
    lines = [f"# Decision {step.get('step_index', '?')} (t = {t_s:.1f} s)", ""]
    lines += [f"**Thought:** {_plain(step.get('thought', ''))}", ""]
    lines += [f"**Action:** {_plain(json.dumps(step.get('action'), default=str))}", ""]
    if step.get("feedback"):
        lines += [f"**Feedback:** {_plain(step['feedback'])}", ""]
    subgoals = trace.get("subgoals") or []
    done = set(trace.get("done_subgoals") or [])
    if subgoals:
        lines += ["## Sub-goals", ""]
        for i, goal in enumerate(subgoals):
            mark = "x" if i in done else " "
            lines.append(f"- [{mark}] {_plain(json.dumps(goal, default=str))}")
        lines.append("")
    shown = {"subgoals", "done_subgoals", "sightings", "hsd_matches", "memory"}
    rest = {k: v for k, v in trace.items() if k not in shown and v not in (None, [], {}, False)}
    if rest:
        lines += ["## Trace", "", fenced(json.dumps(rest, indent=1, default=str))]
    return "\n".join(lines) + "\n"


def exchange_fields(exchange: Mapping[str, Any]) -> list[tuple[str, Any]]:
    """The fields of an LLM exchange beyond prompt and response (tokens, latency, status...)."""
    extra = {k: v for k, v in exchange.items() if k not in _EXCHANGE_BODY}
    return [(k, v) for k, v in _flat(extra) if v is not None]


def exchange_line(exchange: Mapping[str, Any]) -> str:
    """One line per exchange, for the log panel: module, decision, outcome and its figures."""
    module = exchange.get("module", "?")
    outcome = "error: " + str(exchange["error"]) if exchange.get("error") else "answered"
    if exchange.get("response") is None and not exchange.get("error"):
        outcome = "no response"
    fields = ", ".join(f"{k}={_scalar(v)}" for k, v in exchange_fields(exchange))
    return f"{module} (decision {exchange.get('step_index', '?')}): {outcome}" + (
        f"; {fields}" if fields else ""
    )


def exchange_document(exchange: Mapping[str, Any]) -> str:
    """A prompt and its response in Markdown, with every figure the log holds."""
    lines = [f"# {exchange.get('module', '?')}, decision {exchange.get('step_index', '?')}", ""]
    lines += [f"- {k}: {_plain(v)}" for k, v in exchange_fields(exchange)]
    for message in exchange.get("prompt") or []:
        images = message.get("images") or 0
        if isinstance(images, list):  # the views' names (the run log keeps no pixels here)
            note = f" (images attached, not stored: {', '.join(map(str, images))})"
        else:
            note = f" ({images} image(s) attached, not stored)" if images else ""
        lines += ["", f"## {message.get('role', '?')}{note}", "", fenced(str(message.get("text")))]
    response = exchange.get("response")
    lines += ["", "## response", "", fenced(str(response)) if response is not None else "(none)"]
    if exchange.get("error"):
        lines += ["", "## error", "", fenced(str(exchange["error"]))]
    return "\n".join(lines) + "\n"
