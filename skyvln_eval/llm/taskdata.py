"""The machine-readable part of every agent prompt: one fenced JSON block with a ``task``.

Each prompt the agent sends ends with a block like::

    TASK DATA (JSON):
    ```json
    {"task": "motion", "version": 1, ...}
    ```

An LLM reads it along with the prose; the offline ``rule`` and ``random`` backends read
only it. Keeping one writer and one reader here means the two cannot drift apart.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from typing import Any, Final

from skyvln_eval.errors import LLMError
from skyvln_eval.llm.types import Message

TASK_DATA_VERSION: Final = 1
HEADER: Final = "TASK DATA (JSON):"
_BLOCK = re.compile(r"```json\s*\n(.*?)\n```", re.DOTALL)


def task_block(task: str, data: dict[str, Any]) -> str:
    """The fenced block for ``task`` carrying ``data`` (keys ``task`` and ``version`` are added)."""
    body = {"task": task, "version": TASK_DATA_VERSION, **data}
    return f"{HEADER}\n```json\n{json.dumps(body, ensure_ascii=False, allow_nan=False)}\n```"


def read_task_block(messages: Sequence[Message]) -> dict[str, Any]:
    """The task block of the latest user message that has one (a repair request has none,
    so the block of the question being repaired is found); :class:`LLMError` without any."""
    for message in reversed(messages):
        if message.role != "user":
            continue
        for raw in reversed(_BLOCK.findall(message.text)):
            try:
                data = json.loads(raw)
            except json.JSONDecodeError:
                continue
            if isinstance(data, dict) and "task" in data:
                if data.get("version") != TASK_DATA_VERSION:
                    raise LLMError(
                        f"task data version {data.get('version')!r}, this backend reads "
                        f"{TASK_DATA_VERSION}"
                    )
                return data
    raise LLMError("the prompt has no TASK DATA block: offline backends read only that block")
