"""The dynamics-mode loop: each action is flown by a controller on the quadrotor plant.

As in official mode the episode has at most ``max_steps`` views, the start included, and
the agent's STOP ends it. Every other action becomes a target pose
(:func:`~skyvln_eval.agent.mapping.to_target_pose`, kept inside the map); a reference at
cruise speed is flown by the controller through obstacles placed against that segment;
the next view is seen from the flown pose (centre below the drone, heading from its yaw,
edge = 2 x height). A collision ends the episode where it happened (``end_on_collision``).
The per-step control log covers the whole episode.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from skyvln_eval.agent.actions import Action, action_to_dict
from skyvln_eval.agent.base import Agent
from skyvln_eval.agent.mapping import to_target_pose
from skyvln_eval.avdn.constants import METERS_PER_DEGREE
from skyvln_eval.avdn.records import Episode
from skyvln_eval.control import ArrivalCriteria, Controller, Flight
from skyvln_eval.errors import ConfigError
from skyvln_eval.frames import ViewPose, enu_yaw_to_compass_deg, pose_to_view, view_to_pose
from skyvln_eval.harness.config import DynamicsSettings
from skyvln_eval.harness.rollout import Rollout, episode_brief
from skyvln_eval.harness.seeds import derived_seed
from skyvln_eval.sensing import SensorConfig

if TYPE_CHECKING:
    from skyvln_eval.harness.commander import SimulatedCommander
from skyvln_eval.sim.obstacles import ObstacleScenario
from skyvln_eval.sim.quadrotor import DroneState
from skyvln_eval.sim.reference import ReferenceConfig
from skyvln_eval.sim.scenarios import ScenarioSpec, make_scenario
from skyvln_eval.worlds.tile import WorldTile

#: A segment shorter than this gets no obstacles (they are placed where the drone cruises).
MIN_ROUTE_FOR_OBSTACLES_M = 5.0


@dataclass(eq=False)
class DynamicsRollout(Rollout):
    """A flown episode: the :class:`Rollout` plus each action's target pose, when it was
    decided and where its segment ended, the obstacles of each segment and the control log."""

    targets: list[ViewPose] = field(default_factory=list)
    segment_end_times_s: list[float] = field(default_factory=list)
    reached: list[bool] = field(default_factory=list)
    decision_times_s: list[float] = field(default_factory=list)
    control_log: pd.DataFrame = field(default_factory=pd.DataFrame)
    obstacle_segments: list[tuple[float, float, ObstacleScenario]] = field(default_factory=list)
    simulated_s: float = 0.0


def _inside_map(target: ViewPose, width_m: float, height_m: float) -> ViewPose:
    """The target with its ground point kept inside the map (the view needs a map below)."""
    x = min(max(target.x_m, 0.0), width_m)
    y = min(max(target.y_m, 0.0), height_m)
    return ViewPose(x, y, target.z_m, target.yaw_rad)


def _pose_of(state: DroneState) -> ViewPose:
    return ViewPose(state.x_m, state.y_m, state.z_m, state.yaw_rad)


def _feedback(action: Action, reached: bool, collided: bool) -> str:
    what = json.dumps(action_to_dict(action))
    if collided:
        return f"crashed: {what} hit an obstacle"
    return f"done: {what}" if reached else f"partly done: {what} (the drone did not settle in time)"


def run_dynamics_episode(
    agent: Agent,
    episode: Episode,
    world: WorldTile,
    controller: Controller,
    settings: DynamicsSettings,
    seed: int,
    max_steps: int,
    sensors: SensorConfig | None = None,
    commander: SimulatedCommander | None = None,
) -> DynamicsRollout:
    """Fly ``episode`` with ``agent`` and ``controller``; see the module docstring.

    As in official mode, the agent is told only the episode's brief and sees through the
    drone's ``sensors``.
    """
    if max_steps < 1:
        raise ConfigError(f"max_steps must be >= 1 (views, start included), got {max_steps}")
    georef = episode.georef
    (lat0, lng0), (lat1, lng1) = georef.gps_botm_left, georef.gps_top_right
    width_m, height_m = (lng1 - lng0) * METERS_PER_DEGREE, (lat1 - lat0) * METERS_PER_DEGREE
    # A copy: the episode's start view stays as it was.
    view = np.array(episode.start_view, dtype=np.float64)
    pose = view_to_pose(view, georef)
    obstacles = settings.obstacles
    flight = Flight(
        controller,
        DroneState(pose.x_m, pose.y_m, pose.z_m, yaw_rad=pose.yaw_rad),
        # One scenario name for the whole episode, whether or not a segment has obstacles.
        scenario=ObstacleScenario(obstacles.kind),
        plant_config=settings.plant.plant_config(),
        seed=seed,
        reference_config=ReferenceConfig(
            cruise_speed_m_s=settings.cruise_speed_m_s,
            max_acceleration_m_s2=settings.max_acceleration_m_s2,
            yaw_rate_max_rad_s=settings.yaw_rate_max_rad_s,
        ),
        arrival=ArrivalCriteria(
            position_tolerance_m=settings.arrival_tolerance_m,
            speed_tolerance_m_s=settings.arrival_speed_m_s,
            yaw_tolerance_rad=settings.arrival_yaw_rad,
        ),
    )
    rollout = DynamicsRollout(
        episode.episode_id, [view], [episode.start_heading_deg], max_steps=max_steps
    )
    agent.reset(episode_brief(episode, max_steps))
    sensor_config = sensors or SensorConfig()
    feedback: str | None = None
    while len(rollout.views) < max_steps:
        rollout.decision_times_s.append(flight.t_s)
        action = rollout.observe_and_decide(
            agent, world, pose, view, sensor_config, commander, feedback
        )
        if action is None:
            break
        target = _inside_map(to_target_pose(action, pose), width_m, height_m)
        reference = flight.segment_reference(target)
        if obstacles.kind != "none" and obstacles.n_obstacles > 0:
            times = np.arange(flight.t_s, reference.end_time_s + flight.dt_s, flight.dt_s)
            route = reference.window(times).position_m if len(times) >= 2 else np.zeros((1, 3))
            # Obstacles meet the drone where it travels; a turn or climb in place has no route.
            if np.linalg.norm(np.diff(route, axis=0), axis=1).sum() >= MIN_ROUTE_FOR_OBSTACLES_M:
                spec = ScenarioSpec(
                    obstacles.kind,
                    obstacles.n_obstacles,
                    obstacles.radius_m,
                    obstacles.safety_radius_m,
                    obstacles.obstacle_speed_m_s,
                    seed=derived_seed(seed, "obstacles", len(rollout.views)),
                )
                placed = make_scenario(spec, times, route)
                # Each segment meets its own obstacles; one name keeps the log one scenario.
                flight.scenario = ObstacleScenario(obstacles.kind, placed.obstacles, spec.seed)
        start_s = flight.t_s
        segment = flight.fly_to(
            target,
            max_time_s=settings.max_segment_time_s,
            reference=reference,
            stop_on_collision=settings.end_on_collision,  # a crash ends the flight there
        )
        rollout.obstacle_segments.append((start_s, segment.t_end_s, flight.scenario))
        rollout.targets.append(target)
        rollout.reached.append(segment.reached)
        rollout.segment_end_times_s.append(segment.t_end_s)
        pose = _pose_of(segment.final_state)
        if not all(math.isfinite(v) for v in (pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad)):
            rollout.stop_reason, rollout.error = "error", "the flown state is not finite"
            break
        view = pose_to_view(ViewPose(pose.x_m, pose.y_m, max(pose.z_m, 1.0), pose.yaw_rad), georef)
        rollout.views.append(view)
        rollout.headings_deg.append(round(float(enu_yaw_to_compass_deg(pose.yaw_rad))) % 360)
        feedback = _feedback(action, segment.reached, segment.collided)
        if segment.collided and settings.end_on_collision:
            rollout.stop_reason = "collision"
            break
    rollout.control_log = flight.log()
    rollout.simulated_s = flight.t_s
    return rollout
