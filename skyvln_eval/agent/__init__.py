"""The SkyVLN agent: its closed action vocabulary and the mappings to each execution mode.

Actions form a closed vocabulary (:mod:`.actions`), parsed strictly from LLM output
(:mod:`.parsing`) and mapped to the official step (:func:`to_official_action`) or to a
target pose for a controller (:func:`to_target_pose`).
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
from skyvln_eval.agent.mapping import (
    TURN_NUDGE,
    official_reach_m,
    to_official_action,
    to_target_pose,
)
from skyvln_eval.agent.parsing import load_json_object, parse_decision

__all__ = [
    "ACTION_TYPES",
    "TURN_NUDGE",
    "Action",
    "Climb",
    "FlyTo",
    "Move",
    "Stop",
    "Turn",
    "Waypoint",
    "action_from_dict",
    "action_record",
    "action_to_dict",
    "decision_json_schema",
    "load_json_object",
    "official_reach_m",
    "parse_decision",
    "to_official_action",
    "to_target_pose",
]
