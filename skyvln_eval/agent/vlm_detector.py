"""A vision-language model as the landmark detector, over the OpenAI protocol.

Each capture goes to the model as a JPEG (at most the backend's ``image_max_side_px`` on
its long side) with the landmark phrases to look for; the model answers with landmarks
and boxes in JSON (:data:`LANDMARKS_SCHEMA`'s shape, checked by :func:`parse_landmarks`).
Boxes are in coordinates from 0 to 1000 of the image's width and height, as several VLMs
are trained to give them, so they do not depend on how far the image was scaled down;
they become pixel boxes of the capture.

The call goes through the project's :class:`~skyvln_eval.llm.client.LLMClient` and
:func:`~skyvln_eval.agent.calls.call_json`, so it is cached, retried, repaired and
recorded like every other LLM call. The detector keeps the records of its calls (and the
failures of calls that gave nothing usable: that view then has no detections) until
:meth:`VlmDetector.take_calls` collects them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

from skyvln_eval.agent.calls import call_json
from skyvln_eval.agent.detectors import Detection, Detector, DetectorCalls, clip_box
from skyvln_eval.agent.images import jpeg_image
from skyvln_eval.agent.parsing import load_json_object
from skyvln_eval.errors import ActionParseError, ConfigError
from skyvln_eval.frames import enu_yaw_to_compass_deg
from skyvln_eval.llm.client import LLMClient
from skyvln_eval.llm.config import LLMConfig, build_client
from skyvln_eval.llm.types import Message
from skyvln_eval.sensing import CameraImages

MODULE: Final = "detect"
BOX_SCALE: Final = 1000
MAX_LANDMARKS: Final = 20
MAX_LABEL_CHARS: Final = 80
MAX_CAPTION_CHARS: Final = 200
_FIELDS: Final = ("label", "box", "score", "caption")

SYSTEM_PROMPT: Final = (
    "You are the landmark detector of a drone's camera. You look at one aerial image and "
    "report where the landmarks you are asked for are, with boxes. You report only what you "
    "can see. You answer with one JSON object only."
)


def landmarks_schema(phrases: Sequence[str] = ()) -> dict[str, Any]:
    """The answer's JSON schema; with ``phrases``, a label must be one of them.

    :func:`parse_landmarks` accepts what this allows, except boxes without area
    (``x0 >= x1`` or ``y0 >= y1``), which it refuses with a reason to repair.
    """
    label: dict[str, Any] = {"type": "string", "maxLength": MAX_LABEL_CHARS}
    if phrases:
        label = {"type": "string", "enum": list(phrases)}
    coordinate = {"type": "number", "minimum": 0, "maximum": BOX_SCALE}
    return {
        "type": "object",
        "additionalProperties": False,
        "required": ["landmarks"],
        "properties": {
            "landmarks": {
                "type": "array",
                "maxItems": MAX_LANDMARKS,
                "items": {
                    "type": "object",
                    "additionalProperties": False,
                    "required": list(_FIELDS),
                    "properties": {
                        "label": label,
                        "box": {
                            "type": "array",
                            "minItems": 4,
                            "maxItems": 4,
                            "items": coordinate,
                        },
                        "score": {"type": "number", "minimum": 0, "maximum": 1},
                        "caption": {"type": "string", "maxLength": MAX_CAPTION_CHARS},
                    },
                },
            }
        },
    }


#: The schema without a list of phrases (open vocabulary).
LANDMARKS_SCHEMA: Final = landmarks_schema()


@dataclass(frozen=True)
class Landmark:
    """One landmark of the answer: label, box in 0-1000 image coordinates, score, caption."""

    label: str
    box: tuple[float, float, float, float]
    score: float
    caption: str


def _number(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | float) and math.isfinite(value)


def _landmark(item: Any, where: str, phrases: Sequence[str]) -> Landmark:
    if not isinstance(item, dict):
        raise ActionParseError(f"{where} must be an object")
    unknown = sorted(set(item) - set(_FIELDS))
    missing = [f for f in _FIELDS if f not in item]
    if unknown or missing:
        raise ActionParseError(
            f"{where} must have exactly the fields {', '.join(_FIELDS)} "
            f"(unknown: {', '.join(unknown) or 'none'}; missing: {', '.join(missing) or 'none'})"
        )
    label = item["label"]
    if not isinstance(label, str) or not label.strip() or len(label) > MAX_LABEL_CHARS:
        raise ActionParseError(f"{where}.label must be a non-empty string")
    if phrases:
        by_text = {p.strip().lower(): p for p in phrases}
        if label.strip().lower() not in by_text:
            raise ActionParseError(
                f"{where}.label {label!r} is not one of the phrases asked for: "
                + ", ".join(repr(p) for p in phrases)
            )
        label = by_text[label.strip().lower()]
    box = item["box"]
    if not isinstance(box, list) or len(box) != 4 or not all(_number(v) for v in box):
        raise ActionParseError(f"{where}.box must be a list of 4 numbers [x0, y0, x1, y1]")
    if not all(0 <= v <= BOX_SCALE for v in box):
        raise ActionParseError(f"{where}.box coordinates must be in [0, {BOX_SCALE}], got {box}")
    x0, y0, x1, y1 = (float(v) for v in box)
    if x0 >= x1 or y0 >= y1:
        raise ActionParseError(f"{where}.box needs x0 < x1 and y0 < y1, got {box}")
    score = item["score"]
    if not _number(score) or not 0 <= score <= 1:
        raise ActionParseError(f"{where}.score must be a number in [0, 1], got {score!r}")
    caption = item["caption"]
    if not isinstance(caption, str) or len(caption) > MAX_CAPTION_CHARS:
        raise ActionParseError(
            f"{where}.caption must be a string of at most {MAX_CAPTION_CHARS} characters"
        )
    return Landmark(label.strip(), (x0, y0, x1, y1), float(score), caption.strip())


def parse_landmarks(text: str, phrases: Sequence[str] = ()) -> list[Landmark]:
    """The model's landmarks; :class:`ActionParseError` says what is wrong with an answer."""
    data = load_json_object(text)
    if set(data) != {"landmarks"}:
        raise ActionParseError("the answer must be an object with exactly one field, landmarks")
    items = data["landmarks"]
    if not isinstance(items, list) or len(items) > MAX_LANDMARKS:
        raise ActionParseError(f"'landmarks' must be a list of at most {MAX_LANDMARKS} items")
    return [_landmark(item, f"landmarks[{i}]", phrases) for i, item in enumerate(items)]


def to_detections(landmarks: Sequence[Landmark], width: int, height: int) -> list[Detection]:
    """Landmarks in 0-1000 coordinates as detections in pixels of a ``width`` x ``height``
    image (the caption is the label when the model gave none)."""
    out = []
    for mark in landmarks:
        x0, y0, x1, y1 = mark.box
        scaled = (
            x0 * width / BOX_SCALE,
            y0 * height / BOX_SCALE,
            x1 * width / BOX_SCALE,
            y1 * height / BOX_SCALE,
        )
        box = clip_box(scaled, width, height)
        if box is not None:
            out.append(Detection(mark.label, box, mark.score, mark.caption or mark.label))
    return out


def detection_prompt(phrases: Sequence[str]) -> str:
    """What the model is asked about one image."""
    if phrases:
        wanted = "\n".join(f"- {p}" for p in phrases)
        ask = (
            f"Find these landmarks in the image:\n{wanted}\n"
            "A phrase may match several objects or none. Copy the phrase exactly as the label."
        )
    else:
        ask = (
            "Find the landmarks in the image a drone pilot could navigate by (notable "
            "buildings, parks, bridges, fields, car parks). Label each with a short noun phrase."
        )
    return (
        f"{ask}\nFor each landmark you can see, give: label; box [x0, y0, x1, y1] in "
        f"coordinates from 0 to {BOX_SCALE} of the image's width and height ((0, 0) is the "
        "top-left corner, x grows to the right and y downwards, x0 < x1, y0 < y1); score, "
        "your confidence from 0 to 1; caption, a short description of what you see (its "
        "colour, its roof). Report nothing you cannot see: an empty list is a fine answer.\n"
        'Answer as {"landmarks": [{"label": ..., "box": [x0, y0, x1, y1], "score": ..., '
        '"caption": ...}]}.'
    )


class VlmDetector(Detector):
    """Landmarks and boxes from a vision-language model that is sent each capture."""

    name = "vlm"
    requires = frozenset({"rgb"})

    def __init__(self, llm: LLMConfig, client: LLMClient | None = None) -> None:
        self.llm = llm
        self.client = client or build_client(llm)
        if not self.client.backend.takes_images:
            raise ConfigError(
                f"detector 'vlm' sends the camera image to its model, but backend "
                f"{llm.backend!r} does not take images: use an openai:<model> backend of a "
                "vision-language model with takes_images: true in the detector's llm"
            )
        self._calls = DetectorCalls()

    def llm_clients(self) -> tuple[LLMClient, ...]:
        return (self.client,)

    def settings(self) -> dict[str, Any]:
        return {
            **super().settings(),
            "backend": self.client.backend.label,
            "image_max_side_px": self.llm.image_max_side_px,
            "box_coordinates": f"0-{BOX_SCALE} of the image's width and height",
        }

    def reset(self, seed: int) -> None:
        self._calls = DetectorCalls()

    def take_calls(self) -> DetectorCalls:
        """The records, exchanges and failures of the calls made since the last take."""
        calls, self._calls = self._calls, DetectorCalls()
        return calls

    def detect(self, images: CameraImages, phrases: Sequence[str] = ()) -> list[Detection]:
        wanted = list(dict.fromkeys(p.strip() for p in phrases if p.strip()))
        pose = images.pose
        heading = enu_yaw_to_compass_deg(pose.yaw_rad)
        label = f"capture (facing {heading:.0f} deg, {pose.pitch_deg:.0f} deg down)"
        image = jpeg_image(images.rgb, self.llm.image_max_side_px, label)
        if image is None:
            return []
        messages = [
            Message("system", SYSTEM_PROMPT),
            Message("user", detection_prompt(wanted), (image,)),
        ]
        config = self.llm.generation(
            MODULE, json_schema=landmarks_schema(wanted), schema_name="landmarks"
        )
        call = call_json(
            self.client,
            MODULE,
            messages,
            config,
            lambda text: parse_landmarks(text, wanted),
            self.llm.repair_policy(),
        )
        self._calls.records += call.records
        self._calls.exchanges += call.exchanges
        failure = call.failure(MODULE, "no detections in this view")
        if failure is not None or call.value is None:
            self._calls.failures += [failure] if failure is not None else []
            return []
        width, height = images.size_px
        return to_detections(call.value, width, height)
