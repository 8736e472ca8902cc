"""The compiled Riccati interior point method that solves the MPC's QP (the default):
its solutions against an exact active-set solver on the QPs of a flight with obstacles,
flights against HPIPM's, its failure codes, and the fall-back to HPIPM without a compiler."""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from typing import Any

import casadi as ca
import numpy as np
import pytest

from skyvln_eval.control import Flight, MpcConfig, NmpcController, codegen, mpc, stage_ipm
from skyvln_eval.control.rti import RiccatiStep, step_inputs
from skyvln_eval.control.stage_ipm import STATUS
from skyvln_eval.control.stage_qp import NZ
from skyvln_eval.errors import SolverBuildError
from skyvln_eval.sim import DroneState
from tests.control.helpers import TARGET, scenario

needs_gcc = pytest.mark.skipif(codegen.compiler() is None, reason="no C compiler ($CC or gcc)")


def riccati_controller() -> NmpcController:
    controller = NmpcController(MpcConfig(qp_solver="riccati", compile="always"))
    assert isinstance(controller.rti, RiccatiStep) and controller.qp_solver_used == "riccati"
    return controller


def flown_qps(controller: NmpcController, steps: int) -> Iterator[tuple[np.ndarray, ...]]:
    """The step inputs and the Riccati solution of every QP of a flight through crossing
    obstacles (copies, taken as each step solves)."""
    rti = controller.rti
    solve = rti.solve
    taken: list[tuple[np.ndarray, ...]] = []

    def recording(shift: bool) -> tuple[bool, int]:
        rti.warm[3] = 1.0 if shift else 0.0
        inputs = (rti.plan.copy(), rti.guess.copy(), rti.params.copy(), rti.warm.copy())
        result = solve(shift)
        taken.append((*inputs, rti.w.copy(), np.array(result[0])))
        return result

    rti.solve = recording  # type: ignore[method-assign]
    flight = Flight(controller, DroneState(0.0, 0.0, 10.0), scenario=scenario("crossing"))
    flight.fly_to(TARGET, max_time_s=steps * controller.dt_s)
    return iter(taken)


@needs_gcc
def test_its_solutions_are_the_exact_solutions_of_the_flights_qps() -> None:
    """Every eighth QP of 80 control steps past two crossing spheres (qpOASES is slow on
    them), solved again by qpOASES (an active-set method: exact to rounding): the same
    solution to within what the interior point tolerance (residuals 1e-6) allows, 5e-4
    (measured: 4.4e-4 on the first, cold started, QP, under 7e-5 on the others; HPIPM's
    exit test at the same tolerance was off by up to 8e-3), with obstacle and rate
    constraints among those that are active."""
    controller = riccati_controller()
    qp = controller.qp
    inputs, start, p = step_inputs(qp)
    data = ca.Function("qp_at", inputs, [*qp.data(start, p), start])
    exact = ca.conic(
        "exact",
        "qpoases",
        {"h": qp.hessian.sparsity(), "a": qp.data.sparsity_out("a")},
        {"printLevel": "none", "error_on_fail": True},
    )
    rows = qp.rows_per_stage
    active_kinds: set[str] = set()
    count = 0
    for index, (plan, guess, params, warm, w, ok) in enumerate(flown_qps(controller, 80)):
        assert ok, "every QP of the flight is solved"
        if index % 8:
            continue
        g, a, lba, uba, lbx, ubx, at = data(plan, guess, params, warm)
        solution = exact(h=qp.hessian, g=g, a=a, lba=lba, uba=uba, lbx=lbx, ubx=ubx)
        reference = np.asarray(solution["x"]).ravel()
        assert np.max(np.abs(w - reference)) < 5e-4
        assert np.array_equal(w[: qp.stage - qp.n_v], np.asarray(at).ravel()[: qp.stage - qp.n_v])
        values = np.asarray(ca.mtimes(a, solution["x"])).ravel()
        low, high = np.asarray(lba).ravel(), np.asarray(uba).ravel()
        for row in np.flatnonzero((np.abs(values - low) < 1e-7) | (np.abs(values - high) < 1e-7)):
            local = row % rows  # the model and memory rows, 2 rate limits, the spheres
            if local >= NZ:
                active_kinds.add("rate" if local < NZ + 2 else "obstacle")
        bound = np.flatnonzero(
            (np.abs(reference - np.asarray(lbx).ravel()) < 1e-7)
            | (np.abs(reference - np.asarray(ubx).ravel()) < 1e-7)
        )
        if np.any(bound >= qp.stage - qp.n_v):  # beyond the fixed first state
            active_kinds.add("input bound")
        count += 1
    assert count == 10
    assert {"rate", "obstacle"} <= active_kinds, active_kinds


@needs_gcc
def test_it_flies_as_hpipm_does() -> None:
    """The same flight past two crossing spheres with either QP solver (HPIPM interpreted,
    which flies as its compiled form does): the same path to within 5 mm (HPIPM's exit test
    leaves its inputs up to ~1e-2 from the QP's solution on some steps, so not to
    rounding), no failed step, clearance kept."""
    logs = []
    for solver, compile_mode in (("riccati", "always"), ("hpipm", "never")):
        config = MpcConfig(qp_solver=solver, compile=compile_mode)  # type: ignore[arg-type]
        controller = NmpcController(config)
        assert controller.qp_solver_used == solver
        flight = Flight(controller, DroneState(0.0, 0.0, 10.0), scenario=scenario("crossing"))
        logs.append(flight.fly_to(TARGET, max_time_s=15.0).log)
    riccati, hpipm = logs
    assert len(riccati) == len(hpipm)
    assert not riccati.solve_failed.any() and not hpipm.solve_failed.any()
    position = ["x_m", "y_m", "z_m"]
    assert np.max(np.abs(riccati[position].to_numpy() - hpipm[position].to_numpy())) < 5e-3
    assert (riccati.min_clearance_m >= 0.0).all()
    assert riccati.min_clearance_m.min() < 0.2  # the spheres were in the way


@needs_gcc
def test_failures_are_reported_by_status_not_as_solutions() -> None:
    controller = riccati_controller()
    Flight(controller, DroneState(0.0, 0.0, 10.0)).fly_to(TARGET, max_time_s=0.5)
    rti = controller.rti
    assert isinstance(rti, RiccatiStep)
    solver = rti.solver
    assert STATUS[solver()[0]] == "solved"
    solver.settings[3] = 1  # at most one iteration, and nothing is acceptable
    solver.settings[5] = 0.0
    assert STATUS[solver()[0]] == "iteration limit"
    solver.settings[5] = 1e9  # any iterate is acceptable: the best one is the solution
    assert STATUS[solver()[0]] == "solved to the acceptable residual"
    solver.settings[5] = stage_ipm.ACCEPTABLE
    solver.settings[3] = stage_ipm.MAX_ITERATIONS
    rti.problem[5] = np.nan
    assert STATUS[solver()[0]] == "non-finite"


@pytest.fixture
def fresh_problems(monkeypatch: pytest.MonkeyPatch) -> None:
    """No problem or solver library built earlier in this process."""
    monkeypatch.setattr(mpc, "_PROBLEMS", {})
    monkeypatch.setattr(stage_ipm, "_libraries", {})


def no_compiler(monkeypatch: pytest.MonkeyPatch) -> None:
    for module in (stage_ipm, codegen):
        monkeypatch.setattr(module, "compiler", lambda: None)


def test_without_a_compiler_hpipm_solves_the_qp_with_one_warning(
    fresh_problems: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    no_compiler(monkeypatch)
    with pytest.warns(RuntimeWarning, match="no C compiler") as caught:
        controller = NmpcController(MpcConfig(horizon_steps=6))
    assert any("solves its QP with HPIPM" in str(w.message) for w in caught)
    assert controller.qp_solver_used == "hpipm" and not controller.rti.compiled
    assert controller.settings()["qp_solver_used"] == "hpipm"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = Flight(controller, DroneState(0.0, 0.0, 10.0)).fly_to(TARGET, max_time_s=1.0)
    assert result.failed_steps == 0


def test_without_a_compiler_compile_always_is_an_error(
    fresh_problems: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    no_compiler(monkeypatch)
    with pytest.raises(SolverBuildError, match="no C compiler"):
        NmpcController(MpcConfig(horizon_steps=6, compile="always"))


@needs_gcc
def test_a_problem_without_obstacle_slots_or_slacks_is_solved_alike() -> None:
    """No obstacle slot: no slack control, so the stage controls (3) do not fill a SIMD
    register and the solver pads them. A short horizon keeps the build quick."""
    logs = []
    for solver, compile_mode in (("riccati", "always"), ("hpipm", "never")):
        config = MpcConfig(
            qp_solver=solver,  # type: ignore[arg-type]
            compile=compile_mode,  # type: ignore[arg-type]
            max_obstacles=0,
            horizon_steps=4,
        )
        controller = NmpcController(config)
        assert controller.qp_solver_used == solver and controller.qp.n_v == 3
        logs.append(Flight(controller, DroneState(0.0, 0.0, 10.0)).fly_to(TARGET, 8.0).log)
    riccati, hpipm = logs
    assert len(riccati) == len(hpipm) and not riccati.solve_failed.any()
    position = ["x_m", "y_m", "z_m"]
    assert np.max(np.abs(riccati[position].to_numpy() - hpipm[position].to_numpy())) < 5e-3


@needs_gcc
def test_a_qp_it_cannot_solve_is_solved_by_hpipm_instead() -> None:
    """The Riccati solver stalls on a few nearly degenerate QPs (about 1 in 4,000 of a
    flight with a random agent): the step then solves the same QP with HPIPM and counts it.
    Forced here by allowing a single iteration and no acceptable residual."""
    controller = riccati_controller()
    rti = controller.rti
    assert isinstance(rti, RiccatiStep)
    rti.solver.settings[3] = 1
    rti.solver.settings[5] = 0.0
    flight = Flight(controller, DroneState(0.0, 0.0, 10.0), scenario=scenario("crossing"))
    log = flight.fly_to(TARGET, max_time_s=3.0).log
    assert rti.hpipm_solves == len(log) and not log.solve_failed.any()
    reference = NmpcController(MpcConfig(qp_solver="hpipm", compile="never"))
    expected = Flight(reference, DroneState(0.0, 0.0, 10.0), scenario=scenario("crossing"))
    position = ["x_m", "y_m", "z_m"]
    flown = expected.fly_to(TARGET, max_time_s=3.0).log[position].to_numpy()
    assert np.allclose(log[position].to_numpy(), flown, atol=1e-9)
