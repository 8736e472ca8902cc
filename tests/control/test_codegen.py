"""Compiled solver functions: the cache, its key, its repair, and the no-compiler fallback."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from skyvln_eval.control import MpcConfig, NmpcController, codegen
from skyvln_eval.errors import SolverBuildError
from skyvln_eval.sim import ObstacleForecast, segment_reference
from tests.control.helpers import START, TARGET

needs_gcc = pytest.mark.skipif(codegen.compiler() is None, reason="no C compiler ($CC or gcc)")


def tiny() -> ca.Function:
    x = ca.SX.sym("x", 2)
    return ca.Function("tiny_test_fn", [x], [ca.sin(x) * x[0]])


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("SKYVLN_EVAL_CACHE", str(tmp_path))
    return tmp_path


@needs_gcc
def test_a_compiled_function_is_cached_and_reused(
    cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    compiled, is_compiled = codegen.maybe_compile(tiny(), "always")
    assert is_compiled
    assert np.allclose(
        np.asarray(compiled([0.5, 2.0])).ravel(), np.asarray(tiny()([0.5, 2.0])).ravel()
    )
    assert len(list((cache / "casadi").glob("tiny_test_fn-*.so"))) == 1

    def no_build(*args: object) -> None:
        raise AssertionError("the cached library should have been reused")

    monkeypatch.setattr(codegen, "_build", no_build)
    again, is_compiled = codegen.maybe_compile(tiny(), "always")
    assert is_compiled and np.allclose(
        np.asarray(again([1.0, 1.0])), np.asarray(compiled([1.0, 1.0]))
    )


@needs_gcc
def test_a_broken_cache_entry_is_rebuilt(cache: Path) -> None:
    codegen.maybe_compile(tiny(), "always")
    (library,) = (cache / "casadi").glob("tiny_test_fn-*.so")
    library.write_bytes(b"not a shared library")
    compiled, is_compiled = codegen.maybe_compile(tiny(), "always")
    assert is_compiled
    assert np.allclose(np.asarray(compiled([0.5, 2.0])), np.asarray(tiny()([0.5, 2.0])))


def test_the_key_changes_with_the_problem() -> None:
    x = ca.SX.sym("x", 2)
    other = ca.Function("tiny_test_fn", [x], [ca.cos(x) * x[0]])
    assert codegen.cache_key(tiny(), "gcc") == codegen.cache_key(tiny(), "gcc")
    assert codegen.cache_key(tiny(), "gcc") != codegen.cache_key(other, "gcc")


def test_without_a_compiler_functions_run_interpreted_with_one_warning(
    cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(codegen, "compiler", lambda: None)
    monkeypatch.setattr(codegen, "_warned_no_compiler", False)
    with pytest.warns(RuntimeWarning, match="no C compiler"):
        function, is_compiled = codegen.maybe_compile(tiny(), "auto")
    assert not is_compiled and function.name() == "tiny_test_fn"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a second build says nothing more
        codegen.maybe_compile(tiny(), "auto")
    with pytest.raises(SolverBuildError, match="no C compiler"):
        codegen.maybe_compile(tiny(), "always")
    assert not (cache / "casadi").exists()


@needs_gcc
@pytest.mark.slow
def test_the_compiled_nmpc_gives_the_interpreted_commands(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Compiling takes 10-25 s: with SKYVLN_EVAL_CACHE set it happens once per problem
    # definition and later runs load the library; otherwise once per test session.
    root = os.environ.get("SKYVLN_EVAL_CACHE") or str(tmp_path_factory.mktemp("solver-cache"))
    monkeypatch.setenv("SKYVLN_EVAL_CACHE", root)
    compiled = NmpcController(MpcConfig(compile="always"))
    interpreted = NmpcController(MpcConfig(compile="never"))
    assert compiled.qp.compiled and not interpreted.qp.compiled
    reference = segment_reference(START, TARGET, 0.0)
    for k in range(5):
        times = 0.1 * (k + np.arange(21))
        window, forecast = reference.window(times), ObstacleForecast.none(times)
        a = compiled.step(START, window, forecast)
        b = interpreted.step(START, window, forecast)
        assert np.allclose(a.inputs, b.inputs, atol=1e-9)
