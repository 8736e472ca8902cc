"""The closed loop: a controller flies the plant along a reference through an obstacle scenario.

:class:`Flight` is one drone's flight on one clock: it keeps the true state, the time, the
controller (and its warm start) and the plant's seeded wind and noise across successive
segments, so a replay harness can call :meth:`Flight.fly_to` once per agent action and
obstacles keep moving in between. Each control step: measure the state, forecast the
obstacles over the controller's horizon, take the reference window, call
``controller.step``, apply the command to the plant for ``dt_s``, and log one row
(:mod:`skyvln_eval.control.flight_log`). Every run is deterministic given its seeds.

:func:`fly_to` is the one-call form for a single segment.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from skyvln_eval.control.base import Command, Controller, SolveStats
from skyvln_eval.control.flight_log import PREDICTED_PATH_COLUMN, log_frame
from skyvln_eval.errors import ConfigError
from skyvln_eval.frames import ViewPose, wrap_angle_rad
from skyvln_eval.native_calls import NATIVE_CALLS
from skyvln_eval.sim.obstacles import ConstantVelocityPredictor, ObstacleForecast, ObstacleScenario
from skyvln_eval.sim.plant import Plant, PlantConfig
from skyvln_eval.sim.quadrotor import DroneState, require_positive
from skyvln_eval.sim.reference import (
    ReferenceConfig,
    ReferenceTrajectory,
    ReferenceWindow,
    segment_reference,
)

#: Slack for floating-point noise when checking the commands against the limits.
LIMIT_TOLERANCE = 1e-9
#: How long a segment may take beyond its reference to settle on the target, by default.
SETTLE_TIME_S = 30.0


class Predictor(Protocol):
    def forecast(self, scenario: ObstacleScenario, times_s: np.ndarray) -> ObstacleForecast: ...


@dataclass(frozen=True)
class ArrivalCriteria:
    """When a :meth:`Flight.fly_to` segment counts as arrived (after the reference ends)."""

    position_tolerance_m: float = 0.5
    speed_tolerance_m_s: float = 0.3
    yaw_tolerance_rad: float = 0.1

    def __post_init__(self) -> None:
        require_positive(self, "position_tolerance_m", "speed_tolerance_m_s", "yaw_tolerance_rad")


@dataclass(frozen=True)
class SegmentResult:
    """One flown segment: where it ended, whether it arrived, and its per-step log.

    The log is built on first use (a replay harness flying many segments only needs the
    whole flight's log, :meth:`Flight.log`).
    """

    final_state: DroneState
    t_end_s: float
    reached: bool
    rows: list[dict[str, Any]] = field(repr=False)
    failed_steps: int
    collided: bool

    @functools.cached_property
    def log(self) -> pd.DataFrame:
        return log_frame(self.rows)


@dataclass
class Flight:
    """One drone flying with one controller through one obstacle scenario, segment after segment."""

    controller: Controller
    start: DroneState
    scenario: ObstacleScenario = field(default_factory=lambda: ObstacleScenario("none"))
    t0_s: float = 0.0
    plant_config: PlantConfig = field(default_factory=PlantConfig)
    seed: int = 0
    predictor: Predictor = field(default_factory=ConstantVelocityPredictor)
    reference_config: ReferenceConfig = field(default_factory=ReferenceConfig)
    arrival: ArrivalCriteria = field(default_factory=ArrivalCriteria)

    def __post_init__(self) -> None:
        if not self.start.is_finite():
            raise ConfigError(f"Flight.start must be a finite state, got {self.start!r}")
        self.plant = Plant(self.start, self.plant_config, self.seed)
        self.t_s = float(self.t0_s)
        self._rows: list[dict[str, Any]] = []
        self.controller.reset()

    @property
    def state(self) -> DroneState:
        """The true state now."""
        return self.plant.state

    @property
    def dt_s(self) -> float:
        return self.controller.dt_s

    def segment_reference(self, target: ViewPose) -> ReferenceTrajectory:
        """The reference :meth:`fly_to` would fly to ``target`` from here and now.

        Useful to place obstacles against a segment before flying it::

            reference = flight.segment_reference(target)
            times = np.arange(flight.t_s, reference.end_time_s, 0.1)
            new = make_scenario(spec, times, reference.window(times).position_m)
            flight.scenario = flight.scenario.merged(new)
            flight.fly_to(target, reference=reference)
        """
        return segment_reference(
            self.state, target, self.t_s, self.reference_config, self.plant_config.params
        )

    def fly_to(
        self,
        target: ViewPose,
        max_time_s: float | None = None,
        reference: ReferenceTrajectory | None = None,
        stop_on_collision: bool = False,
    ) -> SegmentResult:
        """Fly from the current state to ``target`` (ENU waypoint, height z_m, heading yaw_rad).

        The reference (``reference``, else :meth:`segment_reference`) starts now from the
        current position at ``reference_config``'s cruise speed; the segment ends once the
        reference has ended and the drone has settled on the target
        (:class:`ArrivalCriteria`), or after ``max_time_s`` (default: the reference's
        duration plus :data:`SETTLE_TIME_S`); with ``stop_on_collision``, with the first
        step that touches an obstacle (:meth:`fly`).
        """
        reference = reference or self.segment_reference(target)
        if max_time_s is None:
            max_time_s = max(reference.end_time_s - self.t_s, 0.0) + SETTLE_TIME_S
        goal = np.array([target.x_m, target.y_m, target.z_m])

        def arrived(state: DroneState, t_s: float) -> bool:
            a = self.arrival
            return (
                t_s >= reference.end_time_s
                and float(np.linalg.norm(state.position_m - goal)) <= a.position_tolerance_m
                and float(np.linalg.norm(state.velocity_m_s)) <= a.speed_tolerance_m_s
                and abs(wrap_angle_rad(state.yaw_rad - target.yaw_rad)) <= a.yaw_tolerance_rad
            )

        return self.fly(reference, max_time_s, arrived, stop_on_collision)

    def fly(
        self,
        reference: ReferenceTrajectory,
        duration_s: float,
        done: Callable[[DroneState, float], bool] | None = None,
        stop_on_collision: bool = False,
    ) -> SegmentResult:
        """Track ``reference`` for ``duration_s`` seconds, or until ``done(state, t_s)``;
        with ``stop_on_collision``, until a step touches an obstacle (the drone is inside
        its radius at some point of the step, :meth:`ObstacleScenario.swept_clearance_m`): a
        crash. The flight then ends at the end of that step (within one step of the
        contact), not where the rest of the segment would have taken it."""
        if not (math.isfinite(duration_s) and duration_s > 0):
            raise ConfigError(
                f"the flight duration must be a positive number of seconds, got {duration_s!r}"
            )
        first_row = len(self._rows)
        n_steps = max(1, round(duration_s / self.dt_s))
        offsets = self.dt_s * np.arange(self.controller.horizon_steps + 1)
        reached = False
        for k, window in enumerate(_step_windows(reference, self.t_s, self.dt_s, n_steps, offsets)):
            # At least one step: a segment that is done where it starts (a move to where
            # the drone is) still takes a control period, so no two of a run's decisions
            # share a time (an audit: the viewer's decision timeline merged them).
            if k > 0 and done is not None and done(self.state, self.t_s):
                reached = True
                break
            if not self._step(window, stop_on_collision):
                break  # crashed: not reached
        else:
            reached = done is None or bool(done(self.state, self.t_s))
        rows = self._rows[first_row:]
        return SegmentResult(
            final_state=self.state,
            t_end_s=self.t_s,
            reached=reached,
            rows=rows,
            failed_steps=sum(bool(row["solve_failed"]) for row in rows),
            collided=any(bool(row["collision"]) for row in rows),
        )

    def log(self) -> pd.DataFrame:
        """Every step flown so far, all segments."""
        return log_frame(self._rows)

    def _step(self, window: ReferenceWindow, stop_on_collision: bool = False) -> bool:
        """One control step, logged; ``False`` when the step touched an obstacle and
        ``stop_on_collision`` ends the flight there."""
        truth = self.state
        forecast = self.predictor.forecast(self.scenario, window.times_s)
        # The input the rate limits start from, as floats (the controller replaces it).
        before = self.controller.previous_input.tolist()
        previous_tilt = (before[1], before[2])
        # The controller takes the native-code lock for its solves itself.
        command = self.controller.step(self.plant.measure(), window, forecast)
        if not command.is_finite():  # a controller bug must not crash the flight either
            # Eased to hover from the input last applied, not from the non-finite one the
            # controller kept (a hover from NaN is NaN, and so would every state be after).
            self.controller.previous_input = np.array(before)
            thrust, roll, pitch = self.controller.safe_input()
            self.controller.previous_input = np.array([thrust, roll, pitch])
            stats = SolveStats(
                command.stats.solve_time_ms,
                command.stats.iterations,
                "fallback_hover:non_finite_command",
                True,
            )
            command = Command(thrust, roll, pitch, truth.yaw_rad, stats)
        with NATIVE_CALLS:
            self.plant.step(
                command.thrust_m_s2,
                command.roll_ref_rad,
                command.pitch_ref_rad,
                command.yaw_ref_rad,
                self.dt_s,
            )
        after = self.state
        # Clearance and contact over the whole step, not at its start alone.
        clearance, collision = self.scenario.swept_clearance_m(
            (truth.x_m, truth.y_m, truth.z_m),
            (after.x_m, after.y_m, after.z_m),
            self.t_s,
            self.t_s + self.dt_s,
        )
        self._rows.append(self._row(truth, window, command, previous_tilt, (clearance, collision)))
        self.t_s += self.dt_s
        return not (stop_on_collision and collision)

    def _row(
        self,
        truth: DroneState,
        window: ReferenceWindow,
        command: Command,
        previous_tilt: tuple[float, float],
        swept: tuple[float, bool],
    ) -> dict[str, Any]:
        """The log row of a step from ``truth``; ``swept``: its clearance and contact over
        the whole step (:meth:`ObstacleScenario.swept_clearance_m`)."""
        clearance, collision = swept
        violation = clearance < 0.0 or not self._within_limits(command, previous_tilt)
        reference = window.states[0].tolist()  # the Python floats of the row, in one call
        return {
            "controller": self.controller.name,
            "scenario": self.scenario.name,
            "t_s": self.t_s,
            "x_m": truth.x_m,
            "y_m": truth.y_m,
            "z_m": truth.z_m,
            "vx_m_s": truth.vx_m_s,
            "vy_m_s": truth.vy_m_s,
            "vz_m_s": truth.vz_m_s,
            "roll_rad": truth.roll_rad,
            "pitch_rad": truth.pitch_rad,
            "yaw_rad": truth.yaw_rad,
            "ref_x_m": reference[0],
            "ref_y_m": reference[1],
            "ref_z_m": reference[2],
            "ref_yaw_rad": float(window.yaw_rad[0]),
            "cmd_thrust_m_s2": command.thrust_m_s2,
            "cmd_roll_rad": command.roll_ref_rad,
            "cmd_pitch_rad": command.pitch_ref_rad,
            "solve_time_ms": command.stats.solve_time_ms,
            "iterations": command.stats.iterations,
            "status": command.stats.status,
            "solve_failed": command.stats.failed,
            "min_clearance_m": clearance,
            "collision": collision,
            "constraint_violation": violation,
            "ref_roll_rad": reference[6],
            "ref_pitch_rad": reference[7],
            # The command's own array, flattened (a view): the run log's messages and the
            # Parquet writer take arrays, so no step makes a list of 63 Python floats.
            PREDICTED_PATH_COLUMN: (
                None
                if command.predicted_positions_m is None
                else command.predicted_positions_m.reshape(-1)
            ),
        }

    def _within_limits(self, command: Command, previous_tilt: tuple[float, float]) -> bool:
        limits, eps = self.controller.limits, LIMIT_TOLERANCE
        tilt_max = limits.tilt_ref_max_rad + eps
        step_max = limits.tilt_ref_step_max_rad + eps
        roll, pitch = command.roll_ref_rad, command.pitch_ref_rad
        # Plain floats: the same comparisons numpy made on two-element arrays.
        return bool(
            limits.thrust_min_m_s2 - eps <= command.thrust_m_s2 <= limits.thrust_max_m_s2 + eps
            and abs(roll) <= tilt_max
            and abs(pitch) <= tilt_max
            and abs(roll - previous_tilt[0]) <= step_max
            and abs(pitch - previous_tilt[1]) <= step_max
        )


def _step_windows(
    reference: ReferenceTrajectory,
    t0_s: float,
    dt_s: float,
    n_steps: int,
    offsets: NDArray[np.floating[Any]],
) -> Iterator[ReferenceWindow]:
    """The reference window of each step a flight may take, made in batches of 32, 64, 128...
    steps as the flight gets to them: a flight is given time to spare and most arrive long
    before it is up (in the harness they fly about a ninth of it), so one batch for every
    step allowed would mostly be thrown away. Each step's clock is the previous one plus
    ``dt_s``, as :meth:`Flight._step` advances it, so the times are the same floats."""
    clock, made, batch = t0_s, 0, 32
    while made < n_steps:
        times = []
        for _ in range(min(batch, n_steps - made)):
            times.append(clock)
            clock += dt_s
        yield from reference.windows(np.asarray(times)[:, None] + offsets)
        made += len(times)
        batch *= 2


def fly_to(
    state: DroneState,
    target: ViewPose,
    controller: Controller,
    scenario: ObstacleScenario | None = None,
    t0_s: float = 0.0,
    max_time_s: float | None = None,
    seed: int = 0,
    plant_config: PlantConfig | None = None,
    reference_config: ReferenceConfig | None = None,
) -> tuple[DroneState, pd.DataFrame]:
    """Fly one segment from ``state`` at ``t0_s`` to ``target``; the final state and its log.

    For successive segments keep one :class:`Flight` and call :meth:`Flight.fly_to` on it,
    which also continues the controller's warm start and the plant's wind.
    """
    flight = Flight(
        controller=controller,
        start=state,
        scenario=scenario or ObstacleScenario("none"),
        t0_s=t0_s,
        plant_config=plant_config or PlantConfig(),
        seed=seed,
        reference_config=reference_config or ReferenceConfig(),
    )
    result = flight.fly_to(target, max_time_s)
    return result.final_state, result.log
