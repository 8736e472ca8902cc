"""The minimal official-mode loop: an agent flies one episode with the official AVDN step.

As in AVDN: the episode has at most ``max_steps`` views, the start view included (by
default its :meth:`~skyvln_eval.avdn.Episode.view_budget`, AVDN's ``max_action_len`` per
dialog round flown); the
agent's STOP ends it; every other action becomes an official action
(:func:`~skyvln_eval.agent.mapping.to_official_action`) applied by
:func:`~skyvln_eval.avdn.official_step_detailed` inside the map bounds (a step that
would leave the map is cancelled or cut short, as officially, and the agent is told).
The view budget running out ends it too. An agent error the user can cause
(:class:`~skyvln_eval.errors.SkyvlnError`) ends the episode with what was flown so far.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from skyvln_eval.agent.actions import Action, action_to_dict
from skyvln_eval.agent.base import Agent
from skyvln_eval.agent.mapping import official_shortfall, to_official_action
from skyvln_eval.avdn.records import Episode
from skyvln_eval.avdn.step import OfficialAction, official_step_detailed
from skyvln_eval.errors import ConfigError
from skyvln_eval.frames import view_to_pose
from skyvln_eval.harness.rollout import Rollout, episode_brief
from skyvln_eval.sensing import SensorConfig

if TYPE_CHECKING:
    from skyvln_eval.harness.commander import SimulatedCommander
from skyvln_eval.worlds.tile import WorldTile


@dataclass(eq=False)
class OfficialRollout(Rollout):
    """An episode in official mode: the :class:`Rollout` plus each step's official action
    and outcome (``full``, or cut short by the map border)."""

    official_actions: list[OfficialAction] = field(default_factory=list)
    step_outcomes: list[str] = field(default_factory=list)


def _feedback(action: Action, outcome: str, turn_deg: int, shortfall: str | None = None) -> str:
    """What became of ``action``, as the agent is told: done (how it turned, and what the
    step could not do of it: ``shortfall``), or what the map's border kept it from."""
    what = json.dumps(action_to_dict(action))
    if outcome == "full":
        # The step's turn is clockwise in [0, 360] (360 from its rounded pi): said as the
        # pilot would, left or right by at most 180 degrees.
        signed = (turn_deg + 180) % 360 - 180
        turned = (
            "no turn"
            if signed == 0
            else f"turned {abs(signed)} deg {'right' if signed > 0 else 'left'}"
        )
        # A move past one step's reach was said done in full (an audit: 390 m asked, 88 m
        # flown, and the next prompt said "done").
        return f"done: {what} ({turned}{f'; {shortfall}' if shortfall else ''})"
    if outcome == "cancelled":
        return f"not done: {what} would have left the map; nothing changed"
    if outcome == "zoom_only":
        return f"partly done: {what} changed height but turning would have left the map"
    return f"partly done: {what} turned but moving would have left the map"


def run_official_episode(
    agent: Agent,
    episode: Episode,
    world: WorldTile,
    max_steps: int | None = None,
    sensors: SensorConfig | None = None,
    commander: SimulatedCommander | None = None,
) -> OfficialRollout:
    """Fly ``episode`` with ``agent`` in official mode; see the module docstring.

    The agent is told only the episode's brief; at each step it gets its pose, the
    feedback and the drone's ``sensors`` (RGB, depth and the semantic camera by default).
    """
    if max_steps is None:
        max_steps = episode.view_budget()
    if max_steps < 1:
        raise ConfigError(f"max_steps must be >= 1 (views, start included), got {max_steps}")
    georef = episode.georef
    bounds = (georef.gps_botm_left, georef.gps_top_right)
    # A copy: the episode's start view stays as it was.
    view = np.array(episode.start_view, dtype=np.float64)
    rollout = OfficialRollout(
        episode.episode_id, [view], [episode.start_heading_deg], max_steps=max_steps
    )
    agent.reset(episode_brief(episode, max_steps))
    sensor_config = sensors or SensorConfig()
    feedback = None
    while len(rollout.views) < max_steps:
        pose = view_to_pose(view, georef)
        action = rollout.observe_and_decide(
            agent, world, pose, view, sensor_config, commander, feedback
        )
        if action is None:
            break
        official = to_official_action(action, view)
        shortfall = official_shortfall(action, view, official)
        result = official_step_detailed(view, official.waypoint, official.altitude, *bounds)
        rollout.official_actions.append(official)
        rollout.step_outcomes.append(result.outcome)
        feedback = _feedback(action, result.outcome, result.turn_deg, shortfall)
        view = result.corners
        rollout.views.append(view)
        rollout.headings_deg.append(result.heading_deg)
    return rollout
