"""The rule backend's HSD answers: describe a (phrase, candidate) pair, rank candidates.

The description compares kind of place, colours and other attribute words, and says
where the candidate is; the ranking orders by match level, then by agreement with the
route (direction and distance the commander gave), and demotes candidates the memory
says were already reached or rejected.
"""

from __future__ import annotations

from typing import Any

from skyvln_eval.vocabulary import colours_in, compass_word, content_words, landmark_kind

LEVEL_SCORE = {"strong": 3.0, "partial": 2.0, "weak": 1.0, "none": 0.0, "unknown": 1.0}


def compare(phrase: str, label: str, caption: str) -> tuple[str, list[str]]:
    """Match level of a candidate for a phrase, and the reasons."""
    reasons = []
    # A generic kind ("the grey building") is the same kind only as the same generic word,
    # and never more than a partial match: it says less than a category.
    wanted_kind, seen_kind = landmark_kind(phrase), landmark_kind(f"{label} {caption}")
    same_kind = wanted_kind is not None and wanted_kind == seen_kind
    generic = wanted_kind is not None and not wanted_kind[1]
    reasons.append(
        f"same kind of place ({label})" if same_kind else f"a {label}, not the kind named"
    )
    wanted_colours, seen_colours = colours_in(phrase), colours_in(caption)
    colour_clash = bool(wanted_colours and seen_colours and not wanted_colours & seen_colours)
    if wanted_colours and seen_colours:
        agree = wanted_colours & seen_colours
        reasons.append(
            f"colour agrees ({', '.join(sorted(agree))})"
            if agree
            else f"colour differs ({', '.join(sorted(seen_colours))})"
        )
    attributes = content_words(phrase) - content_words(label) - wanted_colours
    overlap = len(attributes & content_words(caption)) / len(attributes) if attributes else 1.0
    if attributes:
        reasons.append(f"{overlap:.0%} of the other details agree")
    if same_kind and not colour_clash and overlap >= 0.5 and not generic:
        level = "strong"
    elif same_kind and not colour_clash:
        level = "partial"
    elif same_kind or overlap >= 0.5:
        level = "weak"
    else:
        level = "none"
    return level, reasons


def describe(data: dict[str, Any]) -> dict[str, Any]:
    phrase, candidate = str(data["phrase"]), data["candidate"]
    level, reasons = compare(phrase, candidate["label"], candidate.get("caption", ""))
    where = (
        f"{candidate['distance_m']:.0f} m to the {compass_word(candidate['bearing_deg'])}, "
        f"sector #{candidate['sector']} of the {candidate['view']} view"
    )
    text = (
        f"{candidate['id']} looks like {candidate.get('caption') or candidate['label']}, {where}: "
        + "; ".join(reasons)
    )
    return {"description": text, "match": level}


def _route_penalty(candidate: dict[str, Any], hint: dict[str, Any]) -> float:
    """How badly a candidate disagrees with the route's direction and distance (0 = not at all)."""
    penalty = 0.0
    direction = hint.get("direction_deg")
    if direction is not None:
        off = abs((candidate["bearing_deg"] - direction + 180.0) % 360.0 - 180.0)
        penalty += 0.8 if off > 100.0 else 0.0
    distance = hint.get("remaining_m")
    if distance is not None and distance > 0:
        penalty += min(1.0, abs(candidate["distance_m"] - distance) / max(distance, 50.0)) * 0.6
    return penalty


def rank(data: dict[str, Any]) -> dict[str, Any]:
    hint = data.get("route_hint") or {}
    scored = []
    for c in data.get("candidates", []):
        score = LEVEL_SCORE.get(str(c.get("match")), 1.0) - _route_penalty(c, hint)
        note = c.get("memory_note") or ""
        if "already reached" in note or "already used" in note or "rejected" in note:
            score -= 3.0
        elif "confirmed" in note:
            score += 0.5
        scored.append((score, c["id"]))
    scored.sort(key=lambda item: (-item[0], item[1]))
    ranking = [cid for _, cid in scored]
    if not scored or scored[0][0] < 1.5:
        return {"ranking": ranking, "best": None, "confidence": 0.1}
    margin = scored[0][0] - (scored[1][0] if len(scored) > 1 else 0.0)
    confidence = min(0.95, 0.35 + 0.15 * scored[0][0] + 0.2 * min(margin, 1.0))
    return {"ranking": ranking, "best": ranking[0], "confidence": round(confidence, 3)}
