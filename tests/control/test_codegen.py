"""Compiled solver functions: the cache, its key, its lock, its repair, the no-compiler
fallback, and the compiled HPIPM NMPC step against the interpreted one."""

from __future__ import annotations

import multiprocessing
import os
import warnings
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from skyvln_eval.control import Flight, MpcConfig, NmpcController, codegen
from skyvln_eval.errors import SolverBuildError
from skyvln_eval.sim import DroneState, ObstacleForecast, segment_reference
from tests.control.helpers import START, TARGET, scenario

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
    built = codegen.maybe_compile(tiny(), "always")
    assert built.compiled and built.built_now
    assert np.allclose(
        np.asarray(built.function([0.5, 2.0])).ravel(), np.asarray(tiny()([0.5, 2.0])).ravel()
    )
    assert len(list((cache / "casadi").glob("tiny_test_fn-*.so"))) == 1

    def no_build(*args: object) -> None:
        raise AssertionError("the cached library should have been reused")

    monkeypatch.setattr(codegen, "_build", no_build)
    again = codegen.maybe_compile(tiny(), "always")
    assert again.compiled and not again.built_now
    assert np.allclose(
        np.asarray(again.function([1.0, 1.0])), np.asarray(built.function([1.0, 1.0]))
    )


def _compile_tiny(root: str) -> bool:
    os.environ["SKYVLN_EVAL_CACHE"] = root
    return codegen.maybe_compile(tiny(), "always").built_now


@needs_gcc
def test_processes_that_need_the_same_library_at_once_build_it_once(cache: Path) -> None:
    context = multiprocessing.get_context("spawn")
    with context.Pool(3) as pool:
        built = pool.map(_compile_tiny, [str(cache)] * 3)
    assert sorted(built) == [False, False, True]
    assert len(list((cache / "casadi").glob("tiny_test_fn-*.so"))) == 1


@needs_gcc
def test_a_broken_cache_entry_is_rebuilt(cache: Path) -> None:
    codegen.maybe_compile(tiny(), "always")
    (library,) = (cache / "casadi").glob("tiny_test_fn-*.so")
    library.write_bytes(b"not a shared library")
    built = codegen.maybe_compile(tiny(), "always")
    assert built.compiled and built.built_now
    assert np.allclose(np.asarray(built.function([0.5, 2.0])), np.asarray(tiny()([0.5, 2.0])))


def key(function: ca.Function, cc: str = "gcc") -> str:
    return codegen.cache_key(codegen.generated_source(function), cc)


@needs_gcc
def test_a_native_call_computes_what_the_function_does_on_the_callers_arrays(
    cache: Path,
) -> None:
    x = ca.SX.sym("x", 3)
    y = ca.SX.sym("y", 2)
    out = ca.vertcat(ca.sin(x) * y[0], ca.sumsqr(x) + y[1])
    function = ca.Function("native_test_fn", [x, y], [out, ca.cos(y)])
    built = codegen.maybe_compile(function, "always")
    a, b = np.array([0.3, -1.2, 2.5]), np.array([1.5, -0.25])
    first, second = np.zeros(4), np.zeros(2)
    call = codegen.NativeCall(built, (a, b), (first, second))
    assert call() == 0
    expected = function(a, b)
    assert np.array_equal(first, np.asarray(expected[0]).ravel())
    assert np.array_equal(second, np.asarray(expected[1]).ravel())
    a[:] = [1.0, 2.0, 3.0]  # the call reads its inputs in place
    assert call() == 0 and np.array_equal(first, np.asarray(function(a, b)[0]).ravel())
    with pytest.raises(ValueError, match="contiguous float64"):
        codegen.NativeCall(built, (a.astype(np.float32), b), (first, second))


def test_the_key_changes_with_the_problem_and_the_compiler(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    x = ca.SX.sym("x", 2)
    other = ca.Function("tiny_test_fn", [x], [ca.cos(x) * x[0]])
    assert key(tiny()) == key(tiny())
    assert key(tiny()) != key(other)
    before = key(tiny())
    monkeypatch.setattr(codegen, "compiler_identity", lambda cc: "gcc (Debian 99.1) 99.1")
    assert key(tiny()) != before
    monkeypatch.setattr(codegen, "PATCH_REVISION", "another revision")
    assert key(tiny()) != before


def hpipm_call(options: dict[str, float]) -> ca.Function:
    """A function that embeds an HPIPM solve of a one-stage QP with the given options."""
    h, a = ca.DM.eye(2), ca.DM([[1.0, 1.0]])
    solver = ca.conic(
        "tiny_hpipm",
        "hpipm",
        {"h": h.sparsity(), "a": a.sparsity()},
        {"N": 0, "nx": [2], "nu": [0], "ng": [1], "hpipm": options},
    )
    g = ca.MX.sym("g", 2)
    return ca.Function("tiny_qp_fn", [g], [solver(h=h, g=g, a=a, lba=1.0, uba=1.0)["x"]])


def test_the_key_changes_with_an_embedded_solver_option() -> None:
    # A function's serialised form leaves out the options of an embedded QP solver: keyed on
    # it, a changed HPIPM option loaded the library built with the old one.
    assert hpipm_call({"iter_max": 3}).serialize() == hpipm_call({"iter_max": 4}).serialize()
    assert key(hpipm_call({"iter_max": 3})) != key(hpipm_call({"iter_max": 4}))


def test_without_a_compiler_functions_run_interpreted_with_one_warning(
    cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(codegen, "compiler", lambda: None)
    monkeypatch.setattr(codegen, "_warned_no_compiler", False)
    with pytest.warns(RuntimeWarning, match="no C compiler"):
        built = codegen.maybe_compile(tiny(), "auto")
    assert not built.compiled and built.function.name() == "tiny_test_fn"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a second build says nothing more
        codegen.maybe_compile(tiny(), "auto")
    with pytest.raises(SolverBuildError, match="no C compiler"):
        codegen.maybe_compile(tiny(), "always")
    assert not (cache / "casadi").exists()


@needs_gcc
@pytest.mark.slow
def test_the_compiled_hpipm_nmpc_step_flies_exactly_as_the_interpreted_one(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Compiling takes 10-25 s: with SKYVLN_EVAL_CACHE set it happens once per problem
    # definition and later runs load the library; otherwise once per test session.
    root = os.environ.get("SKYVLN_EVAL_CACHE") or str(tmp_path_factory.mktemp("solver-cache"))
    monkeypatch.setenv("SKYVLN_EVAL_CACHE", root)
    compiled = NmpcController(MpcConfig(compile="always", qp_solver="hpipm"))
    interpreted = NmpcController(MpcConfig(compile="never", qp_solver="hpipm"))
    assert compiled.rti.compiled and not interpreted.rti.compiled
    reference = segment_reference(START, TARGET, 0.0)
    times = 0.1 * np.arange(21)
    first = compiled.step(START, reference.window(times), ObstacleForecast.none(times))
    assert first.stats.iterations > 0  # the library reports HPIPM's iteration count
    logs = []
    for controller in (compiled, interpreted):
        flight = Flight(controller, DroneState(0.0, 0.0, 10.0), scenario=scenario("crossing"))
        logs.append(flight.fly_to(TARGET, max_time_s=15.0).log)
    a, b = logs
    assert len(a) == len(b) and not a.solve_failed.any()
    columns = ["x_m", "y_m", "z_m", "cmd_thrust_m_s2", "cmd_roll_rad", "cmd_pitch_rad"]
    assert np.array_equal(a[columns].to_numpy(), b[columns].to_numpy())
    assert np.array_equal(a.iterations.to_numpy(), b.iterations.to_numpy())
    assert (a.min_clearance_m >= 0.0).all()


def test_the_blasfeo_under_hpipm_reports_its_instruction_sets() -> None:
    """The CasADi wheel ships BLASFEO next to HPIPM, and the library answers which
    instruction sets it was built for (benchmarks/nmpc.py prints it): words from BLASFEO's
    own list, or none for its generic C build."""
    sets = codegen.blasfeo_instruction_sets()
    assert sets is not None, "no BLASFEO library to ask in CasADi's folder"
    assert set(sets.split()) <= {"AVX", "AVX2", "FMA", "SSE3", "VFPv3", "NEON", "VFPv4", "NEONv2"}
