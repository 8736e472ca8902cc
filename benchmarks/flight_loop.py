"""Benchmark: the Python work of one control step of the dynamics flight loop.

Flies the compiled NMPC (the default settings) through three successive segments with two
spheres crossing the first one (the ``crossing`` scenario, seeded), as
:class:`skyvln_eval.control.Flight` does in dynamics mode, ``--repeat`` times after one
warm-up flight. The baseline in the same process is the native solve alone: the compiled
step's C call (:class:`~skyvln_eval.control.codegen.NativeCall`), timed by wrapping the
controller's instance of it. Prints, as medians over the repeats, the wall time per
control step, the native solve's share, the rest (the Python around it: measuring,
forecasting, packing, clipping, the plant, the log row) and the ratio of the whole step
to the solve. The machine's load moves every figure; compare runs made side by side.

    PYTHONPATH=. python benchmarks/flight_loop.py [--repeat 15]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from skyvln_eval.control import Flight, make_controller
from skyvln_eval.control.mpc import MpcController
from skyvln_eval.control.rti import HpipmStep, RiccatiStep
from skyvln_eval.frames import ViewPose
from skyvln_eval.sim import DroneState, ObstacleScenario, ScenarioSpec, make_scenario
from skyvln_eval.sim.reference import segment_reference

START = DroneState(0.0, 0.0, 10.0)
TARGETS = (
    ViewPose(16.0, 6.0, 12.0, 0.5),
    ViewPose(60.0, 30.0, 15.0, 1.5),
    ViewPose(0.0, 80.0, 12.0, -1.0),
)


class Stopwatch:
    """The seconds spent in the native calls it wraps, added up."""

    def __init__(self) -> None:
        self.seconds = 0.0

    def wrap(self, call: Callable[[], Any]) -> Callable[[], Any]:
        def timed() -> Any:
            start = time.perf_counter()
            result = call()
            self.seconds += time.perf_counter() - start
            return result

        return timed


def time_native_calls(controller: MpcController) -> Stopwatch:
    """Wrap the controller's native calls in one stopwatch (exits if there are none)."""
    watch = Stopwatch()
    step = controller.rti
    if isinstance(step, RiccatiStep):
        step._blocks = watch.wrap(step._blocks)  # type: ignore[assignment]
        step.solver = watch.wrap(step.solver)  # type: ignore[assignment]
    elif isinstance(step, HpipmStep) and step._native is not None:
        step._native = watch.wrap(step._native)  # type: ignore[assignment]
    else:
        raise SystemExit("the NMPC is not compiled here (no C compiler?): nothing to compare")
    return watch


def crossing() -> ObstacleScenario:
    """Two spheres crossing the first segment's nominal route when the drone passes."""
    reference = segment_reference(START, TARGETS[0], 0.0)
    times = np.arange(0.0, reference.end_time_s, 0.1)
    spec = ScenarioSpec(kind="crossing", n_obstacles=2, seed=0)
    return make_scenario(spec, times, reference.window(times).position_m)


def fly(controller: MpcController, scenario: ObstacleScenario) -> int:
    """One flight through every target; the number of control steps."""
    flight = Flight(controller, START, scenario)
    return sum(len(flight.fly_to(target).rows) for target in TARGETS)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15)
    args = parser.parse_args()
    controller = make_controller("nmpc", {})
    assert isinstance(controller, MpcController)
    timed = time_native_calls(controller)
    scenario = crossing()
    fly(controller, scenario)  # warm-up
    whole, solve = [], []
    for _ in range(args.repeat):
        timed.seconds = 0.0
        start = time.perf_counter()
        steps = fly(controller, scenario)
        whole.append((time.perf_counter() - start) / steps * 1e3)
        solve.append(timed.seconds / steps * 1e3)
    # The figures of one flight, the median one, so that solve + rest = whole.
    median_flight = sorted(range(len(whole)), key=whole.__getitem__)[len(whole) // 2]
    step_ms, solve_ms = whole[median_flight], solve[median_flight]
    rest_ms = step_ms - solve_ms
    rest = [w - s for w, s in zip(whole, solve, strict=True)]
    print(f"{steps} control steps a flight, {args.repeat} flights (the median flight's)")
    print(f"  whole step     {step_ms:.4f} ms")
    print(f"  native solve   {solve_ms:.4f} ms   (baseline)")
    print(f"  rest (Python)  {rest_ms:.4f} ms   (min {min(rest):.4f})")
    print(f"  whole / solve  {step_ms / solve_ms:.2f}x")


if __name__ == "__main__":
    main()
