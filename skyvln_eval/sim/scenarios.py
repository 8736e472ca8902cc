"""Seeded obstacle scenarios placed against a route so that the drone has to deal with them.

A route is the reference the drone will fly, sampled as times and positions. Each obstacle
picks a meeting point on the route (a seeded sample among those where the reference
cruises, spread between obstacles) and the time the reference passes there, and is placed
so that it is on the route at that time:

- ``static``: a sphere sitting on the route (centre within half a keep-out radius of it);
- ``crossing``: moving horizontally across the route at ``obstacle_speed_m_s``;
- ``approaching``: moving head-on along the route towards the drone, slightly off-centre;
- ``spline``: wandering along a seeded cubic spline that crosses the route at the meeting.

The same seed and route give the same scenario, byte for byte.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.errors import ConfigError
from skyvln_eval.sim.obstacles import (
    ConstantVelocity,
    Motion,
    ObstacleScenario,
    SphereObstacle,
    SplinePath,
)
from skyvln_eval.sim.quadrotor import require_non_negative, require_positive

ScenarioKind = Literal["none", "static", "crossing", "approaching", "spline"]
SCENARIO_KINDS: tuple[str, ...] = get_args(ScenarioKind)


@dataclass(frozen=True)
class ScenarioSpec:
    """What kind of obstacles, how many, how big and how fast."""

    kind: ScenarioKind = "crossing"
    n_obstacles: int = 2
    radius_m: float = 0.4
    safety_radius_m: float = 0.3
    obstacle_speed_m_s: float = 0.5
    seed: int = 0

    def __post_init__(self) -> None:
        if self.kind not in SCENARIO_KINDS:
            raise ConfigError(
                f"ScenarioSpec.kind must be one of {', '.join(SCENARIO_KINDS)}, got {self.kind!r}"
            )
        if not isinstance(self.n_obstacles, int) or self.n_obstacles < 0:
            raise ConfigError(
                f"ScenarioSpec.n_obstacles must be an integer >= 0, got {self.n_obstacles!r}"
            )
        require_positive(self, "radius_m", "obstacle_speed_m_s")
        require_non_negative(self, "safety_radius_m")

    @property
    def name(self) -> str:
        return f"{self.kind}-{self.n_obstacles}-seed{self.seed}"


def make_scenario(
    spec: ScenarioSpec, route_times_s: NDArray[np.float64], route_positions_m: NDArray[np.float64]
) -> ObstacleScenario:
    """Obstacles of ``spec`` placed against the route sampled at ``route_times_s``."""
    times = np.asarray(route_times_s, dtype=np.float64)
    points = np.asarray(route_positions_m, dtype=np.float64)
    if times.ndim != 1 or points.shape != (len(times), 3) or len(times) < 2:
        raise ConfigError(
            "make_scenario needs route_times_s of shape (n,) and route_positions_m of shape "
            f"(n, 3) with n >= 2, got {times.shape} and {points.shape}"
        )
    if spec.kind == "none" or spec.n_obstacles == 0:
        return ObstacleScenario(spec.name, (), spec.seed)
    rng = np.random.default_rng(spec.seed)
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    if steps.sum() <= 0.0:
        raise ConfigError("make_scenario needs a route that moves (its length is zero)")
    # Meet the drone where it cruises (at least half its top speed along the route), never
    # where it stops at a waypoint: an obstacle parked on a target would make it unreachable.
    speeds = steps / np.maximum(np.diff(times), 1e-9)
    cruising = np.flatnonzero(speeds >= 0.5 * speeds.max()) + 1
    obstacles = []
    for i in range(spec.n_obstacles):
        # Spread the meeting points over the cruising samples, jittered by the seed.
        quantile = (i + 0.5 + 0.5 * (rng.random() - 0.5)) / spec.n_obstacles
        index = int(cruising[min(int(quantile * len(cruising)), len(cruising) - 1)])
        meet_t, meet = float(times[index]), points[index]
        tangent = (points[index] - points[index - 1]) / steps[index - 1]
        side = _horizontal_normal(tangent) * rng.choice([-1.0, 1.0])
        motion = _motion(spec, rng, meet, meet_t, float(times[0]), tangent, side)
        obstacles.append(SphereObstacle(motion, spec.radius_m, spec.safety_radius_m))
    return ObstacleScenario(spec.name, tuple(obstacles), spec.seed)


def _horizontal_normal(tangent: NDArray[np.float64]) -> NDArray[np.float64]:
    """A horizontal unit vector perpendicular to ``tangent`` (east if the route is vertical)."""
    normal = np.array([-tangent[1], tangent[0], 0.0])
    length = float(np.linalg.norm(normal))
    return normal / length if length > 1e-9 else np.array([1.0, 0.0, 0.0])


def _motion(
    spec: ScenarioSpec,
    rng: np.random.Generator,
    meet: NDArray[np.float64],
    meet_t: float,
    t0: float,
    tangent: NDArray[np.float64],
    side: NDArray[np.float64],
) -> Motion:
    keep_out = spec.radius_m + spec.safety_radius_m
    offset = (rng.random() - 0.5) * keep_out  # off the route by less than half a keep-out radius
    lead = meet_t - t0
    if spec.kind == "static":
        return ConstantVelocity(_vec(meet + offset * side), (0.0, 0.0, 0.0), t0)
    if spec.kind == "crossing":
        velocity = -side * spec.obstacle_speed_m_s
        at_meet = meet + offset * tangent
        return ConstantVelocity(_vec(at_meet - velocity * lead), _vec(velocity), t0)
    if spec.kind == "approaching":
        velocity = -tangent * spec.obstacle_speed_m_s
        at_meet = meet + (0.25 + 0.25 * rng.random()) * keep_out * side
        return ConstantVelocity(_vec(at_meet - velocity * lead), _vec(velocity), t0)
    # spline: cross the route at the meeting point, wandering sideways around it.
    step_s = 2.0 * keep_out / spec.obstacle_speed_m_s
    knots_t = meet_t + step_s * np.arange(-2, 3)
    along = np.arange(-2, 3) * spec.obstacle_speed_m_s * step_s
    wander = (rng.random(5) - 0.5) * keep_out
    wander[2] = offset
    knots = [meet - a * side + w * tangent for a, w in zip(along, wander, strict=True)]
    return SplinePath(tuple(float(t) for t in knots_t), tuple(_vec(k) for k in knots))


def _vec(v: NDArray[np.float64]) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))
