"""The machine-readable side of every agent prompt: one ``task_data`` dict per request.

Each request the agent sends carries, besides its text, the same content as data::

    {"task": "motion", "version": 2, ...}

on its last user message (:attr:`~skyvln_eval.llm.types.Message.task_data`). A model
server never receives it: models read the text. The offline ``rule`` and ``random``
backends read only the data. The prompt writers render every field they put in the data
into the text as well, so a stand-in knows nothing a model is not told. Keeping one
writer and one reader here means the two sides cannot drift apart.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final

from skyvln_eval.errors import LLMError
from skyvln_eval.llm.types import ImagePart, Message

TASK_DATA_VERSION: Final = 2


def task_message(
    text: str, task: str, data: dict[str, Any], images: Sequence[ImagePart] = ()
) -> Message:
    """A user message for ``task``: ``text`` for models, ``data`` for offline stand-ins."""
    payload = {"task": task, "version": TASK_DATA_VERSION, **data}
    return Message("user", text, tuple(images), task_data=payload)


def read_task_data(messages: Sequence[Message]) -> dict[str, Any]:
    """The task data of the latest user message that has some (a repair request has none,
    so the data of the question being repaired is found); :class:`LLMError` without any."""
    for message in reversed(messages):
        if message.role != "user" or message.task_data is None:
            continue
        data = message.task_data
        if data.get("version") != TASK_DATA_VERSION:
            raise LLMError(
                f"task data version {data.get('version')!r}, this backend reads {TASK_DATA_VERSION}"
            )
        return dict(data)
    raise LLMError("the request carries no task data: offline backends read only that")
