"""Obstacle motion, forecasts and seeded scenarios placed against a route."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyvln_eval.errors import ConfigError
from skyvln_eval.frames import ViewPose
from skyvln_eval.sim import (
    ConstantVelocity,
    ConstantVelocityPredictor,
    DroneState,
    ExactPredictor,
    ObstacleScenario,
    ScenarioSpec,
    SphereObstacle,
    SplinePath,
    make_scenario,
    segment_reference,
)
from skyvln_eval.sim.obstacles import row_norms


def route() -> tuple[np.ndarray, np.ndarray]:
    reference = segment_reference(DroneState(0, 0, 10), ViewPose(30, 10, 12, 0.0), 5.0)
    times = np.arange(5.0, reference.end_time_s, 0.1)
    return times, reference.window(times).position_m


def test_constant_velocity_motion_and_its_forecast_agree() -> None:
    motion = ConstantVelocity((1.0, 2.0, 3.0), (0.5, 0.0, -0.1), start_time_s=2.0)
    scenario = ObstacleScenario("one", (SphereObstacle(motion),))
    times = 4.0 + 0.1 * np.arange(21)
    forecast = ConstantVelocityPredictor().forecast(scenario, times)
    exact = ExactPredictor().forecast(scenario, times)
    assert np.allclose(forecast.positions_m, exact.positions_m)
    assert np.allclose(forecast.positions_m[0, 0], [2.0, 2.0, 2.8])
    assert forecast.keep_out_radius_m[0] == pytest.approx(0.7)


def test_constant_velocity_scenarios_place_their_obstacles_exactly_as_each_motion_does() -> None:
    # The scenario computes all constant-velocity obstacles in one expression: the floats
    # must be those of each obstacle's own motion.
    rng = np.random.default_rng(7)
    obstacles = tuple(
        SphereObstacle(
            ConstantVelocity(
                tuple(rng.uniform(-300, 300, 3)),  # type: ignore[arg-type]
                tuple(rng.normal(0, 2, 3)),  # type: ignore[arg-type]
                float(rng.uniform(0, 50)),
            )
        )
        for _ in range(5)
    )
    scenario = ObstacleScenario("five", obstacles)
    for t in rng.uniform(0, 400, 50):
        each = np.array([o.motion.position_m(np.array([t]))[0] for o in obstacles])
        assert np.array_equal(scenario.positions_m(float(t)), each)
        velocities = np.array([o.motion.velocity_at(np.array([t]))[0] for o in obstacles])
        assert np.array_equal(scenario.velocities_m_s(float(t)), velocities)
    spline = SplinePath((0.0, 10.0), ((0.0, 0.0, 5.0), (10.0, 0.0, 5.0)))
    mixed = ObstacleScenario("mixed", (*obstacles[:1], SphereObstacle(spline)))
    assert np.array_equal(mixed.positions_m(3.0)[1], spline.position_m(np.array([3.0]))[0])


def test_row_norms_are_numpys_norms_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    for shape in [(1, 3), (2, 3), (7, 3), (2, 20, 3), (5, 21, 3)]:
        vectors = rng.normal(0.0, 10.0, shape) * rng.choice([1e-3, 1.0, 1e3], shape)
        assert np.array_equal(row_norms(vectors), np.linalg.norm(vectors, axis=-1))


def test_clearance_on_floats_is_the_array_computation_bit_for_bit() -> None:
    rng = np.random.default_rng(5)

    def sphere(start_time_s: float) -> SphereObstacle:
        motion = ConstantVelocity(
            tuple(rng.uniform(-50, 50, 3)), tuple(rng.uniform(-3, 3, 3)), start_time_s
        )
        return SphereObstacle(motion, float(rng.uniform(0.1, 2)), float(rng.uniform(0, 1)))

    for count in (1, 2, 3, 6):
        scenario = ObstacleScenario(
            "s", tuple(sphere(float(rng.uniform(0, 9))) for _ in range(count))
        )
        for _ in range(300):
            position = tuple(float(v) for v in rng.uniform(-50, 50, 3))
            t_s = float(rng.uniform(0, 100))
            distances = np.linalg.norm(scenario.positions_m(t_s) - np.asarray(position), axis=1)
            keep_out = scenario.radii_m + scenario.safety_radii_m
            expected = float(np.min(distances - keep_out))
            clearance, collision = scenario.clearance_m(position, t_s)  # type: ignore[arg-type]
            assert clearance == expected
            assert collision == bool(np.any(distances < scenario.radii_m))
    # A drone inside an obstacle, a non-finite position, and a spline obstacle (arrays).
    inside = ObstacleScenario("in", (SphereObstacle(ConstantVelocity((1.0, 0.0, 0.0)), 0.5),))
    assert inside.clearance_m((1.2, 0.0, 0.0), 0.0) == (0.2 - 0.8, True)
    clearance, collision = inside.clearance_m((math.nan, 0.0, 0.0), 0.0)
    assert math.isnan(clearance) and not collision
    spline = SphereObstacle(SplinePath((0.0, 2.0), ((0.0, 0.0, 0.0), (2.0, 0.0, 0.0))), 0.5)
    mixed = ObstacleScenario("mixed", (spline, *inside.obstacles))
    assert mixed.clearance_m((1.0, 0.0, 3.0), 1.0) == (3.0 - 0.8, False)
    assert ObstacleScenario("none").clearance_m((0.0, 0.0, 0.0), 0.0) == (math.inf, False)


def test_spline_path_passes_its_points_and_holds_outside_its_span() -> None:
    path = SplinePath((0.0, 2.0, 4.0), ((0, 0, 0), (2, 1, 0), (4, 0, 1)))
    at = path.position_m(np.array([-1.0, 0.0, 2.0, 4.0, 9.0]))
    assert np.allclose(at, [[0, 0, 0], [0, 0, 0], [2, 1, 0], [4, 0, 1], [4, 0, 1]])
    assert np.allclose(path.velocity_at(np.array([-1.0, 9.0])), 0.0)
    assert np.linalg.norm(path.velocity_at(np.array([2.0]))) > 0.5


def test_noisy_constant_velocity_forecast_is_seeded() -> None:
    scenario = ObstacleScenario("one", (SphereObstacle(ConstantVelocity((0, 0, 0))),))
    times = np.arange(5) * 0.1

    def forecast(seed: int) -> np.ndarray:
        predictor = ConstantVelocityPredictor(0.1, 0.1, seed=seed)
        return predictor.forecast(scenario, times).positions_m

    assert np.array_equal(forecast(1), forecast(1))
    assert not np.array_equal(forecast(1), forecast(2))


@pytest.mark.parametrize("kind", ["static", "crossing", "approaching", "spline"])
def test_every_obstacle_meets_the_route_when_the_drone_passes(kind: str) -> None:
    times, points = route()
    spec = ScenarioSpec(kind=kind, n_obstacles=3, seed=7)  # type: ignore[arg-type]
    scenario = make_scenario(spec, times, points)
    assert len(scenario.obstacles) == 3
    keep_out = spec.radius_m + spec.safety_radius_m
    for i in range(3):
        # At some time the obstacle is within a keep-out radius of where the drone should be.
        track = scenario.trajectories_m(times)[i]
        gaps = np.linalg.norm(track - points, axis=1)
        assert gaps.min() < keep_out
    assert make_scenario(spec, times, points) == scenario  # same seed, same scenario


def test_obstacles_stay_off_the_waypoints() -> None:
    times, points = route()
    scenario = make_scenario(ScenarioSpec(kind="static", n_obstacles=4, seed=3), times, points)
    for end in (points[0], points[-1]):
        assert np.min(scenario.distances_m(end, 0.0)) > 2.0


def test_static_obstacles_do_not_move_and_moving_ones_do() -> None:
    times, points = route()
    static = make_scenario(ScenarioSpec(kind="static"), times, points)
    crossing = make_scenario(ScenarioSpec(kind="crossing"), times, points)
    assert np.allclose(static.velocities_m_s(3.0), 0.0)
    assert np.allclose(np.linalg.norm(crossing.velocities_m_s(3.0), axis=1), 0.5)


def test_no_obstacles_scenario() -> None:
    times, points = route()
    scenario = make_scenario(ScenarioSpec(kind="none"), times, points)
    assert scenario.obstacles == ()
    assert ExactPredictor().forecast(scenario, times[:5]).count == 0


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda: ScenarioSpec(kind="meteor"), "kind"),  # type: ignore[arg-type]
        (lambda: ScenarioSpec(n_obstacles=-1), "n_obstacles"),
        (lambda: ScenarioSpec(radius_m=0.0), "radius_m"),
        (
            lambda: SphereObstacle(ConstantVelocity((0, 0, 0)), safety_radius_m=-1),
            "safety_radius_m",
        ),
        (lambda: ConstantVelocity((0, 0)), "start_m"),  # type: ignore[arg-type]
        (lambda: SplinePath((0.0, 0.0), ((0, 0, 0), (1, 1, 1))), "times_s"),
    ],
)
def test_bad_obstacle_settings_name_the_field(make: object, field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        make()  # type: ignore[operator]


def test_a_route_that_does_not_move_is_refused() -> None:
    with pytest.raises(ConfigError, match="length is zero"):
        make_scenario(ScenarioSpec(), np.array([0.0, 1.0]), np.zeros((2, 3)))


def test_the_swept_clearance_sees_what_happens_between_samples() -> None:
    # A drone at 12 m/s steps 1.2 m in 0.1 s: straight through a sphere 0.8 m across, with
    # both samples outside it. The samples see nothing; the step touches it.
    sphere = SphereObstacle(ConstantVelocity((0.0, 0.0, 10.0), (0.0, 0.0, 0.0)), 0.4, 0.3)
    scenario = ObstacleScenario("one", (sphere,))
    start, end = (-0.6, 0.0, 10.0), (0.6, 0.0, 10.0)
    assert scenario.clearance_m(start, 0.0) == (pytest.approx(-0.1), False)
    assert scenario.clearance_m(end, 0.1)[1] is False
    clearance, collision = scenario.swept_clearance_m(start, end, 0.0, 0.1)
    assert clearance == pytest.approx(-0.7) and collision
    # Passing 0.5 m to the side: outside the sphere, 0.2 m inside the keep-out.
    clearance, collision = scenario.swept_clearance_m((-0.6, 0.5, 10.0), (0.6, 0.5, 10.0), 0, 0.1)
    assert clearance == pytest.approx(-0.2) and not collision
    # A moving obstacle: the relative motion counts (both move at the same velocity here).
    moving = ObstacleScenario(
        "moving", (SphereObstacle(ConstantVelocity((0.0, 2.0, 10.0), (12.0, 0.0, 0.0)), 0.4),)
    )
    clearance, collision = moving.swept_clearance_m((0.0, 0.0, 10.0), (1.2, 0.0, 10.0), 0, 0.1)
    assert clearance == pytest.approx(2.0 - 0.7) and not collision
    assert ObstacleScenario("none").swept_clearance_m(start, end, 0.0, 0.1) == (math.inf, False)
