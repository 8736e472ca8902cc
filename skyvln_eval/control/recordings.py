"""The recorded runs behind the paper's control figures: PID, linear MPC and NMPC flying the
same two-segment route through a static and a dynamic obstacle case.

The route is what two agent actions become in "dynamics" mode: from a hover at
(0, 0, 10) m heading east, fly to (20, 0, 12) m, then turn north and fly to (20, 15, 12) m.
Obstacles (r_obs 1 m, r_s 0.5 m) are placed against the nominal reference of that route
(:mod:`skyvln_eval.sim.scenarios`): ``static`` puts two spheres on it, ``dynamic`` sends two
across it at 0.5 m/s. Every controller meets the same obstacles at the same times; each run
is one flight log (:mod:`skyvln_eval.control.flight_log`) with the reference, so the
reports can draw x/y/z and roll/pitch/yaw against the reference, and their errors.

    python -m skyvln_eval.control OUT_DIR [--seed 0]
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from skyvln_eval.control.closed_loop import Flight
from skyvln_eval.control.flight_log import save_flight_log
from skyvln_eval.control.registry import make_controller
from skyvln_eval.frames import ViewPose
from skyvln_eval.sim.obstacles import ObstacleScenario
from skyvln_eval.sim.quadrotor import DroneState
from skyvln_eval.sim.reference import ReferenceConfig, segment_reference
from skyvln_eval.sim.scenarios import ScenarioSpec, make_scenario

#: Paper case -> kind of obstacles.
PAPER_CASES = {"static": "static", "dynamic": "crossing"}
PAPER_START = DroneState(0.0, 0.0, 10.0, yaw_rad=0.0)
PAPER_TARGETS = (
    ViewPose(20.0, 0.0, 12.0, 0.0),
    ViewPose(20.0, 15.0, 12.0, math.pi / 2),
)
SEGMENT_MAX_TIME_S = 40.0


def paper_scenario(case: str, seed: int = 0) -> ObstacleScenario:
    """The obstacles of a paper case, placed against the nominal reference of the route."""
    if case not in PAPER_CASES:
        raise ValueError(f"unknown paper case {case!r}; known: {', '.join(PAPER_CASES)}")
    times, points = [], []
    start, t0 = PAPER_START, 0.0
    for target in PAPER_TARGETS:
        reference = segment_reference(start, target, t0, ReferenceConfig())
        sample = np.arange(t0, reference.end_time_s, 0.1)
        times.append(sample)
        points.append(reference.window(sample).position_m)
        start = DroneState(target.x_m, target.y_m, target.z_m, yaw_rad=target.yaw_rad)
        t0 = reference.end_time_s
    spec = ScenarioSpec(
        kind=PAPER_CASES[case],  # type: ignore[arg-type]
        n_obstacles=2,
        radius_m=1.0,
        safety_radius_m=0.5,
        obstacle_speed_m_s=0.5,
        seed=seed,
    )
    scenario = make_scenario(spec, np.concatenate(times), np.concatenate(points))
    return dataclasses.replace(scenario, name=f"paper_{case}")


def record_paper_run(controller_name: str, case: str, seed: int = 0) -> pd.DataFrame:
    """Fly the paper route with one controller through one case; the whole flight's log."""
    flight = Flight(
        controller=make_controller(controller_name),
        start=PAPER_START,
        scenario=paper_scenario(case, seed),
        seed=seed,
    )
    for target in PAPER_TARGETS:
        flight.fly_to(target, SEGMENT_MAX_TIME_S)
    frame = flight.log()
    frame.attrs["settings"] = {
        "controller": flight.controller.settings(),
        "case": case,
        "seed": seed,
    }
    return frame


def record_paper_runs(
    out_dir: str | Path,
    controllers: Sequence[str] = ("pid", "mpc", "nmpc"),
    cases: Sequence[str] = tuple(PAPER_CASES),
    seed: int = 0,
) -> dict[tuple[str, str], Path]:
    """Record every (controller, case) run as ``OUT_DIR/<case>_<controller>.parquet``."""
    paths: dict[tuple[str, str], Path] = {}
    for case in cases:
        for name in controllers:
            frame = record_paper_run(name, case, seed)
            path = Path(out_dir) / f"{case}_{name}.parquet"
            paths[(name, case)] = save_flight_log(frame, path, frame.attrs["settings"])
    return paths
