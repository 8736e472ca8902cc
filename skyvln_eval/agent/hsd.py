"""HSD, the high-resolution spatial descriptor, and its coarse ablation.

Each view is split into 3 x 3 sectors, ``#0`` upper-left to ``#8`` lower-right. A
landmark is described by its view, sector, estimated distance, compass bearing and size.
For each landmark phrase of the instruction the top-K candidate sightings are proposed by
a phrase-detection similarity (the paper's score matrix); the LLM writes a description of
each (phrase, candidate) pair (module ``hsd_describe``), then ranks the candidates from
those descriptions (module ``hsd_rank``). With TrackBack memory on, HSD asks it about the
candidates and passes its notes to the ranking: they settle ties between candidates that
describe equally well (``ambiguous``) and keep a rejected landmark from being chosen again.

With HSD off, the descriptor is the paper's rudimentary one: the view and left / centre /
right only, no distance, no sector, no candidate ranking.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any, Final, Literal, TypeVar

from skyvln_eval.agent.calls import JsonCall, call_json
from skyvln_eval.agent.images import jpeg_image
from skyvln_eval.agent.parsing import load_json_object, refuse_other_fields
from skyvln_eval.agent.perception import Panorama, Sighting
from skyvln_eval.agent.subgoals import SubGoal
from skyvln_eval.errors import ActionParseError
from skyvln_eval.llm.client import LLMClient
from skyvln_eval.llm.config import LLMConfig
from skyvln_eval.llm.taskdata import task_message
from skyvln_eval.llm.types import ImagePart, Message
from skyvln_eval.llm_records import LlmCall, ModuleFailure
from skyvln_eval.vocabulary import text_similarity

SECTOR_NAMES: Final = (
    "upper-left",
    "upper-centre",
    "upper-right",
    "middle-left",
    "centre",
    "middle-right",
    "lower-left",
    "lower-centre",
    "lower-right",
)
MATCH_LEVELS: Final = ("strong", "partial", "weak", "none")
#: The last level at which a candidate fits the phrase: ties below it are not ambiguity.
_LAST_FITTING_LEVEL: Final = MATCH_LEVELS.index("partial")
Match = Literal["strong", "partial", "weak", "none", "unknown"]
_Ranking = tuple[list[str], str | None, float]
T = TypeVar("T")


def sector_of(box_px: tuple[int, int, int, int], image_size_px: tuple[int, int]) -> int:
    """Sector 0-8 (row-major from the upper left) of a box's centre; size is (width, height)."""
    x0, y0, x1, y1 = box_px
    width, height = image_size_px
    col = min(2, max(0, int(3 * ((x0 + x1) / 2.0) / width)))
    row = min(2, max(0, int(3 * ((y0 + y1) / 2.0) / height)))
    return 3 * row + col


def coarse_position(box_px: tuple[int, int, int, int], image_size_px: tuple[int, int]) -> str:
    """``left``, ``centre`` or ``right``: the column of the box's centre only."""
    return ("left", "centre", "right")[sector_of(box_px, image_size_px) % 3]


def relative_bearing_deg(bearing_deg: float, heading_deg: float) -> float:
    """Bearing relative to the heading, in (-180, 180] (positive = to the right)."""
    return 180.0 - (180.0 - (bearing_deg - heading_deg)) % 360.0


def fine_entry(s: Sighting, heading_deg: float) -> dict[str, Any]:
    """A sighting as HSD gives it to the LLM: its numbers as the prose says them (whole
    metres and degrees, the score to two places), so that task data is no more precise
    than what a model reads."""
    sector = sector_of(s.box_px, s.image_size_px)
    return {
        "id": s.landmark_id,
        "label": s.label,
        "caption": s.caption,
        "view": s.view_name,
        "view_heading_deg": s.view_heading_deg,
        "sector": sector,
        "sector_name": SECTOR_NAMES[sector],
        "distance_m": round(s.distance_m),
        "bearing_deg": round(s.bearing_deg),
        "relative_bearing_deg": round(relative_bearing_deg(s.bearing_deg, heading_deg)),
        "size_m": round(s.size_m),
        "clipped": s.clipped,
        "score": round(s.score, 2),
    }


def coarse_entry(s: Sighting) -> dict[str, Any]:
    """A sighting as the coarse descriptor (HSD off) gives it: view and left/centre/right.
    The detector's caption stays: it is perception's, not HSD's (the NavGPT-style
    baseline gets it too), so w/o HSD takes away the spatial description alone."""
    return {
        "id": s.landmark_id,
        "label": s.label,
        "caption": s.caption,
        "view": s.view_name,
        "position": coarse_position(s.box_px, s.image_size_px),
        "score": round(s.score, 2),
    }


def fine_text(e: Mapping[str, Any]) -> str:
    return (
        f"{e['id']} {e['label']} ({e['caption']}): view {e['view']} "
        f"(facing {e['view_heading_deg']:.0f} deg), "
        f"sector #{e['sector']} {e['sector_name']}, about {e['distance_m']:.0f} m away at bearing "
        f"{e['bearing_deg']:.0f} deg ({e['relative_bearing_deg']:+.0f} deg from your heading), "
        f"about {e['size_m']:.0f} m across"
        + (", partly outside the view" if e["clipped"] else "")
        + f", detection score {e['score']:.2f}"
    )


def _goal_text(goal: SubGoal) -> str:
    """``stop_at, landmark 'the red tower', distance_m 120``: the sub-goal's fields."""
    fields = goal.to_dict()
    kind = fields.pop("kind")
    return ", ".join([kind, *(f"{key} {value!r}" for key, value in fields.items())])


def _route_text(hint: Mapping[str, Any]) -> str:
    """The commander's direction and the distance still to fly, as far as known."""
    parts = []
    if hint.get("direction_deg") is not None:
        parts.append(f"the route heads {hint['direction_deg']:.0f} deg")
    if hint.get("remaining_m") is not None:
        parts.append(f"about {hint['remaining_m']:.0f} m of it to fly")
    return f" Route: {', '.join(parts)}." if parts else ""


def _position_text(candidate: Mapping[str, Any]) -> str:
    """Where a candidate the model described is (its own description need not say)."""
    distance, bearing = candidate["distance_m"], candidate["bearing_deg"]
    return f" [about {distance:.0f} m away at bearing {bearing:.0f} deg]"


def coarse_text(e: Mapping[str, Any]) -> str:
    return (
        f"{e['id']} {e['label']} ({e['caption']}): view {e['view']}, {e['position']}, "
        f"score {e['score']:.2f}"
    )


def matches_text(matches: Sequence[PhraseMatch]) -> str:
    """HSD's ranking of the candidates for each landmark phrase, for the motion prompt."""
    lines = ["Candidates for the instruction's landmarks (HSD):"]
    for m in matches:
        notes = [f"ranked {', '.join(c.entry['id'] for c in m.candidates) or 'none'}"]
        notes += ["memory consulted"] if m.asked_memory else []
        notes += ["ambiguous"] if m.ambiguous else []
        best = m.best or "none fits"
        lines.append(
            f"- {m.phrase!r}: best {best} (confidence {m.confidence:.2f}; {'; '.join(notes)})"
        )
    return "\n".join(lines)


@dataclass(frozen=True)
class Candidate:
    """One candidate for a phrase: its HSD entry, proposal similarity, LLM description."""

    entry: dict[str, Any]
    similarity: float
    description: str = ""
    match: Match = "unknown"
    memory_note: str | None = None


@dataclass(frozen=True)
class PhraseMatch:
    """The ranked candidates for one landmark phrase and the chosen one (``best``, or None)."""

    phrase: str
    goal: dict[str, Any]
    candidates: tuple[Candidate, ...]
    best: str | None
    confidence: float
    asked_memory: bool = False
    ambiguous: bool = False
    error: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "best": self.best,
            "confidence": round(self.confidence, 3),
            "ranking": [c.entry["id"] for c in self.candidates],
            "asked_memory": self.asked_memory,
            "ambiguous": self.ambiguous,
        }


@dataclass
class HsdResult:
    matches: list[PhraseMatch] = field(default_factory=list)
    records: list[LlmCall] = field(default_factory=list)
    exchanges: list[dict[str, Any]] = field(default_factory=list)
    failures: list[ModuleFailure] = field(default_factory=list)


MAX_DESCRIPTION_CHARS: Final = 2000
#: Answer schemas; the parsers below accept exactly what they allow.
DESCRIPTION_SCHEMA: Final[dict[str, Any]] = {
    "type": "object",
    "properties": {
        "description": {"type": "string", "maxLength": 400},
        "match": {"type": "string", "enum": list(MATCH_LEVELS)},
    },
    "required": ["description", "match"],
    "additionalProperties": False,
}


def rank_schema(ids: Sequence[str]) -> dict[str, Any]:
    """The ranking answer's schema for one call's candidates: ids only from ``ids`` (an
    enum, which grammar-constrained decoders enforce), as :func:`_rank_parser` checks."""
    candidate = {"type": "string", "enum": list(ids)}
    return {
        "type": "object",
        "properties": {
            "ranking": {"type": "array", "items": candidate, "maxItems": len(ids)},
            "best": {"anyOf": [candidate, {"type": "null"}]},
            "confidence": {"type": "number", "minimum": 0, "maximum": 1},
        },
        "required": ["ranking", "best", "confidence"],
        "additionalProperties": False,
    }


def _parse_description(text: str) -> tuple[str, Match]:
    data = load_json_object(text)
    refuse_other_fields(data, ("description", "match"))
    description, match = data.get("description"), data.get("match")
    if not isinstance(description, str) or len(description) > MAX_DESCRIPTION_CHARS:
        raise ActionParseError(
            f"'description' must be a string of at most {MAX_DESCRIPTION_CHARS} characters"
        )
    if match not in MATCH_LEVELS:
        raise ActionParseError(f"'match' must be one of {', '.join(MATCH_LEVELS)}")
    return description, match


def _rank_parser(ids: Sequence[str]) -> Callable[[str], tuple[list[str], str | None, float]]:
    def parse(text: str) -> tuple[list[str], str | None, float]:
        data = load_json_object(text)
        refuse_other_fields(data, ("ranking", "best", "confidence"))
        ranking, best, confidence = data.get("ranking"), data.get("best"), data.get("confidence")
        if (
            not isinstance(ranking, list)
            or any(r not in ids for r in ranking)
            or len(set(ranking)) != len(ranking)
        ):
            raise ActionParseError(
                f"'ranking' must list distinct candidate ids among {', '.join(ids)}"
            )
        if best is not None and best not in ids:
            raise ActionParseError(f"'best' must be a candidate id or null, got {best!r}")
        if (
            isinstance(confidence, bool)
            or not isinstance(confidence, int | float)
            or not 0 <= confidence <= 1
        ):
            raise ActionParseError("'confidence' must be a number in [0, 1]")
        return ranking, best, float(confidence)

    return parse


def _crop(panorama: Panorama, s: Sighting, max_side_px: int) -> tuple[ImagePart, ...]:
    """The sighting's box (and a margin) as a JPEG no larger than ``max_side_px``, as
    every image the agent sends is (none if it cannot be encoded)."""
    view = panorama.views[s.view_index]
    x0, y0, x1, y1 = s.box_px
    pad = 8
    crop = view.images.rgb[max(0, y0 - pad) : y1 + pad, max(0, x0 - pad) : x1 + pad]
    part = jpeg_image(crop, max_side_px, f"{s.landmark_id} in view {view.name}")
    return () if part is None else (part,)


class SpatialDescriptor:
    """HSD (``enabled``) or the coarse descriptor; see the module docstring."""

    def __init__(
        self,
        client: LLMClient,
        llm: LLMConfig,
        enabled: bool = True,
        top_k: int = 3,
    ) -> None:
        self.client = client
        self.describe_config = llm.generation(
            "hsd_describe", json_schema=DESCRIPTION_SCHEMA, schema_name="description"
        )
        self.rank_config = llm.generation("hsd_rank", schema_name="rank")  # schema per call
        self.repair = llm.repair_policy()
        self.image_max_side_px = llm.image_max_side_px
        self.enabled = enabled
        self.top_k = top_k

    def entries(self, panorama: Panorama, heading_deg: float) -> list[dict[str, Any]]:
        if self.enabled:
            return [fine_entry(s, heading_deg) for s in panorama.sightings]
        return [coarse_entry(s) for s in panorama.sightings]

    def text(self, entries: Sequence[Mapping[str, Any]]) -> str:
        if not entries:
            return "No landmark detected around you."
        render = fine_text if self.enabled else coarse_text
        return "\n".join(f"- {render(e)}" for e in entries)

    def propose(self, phrase: str, panorama: Panorama, heading_deg: float) -> list[Candidate]:
        """Top-K sightings for a phrase by text similarity times detection score."""
        scored = []
        for s in panorama.sightings:
            similarity = text_similarity(phrase, s.label, s.caption) * (0.5 + 0.5 * s.score)
            if similarity > 0.0:
                scored.append(Candidate(fine_entry(s, heading_deg), round(similarity, 3)))
        scored.sort(key=lambda c: (-c.similarity, c.entry["id"]))
        return scored[: self.top_k]

    def match(
        self,
        goals: Sequence[SubGoal],
        panorama: Panorama,
        heading_deg: float,
        memory_notes: Callable[[Sequence[str], str], dict[str, str]] | None,
        route_hint: Mapping[str, Any] | None = None,
    ) -> HsdResult:
        """Rank candidates for each goal's landmark phrase (HSD on only).

        ``route_hint`` (``direction_deg``, ``remaining_m``) is the commander's heading and
        the distance still to fly, which the ranking may weigh.

        Every (phrase, candidate) description is independent of the others, and each
        phrase's ranking of the other phrases': the descriptions of all phrases are asked
        for at once, then all rankings at once (up to the client's concurrency limit), so
        a decision waits for two answers however many phrases are pending. Records keep
        the order of one phrase after another.
        """
        result = HsdResult()
        if not self.enabled:
            return result
        by_id = panorama.by_id()
        goals = [g for g in goals if g.landmark is not None]
        proposals = [self.propose(g.landmark or "", panorama, heading_deg) for g in goals]
        pairs = [(goal, c) for goal, cs in zip(goals, proposals, strict=True) for c in cs]
        descriptions = iter(
            self._at_once(lambda pair: self._describe(pair[0], pair[1], panorama, by_id), pairs)
        )
        per_goal: list[tuple[list[Candidate], list[JsonCall[tuple[str, Match]]]]] = []
        for candidates in proposals:
            calls = [next(descriptions) for _ in candidates]
            described = []
            for candidate, call in zip(candidates, calls, strict=True):
                if call.value is None:
                    described.append(candidate)
                else:
                    text, level = call.value
                    described.append(Candidate(candidate.entry, candidate.similarity, text, level))
            per_goal.append((described, calls))
        # Memory is asked in this thread, in goal order; only the model calls run at once.
        prepared = [
            self._rank_request(goal, described, heading_deg, memory_notes, route_hint)
            for goal, (described, _) in zip(goals, per_goal, strict=True)
        ]
        ranks = self._at_once(self._ranked, prepared)
        for (_, calls), (phrase_match, rank_call) in zip(per_goal, ranks, strict=True):
            for call in calls:
                result.records += call.records
                result.exchanges += call.exchanges
                failure = call.failure("hsd_describe", "ranked without a description")
                result.failures += [failure] if failure is not None else []
            if rank_call is not None:
                result.records += rank_call.records
                result.exchanges += rank_call.exchanges
                failure = rank_call.failure("hsd_rank", "proposal order")
                result.failures += [failure] if failure is not None else []
            result.matches.append(phrase_match)
        return result

    def _at_once(self, fn: Callable[[Any], T], items: Sequence[Any]) -> list[T]:
        """``fn`` of each item, in threads up to the client's concurrency limit; in order
        (one after another for a backend that answers in this process)."""
        if len(items) <= 1 or self.client.backend.answers_in_process:
            return [fn(item) for item in items]
        workers = min(self.client.max_concurrency, len(items))
        with ThreadPoolExecutor(max_workers=workers) as pool:
            return list(pool.map(fn, items))

    def _describe(
        self,
        goal: SubGoal,
        c: Candidate,
        panorama: Panorama,
        by_id: dict[str, Sighting],
    ) -> JsonCall[tuple[str, Match]]:
        data = {"phrase": goal.landmark, "goal": goal.to_dict(), "candidate": c.entry}
        prose = (
            f"Landmark phrase from the instruction: {goal.landmark!r}.\n"
            "Candidate seen by the drone: "
            f"{fine_text(c.entry)}.\nDescribe how this candidate compares with the phrase (kind of "
            "place, colours, shape, size, where it is) and say how well it matches. Answer as "
            '{"description": "...", "match": "strong" | "partial" | "weak" | "none"}.\n'
        )
        images = (
            _crop(panorama, by_id[c.entry["id"]], self.image_max_side_px)
            if self.client.backend.takes_images
            else ()
        )
        messages = [
            Message("system", HSD_SYSTEM),
            task_message(prose, "hsd_describe", data, images),
        ]
        return call_json(
            self.client,
            "hsd_describe",
            messages,
            self.describe_config,
            _parse_description,
            self.repair,
        )

    def _rank_request(
        self,
        goal: SubGoal,
        candidates: list[Candidate],
        heading_deg: float,
        memory_notes: Callable[[Sequence[str], str], dict[str, str]] | None,
        route_hint: Mapping[str, Any] | None,
    ) -> _RankRequest:
        """The ranking request for one phrase, with what the memory knows of its candidates."""
        phrase = goal.landmark or ""
        if not candidates:
            return _RankRequest(goal, phrase, (), False, False, ())
        unknown = len(MATCH_LEVELS)  # a candidate whose description failed
        levels = [
            MATCH_LEVELS.index(c.match) if c.match in MATCH_LEVELS else unknown for c in candidates
        ]
        # Two candidates described as matching equally well, and well (strong or partial):
        # two that hardly fit, or failed descriptions, are no tie to ask the commander about.
        best_level = min(levels)
        ambiguous = best_level <= _LAST_FITTING_LEVEL and levels.count(best_level) > 1
        asked = memory_notes is not None
        if memory_notes is not None:
            # What the memory knows (rejected, already used, from an earlier round) settles
            # ties and keeps known mistakes from being made twice.
            notes = memory_notes([c.entry["id"] for c in candidates], phrase)
            candidates = [
                Candidate(c.entry, c.similarity, c.description, c.match, notes.get(c.entry["id"]))
                for c in candidates
            ]
        listed = [
            {
                "id": c.entry["id"],
                "description": c.description or fine_text(c.entry),
                "match": c.match,
                "distance_m": c.entry["distance_m"],
                "bearing_deg": c.entry["bearing_deg"],
                "memory_note": c.memory_note,
            }
            for c in candidates
        ]
        data = {
            "phrase": phrase,
            "goal": goal.to_dict(),
            "heading_deg": round(heading_deg, 1),
            "route_hint": dict(route_hint or {}),
            "candidates": listed,
        }
        # Every value of the task data is in the prose too: a stand-in that reads the data
        # knows nothing the model is not told.
        prose = (
            f"Landmark phrase: {phrase!r} (sub-goal {_goal_text(goal)}). "
            f"Your heading: {data['heading_deg']:.1f} deg.{_route_text(route_hint or {})} "
            "Candidates and their descriptions:\n"
            + "\n".join(
                f"- {x['id']}: {x['description']} [match: {x['match']}]"
                # A candidate not described (its call failed) is given by fine_text, which
                # says where it is already.
                + (_position_text(x) if c.description else "")
                + (f" [memory: {x['memory_note']}]" if x["memory_note"] else "")
                for c, x in zip(candidates, listed, strict=True)
            )
            + "\nRank the candidates from most to least likely to be the landmark of the phrase, "
            "taking the sub-goal's direction and distance into account. Answer as "
            '{"ranking": [ids], "best": id or null if none fits, "confidence": 0..1}.\n'
        )
        messages = (Message("system", HSD_SYSTEM), task_message(prose, "hsd_rank", data))
        return _RankRequest(goal, phrase, tuple(candidates), asked, ambiguous, messages)

    def _ranked(self, request: _RankRequest) -> tuple[PhraseMatch, JsonCall[_Ranking] | None]:
        """The phrase's match from the model's ranking (the proposal order when it gave
        none), and the call (None for a phrase without candidates)."""
        goal, phrase, candidates = request.goal.to_dict(), request.phrase, request.candidates
        if not candidates:
            return PhraseMatch(phrase, goal, (), None, 0.0), None
        ids = [c.entry["id"] for c in candidates]
        call = call_json(
            self.client,
            "hsd_rank",
            request.messages,
            replace(self.rank_config, json_schema=rank_schema(ids)),
            _rank_parser(ids),
            self.repair,
        )
        asked, ambiguous = request.asked_memory, request.ambiguous
        if call.value is None:  # fall back to the proposal order
            best = candidates[0].entry["id"] if candidates[0].similarity >= 0.5 else None
            match = PhraseMatch(
                phrase,
                goal,
                candidates,
                best,
                candidates[0].similarity,
                asked,
                ambiguous,
                call.error,
            )
            return match, call
        ranking, best, confidence = call.value
        order = {cid: i for i, cid in enumerate(ranking)}
        ranked = sorted(candidates, key=lambda c: order.get(c.entry["id"], len(order)))
        return PhraseMatch(phrase, goal, tuple(ranked), best, confidence, asked, ambiguous), call


@dataclass(frozen=True)
class _RankRequest:
    """One phrase's ranking, ready to send: its candidates (with memory notes) and prompt."""

    goal: SubGoal
    phrase: str
    candidates: tuple[Candidate, ...]
    asked_memory: bool
    ambiguous: bool
    messages: tuple[Message, ...]


HSD_SYSTEM: Final = (
    "You help a drone match landmark phrases from a navigation instruction with landmarks "
    "its camera detected. Views are split into 3 x 3 sectors, #0 upper-left to #8 "
    "lower-right. You answer with one JSON object only."
)
