"""Per-thread controllers: threads never share a CasADi solver, a thread reuses its own;
worlds are loaded once per process, also by episodes starting together in threads."""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import pytest

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


def test_threads_that_start_together_load_a_world_once(monkeypatch: pytest.MonkeyPatch) -> None:
    loads: list[str] = []

    def slow_load(data_dir: str, map_name: str, georef: Any) -> object:
        loads.append(map_name)
        time.sleep(0.2)  # long enough for every thread to ask while it loads
        return object()

    monkeypatch.setattr(runner, "load_world", slow_load)
    monkeypatch.setattr(runner, "_worlds", type(runner._worlds)())
    got: list[object] = []
    threads = [
        threading.Thread(target=lambda m=m: got.append(runner._world("/data", m, None)))  # type: ignore[misc]
        for m in ["a", "b"] * 4
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert sorted(loads) == ["a", "b"]  # each map once
    assert len({id(world) for world in got}) == 2
