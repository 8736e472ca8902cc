"""The RK4 plant: determinism, saturation, wind, sensor noise and the heading loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyvln_eval.errors import ConfigError
from skyvln_eval.sim import DroneState, Plant, PlantConfig, SensorNoise, WindConfig

G = 9.81


def fly(plant: Plant, steps: int, command: tuple[float, float, float, float]) -> list[DroneState]:
    return [plant.step(*command, dt_s=0.1) for _ in range(steps)]


def test_hover_holds_position() -> None:
    plant = Plant(DroneState(1.0, 2.0, 3.0))
    final = fly(plant, 50, (G, 0.0, 0.0, 0.0))[-1]
    assert np.allclose(final.position_m, [1.0, 2.0, 3.0], atol=1e-9)


def test_wind_and_noise_are_deterministic_given_the_seed() -> None:
    config = PlantConfig(
        wind=WindConfig(mean_m_s=(1.0, 0.0, 0.0), gust_std_m_s=0.5),
        noise=SensorNoise(position_std_m=0.1, velocity_std_m_s=0.1, attitude_std_rad=0.01),
    )

    def run(seed: int) -> tuple[list[DroneState], DroneState]:
        plant = Plant(DroneState(0, 0, 10), config, seed=seed)
        return fly(plant, 30, (G, 0.0, 0.0, 0.0)), plant.measure()

    assert run(3) == run(3)
    assert run(3) != run(4)


def test_noise_does_not_change_the_wind_a_run_sees() -> None:
    wind = WindConfig(gust_std_m_s=0.5)
    quiet = Plant(DroneState(0, 0, 10), PlantConfig(wind=wind), seed=1)
    noisy = Plant(
        DroneState(0, 0, 10), PlantConfig(wind=wind, noise=SensorNoise(position_std_m=1.0)), seed=1
    )
    for _ in range(20):
        noisy.measure()
        assert quiet.step(G, 0, 0, 0, 0.1) == noisy.step(G, 0, 0, 0, 0.1)


def test_a_constant_wind_carries_a_hovering_drone_at_the_wind_speed() -> None:
    plant = Plant(DroneState(0, 0, 10), PlantConfig(wind=WindConfig(mean_m_s=(0.0, 2.0, 0.0))))
    final = fly(plant, 600, (G, 0.0, 0.0, 0.0))[-1]
    assert final.vy_m_s == pytest.approx(2.0, abs=0.01)


def test_commands_saturate_at_the_limits() -> None:
    config = PlantConfig()
    wild = Plant(DroneState(0, 0, 10), config)
    capped = Plant(DroneState(0, 0, 10), config)
    limits = config.limits
    fly(wild, 5, (100.0, -3.0, 3.0, 0.0))
    fly(capped, 5, (limits.thrust_max_m_s2, -limits.tilt_ref_max_rad, limits.tilt_ref_max_rad, 0.0))
    assert wild.state == capped.state


def test_heading_loop_turns_the_short_way_at_a_bounded_rate() -> None:
    plant = Plant(DroneState(0, 0, 10, yaw_rad=math.radians(170)))
    target = math.radians(-170)  # 20 degrees away across +-pi
    states = fly(plant, 60, (G, 0.0, 0.0, target))
    yaws = np.unwrap([math.radians(170), *[s.yaw_rad for s in states]])
    assert np.all(np.diff(yaws) >= -1e-12)  # counter-clockwise only: the short way
    assert np.max(np.diff(yaws)) <= plant.config.params.yaw_rate_max_rad_s * 0.1 + 1e-9
    assert abs(math.remainder(states[-1].yaw_rad - target, 2 * math.pi)) < 1e-3


def test_measure_without_noise_is_the_true_state() -> None:
    plant = Plant(DroneState(0, 0, 10))
    fly(plant, 3, (G + 1, 0.1, 0.0, 0.0))
    assert plant.measure() == plant.state


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda: WindConfig(gust_std_m_s=-1.0), "gust_std_m_s"),
        (lambda: WindConfig(mean_m_s=(1.0, 2.0)), "mean_m_s"),  # type: ignore[arg-type]
        (lambda: SensorNoise(position_std_m=-0.1), "position_std_m"),
        (lambda: PlantConfig(substeps=0), "substeps"),
    ],
)
def test_bad_plant_settings_name_the_field(make: object, field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        make()  # type: ignore[operator]


def test_the_step_function_gives_the_plain_float_integration_bit_for_bit() -> None:
    from skyvln_eval.sim.plant import rk4_step_floats

    rng = np.random.default_rng(7)
    config = PlantConfig(wind=WindConfig(mean_m_s=(1.0, -2.0, 0.3), gust_std_m_s=0.5))
    for _ in range(40):
        state = DroneState(
            *rng.uniform(-50, 50, 3),
            *rng.uniform(-5, 5, 3),
            *rng.uniform(-0.4, 0.4, 2),
            yaw_rad=float(rng.choice([math.pi - 1e-3, -math.pi + 1e-3, rng.uniform(-3, 3)])),
        )
        plant = Plant(state, config, seed=int(rng.integers(1000)))
        u = (float(rng.uniform(5, 20)), *(float(v) for v in rng.uniform(-0.4, 0.4, 2)))
        yaw_ref = float(rng.uniform(-math.pi, math.pi))
        x = [float(v) for v in plant._x]
        wind = [float(w) for w in plant.wind_m_s]
        expected = rk4_step_floats(x, u, wind, yaw_ref, 0.1 / 4, 4, config.params)
        plant.step(*u, yaw_ref, 0.1)
        assert np.array_equal(plant._x, np.array(expected))


def test_plants_made_in_many_threads_at_once_build_the_step_function_once() -> None:
    """CasADi's symbolic core is not thread-safe, and each thread that missed the cache
    would build the Function again: episodes that start together in threads wait for the
    first build instead (under the native-calls lock)."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from skyvln_eval.sim import plant

    # Parameters no other test uses: a build this test must see, whatever ran before.
    config = PlantConfig(substeps=3)
    plant._step_function.cache_clear()
    start = threading.Barrier(8)

    def make(_: int) -> Plant:
        start.wait()
        return Plant(DroneState(0.0, 0.0, 30.0), config)

    with ThreadPoolExecutor(8) as pool:
        plants = list(pool.map(make, range(8)))
    assert plant._step_function.cache_info().misses == 1
    for p in plants:
        p.step(G, 0.0, 0.0, 0.0, dt_s=0.1)
    assert len({p.state.z_m for p in plants}) == 1
