"""Simulation: the paper's quadrotor model and plant, obstacle scenarios and references.

- :mod:`.quadrotor`: the model (state ``[p, v, roll, pitch]``, inputs ``[T, roll_ref,
  pitch_ref]``), its typed parameters and input limits, :class:`DroneState`;
- :mod:`.plant`: the RK4 plant with wind, sensor noise and the heading loop;
- :mod:`.obstacles` and :mod:`.scenarios`: seeded spherical obstacles (static,
  constant-velocity, spline) placed against a route, and their forecast over a horizon;
- :mod:`.reference`: a target pose to a time-parametrised reference at a cruise speed;
- :mod:`.camera`: the drone's front camera (RGB, depth, semantic, instance images over
  the map's height field), imported on its own: ``from skyvln_eval.sim.camera import ...``.

The controllers that fly this plant, and the closed loop, are in :mod:`skyvln_eval.control`.
"""

from skyvln_eval.sim.obstacles import (
    ConstantVelocity,
    ConstantVelocityPredictor,
    ExactPredictor,
    ObstacleForecast,
    ObstacleScenario,
    SphereObstacle,
    SplinePath,
)
from skyvln_eval.sim.plant import Plant, PlantConfig, SensorNoise, WindConfig
from skyvln_eval.sim.quadrotor import (
    INPUT_NAMES,
    STATE_NAMES,
    DroneState,
    InputLimits,
    QuadrotorParams,
    model_rhs,
    rk4_symbolic,
)
from skyvln_eval.sim.reference import (
    ReferenceConfig,
    ReferenceTrajectory,
    ReferenceWindow,
    segment_reference,
)
from skyvln_eval.sim.scenarios import SCENARIO_KINDS, ScenarioSpec, make_scenario

__all__ = [
    "INPUT_NAMES",
    "SCENARIO_KINDS",
    "STATE_NAMES",
    "ConstantVelocity",
    "ConstantVelocityPredictor",
    "DroneState",
    "ExactPredictor",
    "InputLimits",
    "ObstacleForecast",
    "ObstacleScenario",
    "Plant",
    "PlantConfig",
    "QuadrotorParams",
    "ReferenceConfig",
    "ReferenceTrajectory",
    "ReferenceWindow",
    "ScenarioSpec",
    "SensorNoise",
    "SphereObstacle",
    "SplinePath",
    "WindConfig",
    "make_scenario",
    "model_rhs",
    "rk4_symbolic",
    "segment_reference",
]
