"""Shared set-ups for the control tests: interpreted controllers and obstacle cases."""

from __future__ import annotations

import numpy as np

from skyvln_eval.control import Controller, make_controller
from skyvln_eval.frames import ViewPose
from skyvln_eval.sim import DroneState, ObstacleScenario, ScenarioSpec, make_scenario
from skyvln_eval.sim.reference import segment_reference

START = DroneState(0.0, 0.0, 10.0)
TARGET = ViewPose(16.0, 6.0, 12.0, 0.5)


def controller(name: str, **settings: object) -> Controller:
    """A controller by name: ``"nmpc"`` and ``"mpc"`` with HPIPM interpreted (no wait for
    gcc), ``"nmpc/riccati"`` and ``"mpc/riccati"`` with the compiled Riccati QP solver (the
    default; built once per problem and test session)."""
    if name.endswith("/riccati"):
        name, settings = (
            name.split("/")[0],
            {"qp_solver": "riccati", "compile": "always", **settings},
        )
    elif name != "pid":
        settings = {"compile": "never", "qp_solver": "hpipm", **settings}
    return make_controller(name, settings)


def scenario(kind: str, seed: int = 0, n_obstacles: int = 2) -> ObstacleScenario:
    """Obstacles of ``kind`` placed against the nominal reference from START to TARGET."""
    reference = segment_reference(START, TARGET, 0.0)
    times = np.arange(0.0, reference.end_time_s, 0.1)
    spec = ScenarioSpec(kind=kind, n_obstacles=n_obstacles, seed=seed)  # type: ignore[arg-type]
    return make_scenario(spec, times, reference.window(times).position_m)
