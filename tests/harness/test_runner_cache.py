"""Per-thread controllers: threads never share a CasADi solver, a thread reuses its own."""

from __future__ import annotations

import json
import threading

from skyvln_eval.control import Controller
from skyvln_eval.harness import runner

SETTINGS = json.dumps({"compile": "never"}, sort_keys=True)


def test_each_thread_builds_and_keeps_its_own_controller() -> None:
    seen: list[tuple[Controller, Controller]] = []  # references keep every object alive

    def twice() -> None:
        seen.append((runner._controller("nmpc", SETTINGS), runner._controller("nmpc", SETTINGS)))

    threads = [threading.Thread(target=twice) for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    twice()  # and this thread
    assert len(seen) == 3
    assert all(first is again for first, again in seen)
    assert len({id(first) for first, _ in seen}) == 3
    assert runner._controller("pid", "{}") is not seen[-1][0]
