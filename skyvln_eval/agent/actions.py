"""The agent's closed action vocabulary, as typed data, and its strict validation.

Every action an agent can take is one of the frozen dataclasses below; nothing else is
ever executed. LLM output is turned into one of them by :func:`action_from_dict`, which
checks the type against the vocabulary, every field's type and range, and rejects any
field it does not know (an action never carries code, a shell command or a URL).

Units: distances and heights in metres, turns in degrees (positive = clockwise, i.e. to
the right, seen from above). The AVDN waypoint keeps the official units: ``x`` to the
right and ``y`` forward in half view edges, ``altitude`` in [0, 1] (view edge
``40 + 360 * altitude`` metres).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final, Literal

from skyvln_eval.errors import ActionParseError

#: Longest move an agent may ask for in one action, metres. The official step moves at most
#: sqrt(2) half edges (283 m at the largest view); asking for far more is a sign of garbage.
MAX_MOVE_M: Final = 400.0
#: Largest climb or descent in one action, metres of height (the height range is 20-200 m).
MAX_CLIMB_M: Final = 180.0
#: Flight height range of a 90 degree camera that sees AVDN's 40-400 m view edges.
MIN_HEIGHT_M: Final = 20.0
MAX_HEIGHT_M: Final = 200.0

ActionType = Literal[
    "move_forward",
    "move_left",
    "move_right",
    "turn",
    "ascend",
    "descend",
    "fly_to",
    "waypoint",
    "stop",
]


@dataclass(frozen=True)
class Move:
    """Fly ``distance_m`` metres forward, to the left or to the right of the current heading.

    A multirotor can fly sideways without turning (dynamics mode keeps the heading); the
    official AVDN step cannot, so there the view turns towards the motion.
    """

    direction: Literal["forward", "left", "right"]
    distance_m: float

    @property
    def type(self) -> ActionType:
        return f"move_{self.direction}"  # type: ignore[return-value]


@dataclass(frozen=True)
class Turn:
    """Turn in place by ``degrees`` (positive = clockwise / right, negative = left)."""

    degrees: float
    type: ActionType = "turn"


@dataclass(frozen=True)
class Climb:
    """Change height by ``distance_m`` metres (positive = ascend).

    The view edge changes twice as much (edge = 2 x height for a 90 degree camera).
    """

    distance_m: float

    @property
    def type(self) -> ActionType:
        return "ascend" if self.distance_m >= 0 else "descend"


@dataclass(frozen=True)
class FlyTo:
    """Fly to a detected (or remembered) landmark, optionally ending at ``height_m``.

    The LLM names the landmark (``landmark``, e.g. ``"L3"``); the agent resolves it to the
    landmark's displacement from the drone at decision time (``east_m``, ``north_m``),
    so the action can be mapped without any map or georeference.
    """

    landmark: str
    east_m: float
    north_m: float
    height_m: float | None = None
    type: ActionType = "fly_to"


@dataclass(frozen=True)
class Waypoint:
    """The AVDN action: waypoint ``(x, y)`` in half view edges, altitude in [0, 1].

    ``x`` points to the right and ``y`` forward in the current view.
    """

    x: float
    y: float
    altitude: float
    type: ActionType = "waypoint"


@dataclass(frozen=True)
class Stop:
    """End the episode here: the current view is the agent's answer."""

    type: ActionType = "stop"


Action = Move | Turn | Climb | FlyTo | Waypoint | Stop

#: Fields each action type takes in JSON (required, optional).
ACTION_FIELDS: Final[dict[str, tuple[tuple[str, ...], tuple[str, ...]]]] = {
    "move_forward": (("distance_m",), ()),
    "move_left": (("distance_m",), ()),
    "move_right": (("distance_m",), ()),
    "turn": (("degrees",), ()),
    "ascend": (("distance_m",), ()),
    "descend": (("distance_m",), ()),
    "fly_to": (("landmark",), ("height_m",)),
    "waypoint": (("x", "y", "altitude"), ()),
    "stop": ((), ()),
}
ACTION_TYPES: Final = tuple(ACTION_FIELDS)


def _number(data: Mapping[str, Any], key: str, low: float, high: float) -> float:
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ActionParseError(f"field '{key}' must be a number, got {type(value).__name__}")
    number = float(value)
    if not math.isfinite(number):
        raise ActionParseError(f"field '{key}' must be finite, got {value!r}")
    if not low <= number <= high:
        raise ActionParseError(
            f"field '{key}' = {number:g} is outside the allowed [{low:g}, {high:g}]"
        )
    return number


def action_from_dict(data: Any, landmark_offsets: Mapping[str, tuple[float, float]]) -> Action:
    """Validate one JSON action and build it; raises :class:`ActionParseError` saying why not.

    ``landmark_offsets`` maps the landmark ids the agent may fly to (detected now or kept
    in memory) to their ``(east_m, north_m)`` displacement from the drone.
    """
    if not isinstance(data, Mapping):
        raise ActionParseError(f"'action' must be a JSON object, got {type(data).__name__}")
    # Structured output fills the fields an action does not use with null: drop them.
    data = {key: value for key, value in data.items() if value is not None}
    kind = data.get("type")
    if not isinstance(kind, str) or kind not in ACTION_FIELDS:
        raise ActionParseError(f"unknown action type {kind!r}; allowed: {', '.join(ACTION_TYPES)}")
    required, optional = ACTION_FIELDS[kind]
    unknown = sorted(set(data) - {"type", *required, *optional})
    if unknown:
        raise ActionParseError(f"action '{kind}' does not take field(s) {', '.join(unknown)}")
    missing = [key for key in required if key not in data]
    if missing:
        raise ActionParseError(f"action '{kind}' needs field(s) {', '.join(missing)}")
    if kind.startswith("move_"):
        return Move(kind.removeprefix("move_"), _number(data, "distance_m", 0.0, MAX_MOVE_M))  # type: ignore[arg-type]
    if kind == "turn":
        return Turn(_number(data, "degrees", -180.0, 180.0))
    if kind in ("ascend", "descend"):
        distance = _number(data, "distance_m", 0.0, MAX_CLIMB_M)
        return Climb(distance if kind == "ascend" else -distance)
    if kind == "fly_to":
        landmark = data["landmark"]
        if not isinstance(landmark, str) or landmark not in landmark_offsets:
            known = ", ".join(sorted(landmark_offsets)) or "none"
            raise ActionParseError(f"fly_to names landmark {landmark!r}, not a known one ({known})")
        height = data.get("height_m")
        height_m = None if height is None else _number(data, "height_m", MIN_HEIGHT_M, MAX_HEIGHT_M)
        east, north = landmark_offsets[landmark]
        return FlyTo(landmark, float(east), float(north), height_m)
    if kind == "waypoint":
        return Waypoint(
            _number(data, "x", -1.0, 1.0),
            _number(data, "y", -1.0, 1.0),
            _number(data, "altitude", 0.0, 1.0),
        )
    return Stop()


def action_to_dict(action: Action) -> dict[str, Any]:
    """The JSON form of an action, as an LLM writes it (fly_to keeps only the landmark id)."""
    if isinstance(action, Move):
        return {"type": action.type, "distance_m": action.distance_m}
    if isinstance(action, Turn):
        return {"type": "turn", "degrees": action.degrees}
    if isinstance(action, Climb):
        return {"type": action.type, "distance_m": abs(action.distance_m)}
    if isinstance(action, FlyTo):
        out: dict[str, Any] = {"type": "fly_to", "landmark": action.landmark}
        if action.height_m is not None:
            out["height_m"] = action.height_m
        return out
    if isinstance(action, Waypoint):
        return {"type": "waypoint", "x": action.x, "y": action.y, "altitude": action.altitude}
    return {"type": "stop"}


def action_record(action: Action) -> dict[str, Any]:
    """Everything about an action for logs (fly_to with its resolved displacement)."""
    out = action_to_dict(action)
    if isinstance(action, FlyTo):
        out.update(east_m=action.east_m, north_m=action.north_m)
    return out


def decision_json_schema() -> dict[str, Any]:
    """JSON schema of the motion generator's output, sent as ``response_format`` where supported.

    A flat object keeps it within the subset strict structured output accepts: every
    field present, unused ones ``null``; :func:`action_from_dict` then checks the ranges.
    """
    number_or_null = {"type": ["number", "null"]}
    return {
        "type": "object",
        "additionalProperties": False,
        "required": ["thought", "action"],
        "properties": {
            "thought": {"type": "string"},
            "action": {
                "type": "object",
                "additionalProperties": False,
                "required": [
                    "type",
                    "distance_m",
                    "degrees",
                    "landmark",
                    "height_m",
                    "x",
                    "y",
                    "altitude",
                ],
                "properties": {
                    "type": {"type": "string", "enum": list(ACTION_TYPES)},
                    "distance_m": number_or_null,
                    "degrees": number_or_null,
                    "landmark": {"type": ["string", "null"]},
                    "height_m": number_or_null,
                    "x": number_or_null,
                    "y": number_or_null,
                    "altitude": number_or_null,
                },
            },
        },
    }
