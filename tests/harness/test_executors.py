"""Executors give the same results whatever their kind and worker count."""

from __future__ import annotations

import os

import pytest

from skyvln_eval.errors import ConfigError, UnknownNameError
from skyvln_eval.harness.executors import make_executor


def square_or_fail(x: int) -> int:
    if x == 3:
        raise ValueError("three")
    return x * x


def crash_worker(x: int) -> int:
    if x == 2:
        os._exit(1)  # the worker process dies
    return x


@pytest.mark.parametrize(("kind", "workers"), [("serial", 1), ("threads", 3), ("processes", 2)])
def test_results_do_not_depend_on_the_executor(kind: str, workers: int) -> None:
    results = dict(make_executor(kind, workers).map_unordered(square_or_fail, list(range(6))))
    assert {k: v for k, v in results.items() if k != 3} == {0: 0, 1: 1, 2: 4, 4: 16, 5: 25}
    assert isinstance(results[3], ValueError)


def test_a_crashed_worker_process_is_reported_not_raised() -> None:
    results = dict(make_executor("processes", 2).map_unordered(crash_worker, [0, 1, 2]))
    assert isinstance(results[2], Exception)
    assert len(results) == 3


def test_bad_executor_settings() -> None:
    with pytest.raises(UnknownNameError, match="Did you mean 'threads'"):
        make_executor("thread", 2)
    with pytest.raises(ConfigError, match="at least 1"):
        make_executor("processes", 0)


def test_ray_executor_matches_the_local_one() -> None:
    pytest.importorskip(
        "ray", reason="the ray extra is not installed: pip install 'skyvln-eval[ray]'"
    )
    local = dict(make_executor("serial", 1).map_unordered(square_or_fail, list(range(5))))
    remote = dict(make_executor("ray", 2).map_unordered(square_or_fail, list(range(5))))
    assert {k: v for k, v in remote.items() if k != 3} == {k: v for k, v in local.items() if k != 3}
    assert isinstance(remote[3], Exception) and "three" in str(remote[3])
