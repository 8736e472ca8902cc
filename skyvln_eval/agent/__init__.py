"""The SkyVLN agent and its baselines: perception, sub-goals, HSD, TrackBack memory, motion.

Build an agent from a typed config: ``build_agent(AgentConfig(name="skyvln", hsd=False))``;
run it with :func:`skyvln_eval.harness.run_official_episode`. Actions form a closed
vocabulary (:mod:`.actions`) mapped to the official step (:func:`to_official_action`) or
to a target pose for a controller (:func:`to_target_pose`).
"""

from skyvln_eval.agent.actions import (
    ACTION_TYPES,
    Action,
    Climb,
    FlyTo,
    Move,
    Stop,
    Turn,
    Waypoint,
    action_from_dict,
    action_record,
    action_to_dict,
    decision_json_schema,
)
from skyvln_eval.agent.base import Agent, Decision, EpisodeBrief, Observation
from skyvln_eval.agent.baselines import NavGPTAgent, RandomAgent
from skyvln_eval.agent.config import AGENTS, AgentConfig, DetectorConfig, build_agent
from skyvln_eval.agent.detectors import Detection, Detector, SimulatedDetector, create_detector
from skyvln_eval.agent.hsd import SECTOR_NAMES, coarse_position, sector_of
from skyvln_eval.agent.mapping import (
    TURN_NUDGE,
    official_reach_m,
    to_official_action,
    to_target_pose,
)
from skyvln_eval.agent.memory import TrackBackMemory, WayBack
from skyvln_eval.agent.parsing import load_json_object, parse_decision
from skyvln_eval.agent.perception import Panorama, Perception, PerceptionConfig, Sighting
from skyvln_eval.agent.skyvln import SkyVLNAgent
from skyvln_eval.agent.subgoals import SubGoal, SubGoalPlan, parse_subgoals

__all__ = [
    "ACTION_TYPES",
    "AGENTS",
    "SECTOR_NAMES",
    "TURN_NUDGE",
    "Action",
    "Agent",
    "AgentConfig",
    "Climb",
    "Decision",
    "Detection",
    "Detector",
    "DetectorConfig",
    "EpisodeBrief",
    "FlyTo",
    "Move",
    "NavGPTAgent",
    "Observation",
    "Panorama",
    "Perception",
    "PerceptionConfig",
    "RandomAgent",
    "Sighting",
    "SimulatedDetector",
    "SkyVLNAgent",
    "Stop",
    "SubGoal",
    "SubGoalPlan",
    "TrackBackMemory",
    "Turn",
    "WayBack",
    "Waypoint",
    "action_from_dict",
    "action_record",
    "action_to_dict",
    "build_agent",
    "coarse_position",
    "create_detector",
    "decision_json_schema",
    "load_json_object",
    "official_reach_m",
    "parse_decision",
    "parse_subgoals",
    "sector_of",
    "to_official_action",
    "to_target_pose",
]
