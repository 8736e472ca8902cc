"""Spherical obstacles (static, constant-velocity or spline motion) and their forecast.

An obstacle is a sphere of radius ``radius_m`` plus a safety radius ``safety_radius_m``
(the paper's r_obs and r_s): the drone must keep its centre out of the keep-out sphere of
radius ``r_obs + r_s`` around the obstacle centre. Positions are ENU metres on the same
clock as the flight (seconds), so motion continues across successive flight segments.

A predictor turns the obstacles into an :class:`ObstacleForecast` over a controller's
horizon: :class:`ConstantVelocityPredictor` extrapolates the measured position and velocity
(as the paper does, "based on the measured initial condition"); :class:`ExactPredictor`
knows the true motion (an oracle, for ablations).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyvln_eval.errors import ConfigError
from skyvln_eval.sim.quadrotor import require_non_negative, require_positive

if TYPE_CHECKING:
    from scipy.interpolate import CubicSpline

Vec3 = tuple[float, float, float]


def _vec3(value: ArrayLike, name: str) -> Vec3:
    array = np.asarray(value, dtype=np.float64)
    if array.shape != (3,) or not np.isfinite(array).all():
        raise ConfigError(f"{name} must be 3 finite numbers (ENU metres), got {value!r}")
    return (float(array[0]), float(array[1]), float(array[2]))


@dataclass(frozen=True)
class ConstantVelocity:
    """``p(t) = start_m + velocity_m_s (t - start_time_s)``; zero velocity = a static obstacle."""

    start_m: Vec3
    velocity_m_s: Vec3 = (0.0, 0.0, 0.0)
    start_time_s: float = 0.0

    def __post_init__(self) -> None:
        _vec3(self.start_m, "ConstantVelocity.start_m")
        _vec3(self.velocity_m_s, "ConstantVelocity.velocity_m_s")

    def position_m(self, t_s: NDArray[np.float64]) -> NDArray[np.float64]:
        """Positions at the times ``t_s`` (shape ``(n,)``), shape ``(n, 3)``."""
        dt = (np.asarray(t_s) - self.start_time_s)[:, None]
        return np.asarray(self.start_m) + dt * np.asarray(self.velocity_m_s)

    def velocity_at(self, t_s: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.broadcast_to(np.asarray(self.velocity_m_s), (len(t_s), 3)).copy()


@dataclass(frozen=True)
class SplinePath:
    """A cubic spline through ``points_m`` at ``times_s`` (zero velocity at both ends), held
    at its first and last point outside that time span."""

    times_s: tuple[float, ...]
    points_m: tuple[Vec3, ...]

    def __post_init__(self) -> None:
        times = np.asarray(self.times_s, dtype=np.float64)
        if len(times) < 2 or len(times) != len(self.points_m) or not np.all(np.diff(times) > 0):
            raise ConfigError(
                "SplinePath.times_s must be increasing and as long as points_m (at least 2), got "
                f"{len(self.times_s)} times and {len(self.points_m)} points"
            )
        for i, point in enumerate(self.points_m):
            _vec3(point, f"SplinePath.points_m[{i}]")

    @cached_property
    def _spline(self) -> CubicSpline:
        # Imported here: scipy.interpolate takes half a second to import, and only
        # obstacles on spline paths need it (not every process that imports this module).
        from scipy.interpolate import CubicSpline

        return CubicSpline(self.times_s, np.asarray(self.points_m), bc_type="clamped")

    def position_m(self, t_s: NDArray[np.float64]) -> NDArray[np.float64]:
        t = np.clip(np.asarray(t_s), self.times_s[0], self.times_s[-1])
        return np.asarray(self._spline(t))

    def velocity_at(self, t_s: NDArray[np.float64]) -> NDArray[np.float64]:
        t = np.asarray(t_s)
        inside = ((t >= self.times_s[0]) & (t <= self.times_s[-1]))[:, None]
        return np.where(inside, self._spline(t, 1), 0.0)


Motion = ConstantVelocity | SplinePath


@dataclass(frozen=True)
class SphereObstacle:
    """A moving sphere: ``radius_m`` (r_obs) plus ``safety_radius_m`` (r_s) to keep out of."""

    motion: Motion
    radius_m: float = 0.4
    safety_radius_m: float = 0.3

    def __post_init__(self) -> None:
        require_positive(self, "radius_m")
        require_non_negative(self, "safety_radius_m")

    @property
    def keep_out_radius_m(self) -> float:
        return self.radius_m + self.safety_radius_m


@dataclass(frozen=True)
class ObstacleScenario:
    """A named, seeded set of obstacles on the flight clock."""

    name: str
    obstacles: tuple[SphereObstacle, ...] = ()
    seed: int = 0

    def merged(self, other: ObstacleScenario) -> ObstacleScenario:
        """Both scenarios' obstacles in one (e.g. those added for a new flight segment)."""
        if not self.obstacles:
            return other
        name = self.name if not other.obstacles else f"{self.name}+{other.name}"
        return ObstacleScenario(name, self.obstacles + other.obstacles, self.seed)

    def positions_m(self, t_s: float) -> NDArray[np.float64]:
        """Obstacle centres at time ``t_s``, shape ``(M, 3)``."""
        linear = self._constant_velocities
        if linear is not None:  # the same operations as ConstantVelocity.position_m
            starts, velocities, start_times = linear
            result: NDArray[np.float64] = starts + (t_s - start_times)[:, None] * velocities
            return result
        return self.trajectories_m(np.array([t_s]))[:, 0, :]

    @cached_property
    def _constant_velocities(
        self,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None:
        """Start points, velocities and start times when every obstacle moves at a constant
        velocity (the flight loop asks several times a control step: one numpy expression
        instead of a loop over obstacles); None otherwise."""
        motions = [o.motion for o in self.obstacles]
        if not all(isinstance(m, ConstantVelocity) for m in motions):
            return None
        linear = [m for m in motions if isinstance(m, ConstantVelocity)]
        return (
            np.array([m.start_m for m in linear], dtype=np.float64).reshape(-1, 3),
            np.array([m.velocity_m_s for m in linear], dtype=np.float64).reshape(-1, 3),
            np.array([m.start_time_s for m in linear], dtype=np.float64),
        )

    @cached_property
    def _constant_velocity_floats(self) -> list[tuple[float, ...]] | None:
        """Per obstacle, as Python floats: start point, velocity, start time, keep-out radius
        and radius, when every obstacle moves at a constant velocity; None otherwise."""
        linear = self._constant_velocities
        if linear is None:
            return None
        starts, velocities, start_times = (array.tolist() for array in linear)
        return [
            (*start, *velocity, start_time, keep_out, radius)
            for start, velocity, start_time, keep_out, radius in zip(
                starts,
                velocities,
                start_times,
                self.keep_out_radii_m.tolist(),
                self.radii_m.tolist(),
                strict=True,
            )
        ]

    def clearance_m(self, position_m: Vec3, t_s: float) -> tuple[float, bool]:
        """How far ``position_m`` is outside the nearest keep-out sphere at ``t_s`` (negative:
        inside one; inf without obstacles), and whether it is inside an obstacle's radius:
        :meth:`swept_clearance_m` of a step that stays put (the same values as numpy's
        distances, bit for bit: tested)."""
        return self.swept_clearance_m(position_m, position_m, t_s, t_s)

    def swept_clearance_m(
        self, start_m: Vec3, end_m: Vec3, t0_s: float, t1_s: float
    ) -> tuple[float, bool]:
        """How far the drone stays outside the nearest keep-out sphere over a control step
        (negative: inside one; inf without obstacles), not only at its samples: the least
        clearance while it goes from ``start_m`` (at ``t0_s``) to ``end_m`` (at ``t1_s``),
        drone and obstacles moving in straight lines in between, and whether it is inside
        an obstacle's radius at any point of it. NaN anywhere makes the clearance NaN, as
        numpy's minimum does.

        A sampled check misses what happens between samples: at 12 m/s a 0.1 s step is
        1.2 m, more than an obstacle 0.8 m across, and a controller that keeps its samples
        outside a keep-out sphere may cut through it between them. Per obstacle the
        relative position is ``r(s) = r0 + s (r1 - r0)`` for ``s`` in [0, 1], nearest the
        centre at ``s = clip(-r0.d / d.d, 0, 1)``, ``d = r1 - r0``.
        """
        if not self.obstacles:
            return math.inf, False
        linear = self._constant_velocity_floats
        # Asked every control step: constant-velocity obstacles on plain floats, with the
        # operations of positions_m in numpy's order (left to right over x, y, z).
        if linear is not None:
            centres0 = [(sx + (t0_s - t) * vx, sy + (t0_s - t) * vy, sz + (t0_s - t) * vz)
                        for sx, sy, sz, vx, vy, vz, t, _, _ in linear]  # fmt: skip
            centres1 = [(sx + (t1_s - t) * vx, sy + (t1_s - t) * vy, sz + (t1_s - t) * vz)
                        for sx, sy, sz, vx, vy, vz, t, _, _ in linear]  # fmt: skip
            keep_out = [o[7] for o in linear]
            radii = [o[8] for o in linear]
        else:
            centres0 = self.positions_m(t0_s).tolist()
            centres1 = self.positions_m(t1_s).tolist()
            keep_out, radii = self.keep_out_radii_m.tolist(), self.radii_m.tolist()
        (ax, ay, az), (bx, by, bz) = start_m, end_m
        clearances, collision = [], False
        for c0, c1, keep, radius in zip(centres0, centres1, keep_out, radii, strict=True):
            rx, ry, rz = ax - c0[0], ay - c0[1], az - c0[2]  # relative position at t0
            dx, dy, dz = bx - c1[0] - rx, by - c1[1] - ry, bz - c1[2] - rz  # its change
            dd = dx * dx + dy * dy + dz * dz
            along = 0.0 if dd <= 0.0 else -(rx * dx + ry * dy + rz * dz) / dd
            s = min(max(along, 0.0), 1.0)
            px, py, pz = rx + s * dx, ry + s * dy, rz + s * dz  # nearest the centre
            distance = math.sqrt(px * px + py * py + pz * pz)
            clearances.append(distance - keep)
            collision = collision or distance < radius
        if any(map(math.isnan, clearances)):
            return math.nan, collision
        return min(clearances), collision

    def trajectories_m(self, times_s: NDArray[np.float64]) -> NDArray[np.float64]:
        """Obstacle centres at each time, shape ``(M, n, 3)``."""
        out = np.empty((len(self.obstacles), len(times_s), 3))
        for i, obstacle in enumerate(self.obstacles):
            out[i] = obstacle.motion.position_m(times_s)
        return out

    def velocities_m_s(self, t_s: float) -> NDArray[np.float64]:
        linear = self._constant_velocities
        if linear is not None:
            return linear[1].copy()
        out = np.empty((len(self.obstacles), 3))
        for i, obstacle in enumerate(self.obstacles):
            out[i] = obstacle.motion.velocity_at(np.array([t_s]))[0]
        return out

    @cached_property
    def radii_m(self) -> NDArray[np.float64]:
        """Each obstacle's radius (read-only: made once, read every control step)."""
        return _read_only(np.array([o.radius_m for o in self.obstacles]))

    @cached_property
    def safety_radii_m(self) -> NDArray[np.float64]:
        """Each obstacle's safety radius (read-only: made once, read every control step)."""
        return _read_only(np.array([o.safety_radius_m for o in self.obstacles]))

    @cached_property
    def keep_out_radii_m(self) -> NDArray[np.float64]:
        """Each obstacle's keep-out radius, ``radius + safety radius`` (read-only)."""
        return _read_only(self.radii_m + self.safety_radii_m)

    def distances_m(self, position_m: ArrayLike, t_s: float) -> NDArray[np.float64]:
        """Distance from ``position_m`` to each obstacle centre at ``t_s``, shape ``(M,)``."""
        return row_norms(self.positions_m(t_s) - np.asarray(position_m))


@dataclass(frozen=True)
class ObstacleForecast:
    """Predicted obstacle centres over a horizon: what a controller is given each step.

    ``positions_m`` has shape ``(M, n, 3)`` for the ``n`` times in ``times_s`` (the first is
    now); ``radius_m`` and ``safety_radius_m`` have shape ``(M,)``.
    """

    times_s: NDArray[np.float64]
    positions_m: NDArray[np.float64]
    radius_m: NDArray[np.float64]
    safety_radius_m: NDArray[np.float64]

    @classmethod
    def none(cls, times_s: NDArray[np.float64]) -> ObstacleForecast:
        return cls(np.asarray(times_s), np.zeros((0, len(times_s), 3)), np.zeros(0), np.zeros(0))

    @property
    def count(self) -> int:
        return int(self.positions_m.shape[0])

    @property
    def keep_out_radius_m(self) -> NDArray[np.float64]:
        return self.radius_m + self.safety_radius_m


class ExactPredictor:
    """Forecasts with the obstacles' true motion (an oracle)."""

    def forecast(
        self, scenario: ObstacleScenario, times_s: NDArray[np.float64]
    ) -> ObstacleForecast:
        return ObstacleForecast(
            np.asarray(times_s),
            scenario.trajectories_m(times_s),
            scenario.radii_m,
            scenario.safety_radii_m,
        )


class ConstantVelocityPredictor:
    """Extrapolates each obstacle's measured position and velocity at ``times_s[0]``.

    Optional seeded Gaussian measurement noise models an imperfect obstacle tracker.
    """

    def __init__(
        self, position_std_m: float = 0.0, velocity_std_m_s: float = 0.0, seed: int = 0
    ) -> None:
        self.position_std_m = position_std_m
        self.velocity_std_m_s = velocity_std_m_s
        self._rng = np.random.default_rng(seed)

    def forecast(
        self, scenario: ObstacleScenario, times_s: NDArray[np.float64]
    ) -> ObstacleForecast:
        times = np.asarray(times_s)
        position = scenario.positions_m(float(times[0]))
        velocity = scenario.velocities_m_s(float(times[0]))
        if self.position_std_m > 0.0 or self.velocity_std_m_s > 0.0:
            position = position + self.position_std_m * self._rng.standard_normal(position.shape)
            velocity = velocity + self.velocity_std_m_s * self._rng.standard_normal(velocity.shape)
        ahead = (times - times[0])[None, :, None]
        positions = position[:, None, :] + ahead * velocity[:, None, :]
        return ObstacleForecast(times, positions, scenario.radii_m, scenario.safety_radii_m)


def row_norms(vectors: NDArray[np.float64]) -> NDArray[np.float64]:
    """The Euclidean norm along the last axis: the operations ``np.linalg.norm(..., axis=-1)``
    runs for a real array (the same floats), without its per-call argument handling."""
    result: NDArray[np.float64] = np.sqrt(np.add.reduce(vectors * vectors, axis=-1))
    return result


def _read_only(array: NDArray[np.float64]) -> NDArray[np.float64]:
    array.flags.writeable = False
    return array
