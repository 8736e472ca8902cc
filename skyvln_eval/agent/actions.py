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
from collections.abc import Mapping, Sequence
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


@dataclass(frozen=True)
class FieldSpec:
    """One field of an action in JSON: its type, its range (numbers), whether required.

    The JSON schema sent to the model and the parser are both derived from these specs
    (:data:`ACTION_SPECS`), so a decoder constrained by the schema can only produce what
    the parser accepts, and the parser's reasons name what the schema says.
    """

    name: str
    kind: Literal["number", "string"]
    low: float = 0.0
    high: float = 0.0
    required: bool = True
    description: str = ""

    def schema(self) -> dict[str, Any]:
        if self.kind == "string":
            out: dict[str, Any] = {"type": "string", "maxLength": MAX_ID_CHARS}
        else:
            out = {"type": "number", "minimum": self.low, "maximum": self.high}
        if not self.required:  # strict structured output wants every field: null = absent
            out["type"] = [out["type"], "null"]
        return out | ({"description": self.description} if self.description else {})


#: Longest landmark id an action may name (ids are short: ``L12``, ``P3``).
MAX_ID_CHARS: Final = 40


def _distance(high: float, what: str) -> FieldSpec:
    return FieldSpec("distance_m", "number", 0.0, high, description=what)


#: Every action type and its fields, in the order the model is asked to write them.
ACTION_SPECS: Final[dict[str, tuple[FieldSpec, ...]]] = {
    "move_forward": (_distance(MAX_MOVE_M, "metres"),),
    "move_left": (_distance(MAX_MOVE_M, "metres"),),
    "move_right": (_distance(MAX_MOVE_M, "metres"),),
    "turn": (FieldSpec("degrees", "number", -180.0, 180.0, description="positive = right"),),
    "ascend": (_distance(MAX_CLIMB_M, "metres of height"),),
    "descend": (_distance(MAX_CLIMB_M, "metres of height"),),
    "fly_to": (
        FieldSpec("landmark", "string", description="a landmark or memory id, e.g. L3"),
        FieldSpec("height_m", "number", MIN_HEIGHT_M, MAX_HEIGHT_M, required=False),
    ),
    "waypoint": (
        FieldSpec("x", "number", -1.0, 1.0, description="half view edges, right"),
        FieldSpec("y", "number", -1.0, 1.0, description="half view edges, forward"),
        FieldSpec("altitude", "number", 0.0, 1.0, description="view edge 40 + 360 x altitude m"),
    ),
    "stop": (),
}
ACTION_TYPES: Final = tuple(ACTION_SPECS)
#: Fields each action type takes in JSON (required, optional), from :data:`ACTION_SPECS`.
ACTION_FIELDS: Final[dict[str, tuple[tuple[str, ...], tuple[str, ...]]]] = {
    kind: (
        tuple(f.name for f in specs if f.required),
        tuple(f.name for f in specs if not f.required),
    )
    for kind, specs in ACTION_SPECS.items()
}


def _number(value: Any, spec: FieldSpec) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ActionParseError(f"field '{spec.name}' must be a number, got {type(value).__name__}")
    try:
        number = float(value)
    except OverflowError:  # an integer of hundreds of digits
        raise ActionParseError(
            f"field '{spec.name}' is far outside the allowed [{spec.low:g}, {spec.high:g}]"
        ) from None
    if not math.isfinite(number):
        raise ActionParseError(f"field '{spec.name}' must be finite, got {value!r}")
    if not spec.low <= number <= spec.high:
        raise ActionParseError(
            f"field '{spec.name}' = {number:g} is outside the allowed [{spec.low:g}, {spec.high:g}]"
        )
    return number


def _fields(kind: str, data: Mapping[str, Any]) -> dict[str, Any]:
    """The action's fields checked against its specs (absent optional fields are None)."""
    specs = ACTION_SPECS[kind]
    known = {spec.name for spec in specs}
    unknown = sorted(set(data) - {"type"} - known)
    if unknown:
        takes = ", ".join(sorted(known)) or "no fields"
        raise ActionParseError(
            f"action '{kind}' does not take field(s) {', '.join(unknown)} (it takes {takes})"
        )
    missing = [spec.name for spec in specs if spec.required and spec.name not in data]
    if missing:
        raise ActionParseError(f"action '{kind}' needs field(s) {', '.join(missing)}")
    out: dict[str, Any] = {}
    for spec in specs:
        value = data.get(spec.name)
        if value is None:
            out[spec.name] = None
        elif spec.kind == "number":
            out[spec.name] = _number(value, spec)
        elif not isinstance(value, str) or not value or len(value) > MAX_ID_CHARS:
            raise ActionParseError(
                f"field '{spec.name}' must be a non-empty string of at most {MAX_ID_CHARS} "
                "characters"
            )
        else:
            out[spec.name] = value
    return out


def action_from_dict(data: Any, landmark_offsets: Mapping[str, tuple[float, float]]) -> Action:
    """Validate one JSON action and build it; raises :class:`ActionParseError` saying why not.

    ``landmark_offsets`` maps the landmark ids the agent may fly to (detected now or kept
    in memory) to their ``(east_m, north_m)`` displacement from the drone. A field set to
    ``null`` counts as absent (strict structured output writes optional fields as null).
    """
    if not isinstance(data, Mapping):
        raise ActionParseError(f"'action' must be a JSON object, got {type(data).__name__}")
    data = {key: value for key, value in data.items() if value is not None}
    kind = data.get("type")
    if not isinstance(kind, str) or kind not in ACTION_SPECS:
        raise ActionParseError(f"unknown action type {kind!r}; allowed: {', '.join(ACTION_TYPES)}")
    f = _fields(kind, data)
    if kind.startswith("move_"):
        return Move(kind.removeprefix("move_"), f["distance_m"])  # type: ignore[arg-type]
    if kind == "turn":
        return Turn(f["degrees"])
    if kind in ("ascend", "descend"):
        return Climb(f["distance_m"] if kind == "ascend" else -f["distance_m"])
    if kind == "fly_to":
        landmark = f["landmark"]
        if landmark not in landmark_offsets:
            known = ", ".join(sorted(landmark_offsets)) or "none"
            raise ActionParseError(f"fly_to names landmark {landmark!r}, not a known one ({known})")
        east, north = landmark_offsets[landmark]
        return FlyTo(landmark, float(east), float(north), f["height_m"])
    if kind == "waypoint":
        return Waypoint(f["x"], f["y"], f["altitude"])
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


def action_json_schema(landmark_ids: Sequence[str] | None = None) -> dict[str, Any]:
    """The schema of one action: one object per action type (a discriminated union on
    ``type``), each with exactly its fields and their ranges, from :data:`ACTION_SPECS`.

    With ``landmark_ids`` (the ids a decision may fly to), ``fly_to`` names one of them (an
    enum, which grammar-constrained decoders enforce; no ``fly_to`` when there is none),
    so a constrained decoder cannot name a landmark the parser refuses.
    """
    variants = []
    for kind, specs in ACTION_SPECS.items():
        properties: dict[str, Any] = {"type": {"type": "string", "enum": [kind]}}
        properties |= {spec.name: spec.schema() for spec in specs}
        if kind == "fly_to" and landmark_ids is not None:
            if not landmark_ids:
                continue
            properties["landmark"] |= {"enum": list(landmark_ids)}
        variants.append(
            {
                "type": "object",
                "properties": properties,
                "required": list(properties),
                "additionalProperties": False,
            }
        )
    return {"anyOf": variants}


#: Longest ``thought`` the schema allows: bounds what a constrained decoder writes before
#: the action, so a talkative model cannot spend the whole budget on it.
MAX_SCHEMA_THOUGHT_CHARS: Final = 400


def decision_json_schema(landmark_ids: Sequence[str] | None = None) -> dict[str, Any]:
    """JSON schema of the motion generator's output, sent as structured output.

    ``{"thought": str, "action": <one action type with its fields>}``; every field that
    the parser accepts and nothing else (see :func:`action_json_schema`; ``landmark_ids``
    the ids this decision may fly to, when known).
    """
    return {
        "type": "object",
        "properties": {
            "thought": {"type": "string", "maxLength": MAX_SCHEMA_THOUGHT_CHARS},
            "action": action_json_schema(landmark_ids),
        },
        "required": ["thought", "action"],
        "additionalProperties": False,
    }
