"""Parse and validate AVDN records, reporting every problem with file, record and field.

Validation is split in two passes so that a whole AVDN-sized split validates in a small
multiple of ``json.load``: a per-record pass checks keys, types and values (numbers a
float holds, text and unknown keys that strict JSON can write) and turns corner lists
into arrays; a vectorised pass checks the geometry of every view of the split at once
(finite, square, corner order, inside the map) and of every destination (on the globe,
centre on the map). The slow, precise walk over nested lists runs only for the rare
record whose corners fail the fast checks.
"""

from __future__ import annotations

import difflib
import math
import re
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.avdn.constants import MAX_MAP_SIDE_PX, METERS_PER_DEGREE
from skyvln_eval.avdn.geometry import view_heading_deg
from skyvln_eval.avdn.json_values import (
    locate_bad_number,
    number_problem,
    shown,
    text_ok,
    type_name,
    unwritable,
)
from skyvln_eval.avdn.records import (
    RECORD_KEYS,
    REQUIRED_KEYS,
    AttentionCircle,
    AvdnRecord,
    episode_id_of,
)
from skyvln_eval.errors import ValidationIssue

#: A view whose sides or diagonals differ from a square's by more than this (relative) is
#: rejected. Real AVDN views deviate by up to about 1%.
SQUARE_TOLERANCE = 0.05
#: A view with an edge shorter than this is degenerate, metres.
MIN_EDGE_M = 1.0

_MAP_NAME = re.compile(r"[0-9A-Za-z_-]+")
#: Plain decimal, ASCII digits, no leading zeros: "6_2" and "6_02" (or "٦_٢") would be
#: different ids of one round, which a trajectory would hold twice.
_ROUTE_INDEX = re.compile(r"(0|[1-9][0-9]*)_([1-9][0-9]*)")
#: Files are named after the episode id (``<id>.mcap``, ``.<id>.mcap.XXXXXXXX.tmp`` while
#: written, ``<id>.parquet``); 200 ASCII characters keep every such name within the
#: 255 bytes a file system allows. Real ids are about 10.
MAX_EPISODE_ID_CHARS = 200


def is_episode_id(text: str) -> bool:
    """Whether ``text`` is an id a valid record has: ``<map_name>__<route_index>``."""
    map_name, sep, route = text.rpartition("__")
    return (
        bool(sep)
        and len(text) <= MAX_EPISODE_ID_CHARS
        and _MAP_NAME.fullmatch(map_name) is not None
        and _ROUTE_INDEX.fullmatch(route) is not None
    )


@dataclass
class _Pending:
    """A record that passed the per-record checks, waiting for the geometry pass."""

    index: int
    raw: dict[str, Any]
    corners: NDArray[np.float64]
    destination: NDArray[np.float64] | None
    attention: tuple[AttentionCircle, ...]


def record_place(raw: Any) -> tuple[str | None, str | None, int | None]:
    """(map_name, trajectory index, round) a record names, each None when unreadable.

    For records that fail validation: an ANDH-Full trajectory must know which of its
    rounds were left out, even when the record is otherwise unusable.
    """
    if not isinstance(raw, dict):
        return None, None, None
    map_name, route = raw.get("map_name"), raw.get("route_index")
    place_map = map_name if isinstance(map_name, str) and _MAP_NAME.fullmatch(map_name) else None
    match = _ROUTE_INDEX.fullmatch(route) if isinstance(route, str) else None
    if match is None:
        return place_map, None, None
    return place_map, match.group(1), int(match.group(2))


def _corner_array(
    value: Any, name: str, expected_tail: tuple[int, ...], report: Any
) -> NDArray[np.float64] | None:
    """Nested list of numbers -> float array with trailing shape ``expected_tail``."""
    depth = len(expected_tail) + (1 if name == "gt_path_corners" else 0)
    try:
        # Without a dtype, numpy keeps strings as strings and null as object, so only
        # nested lists of JSON numbers come out as float or int arrays.
        arr = np.array(value)
    except (ValueError, TypeError):
        arr = None
    good_shape = (
        arr is not None
        and arr.ndim == depth
        and arr.shape[arr.ndim - len(expected_tail) :] == expected_tail
    )
    if arr is not None and good_shape and arr.dtype.kind in "fi":
        floats = arr.astype(np.float64, copy=False)
        # numpy turns JSON true/false among numbers into 1/0: an exact 0 or 1 sends the
        # list to the walk below, which tells a boolean from a number.
        if np.isfinite(floats).all() and not ((floats == 0.0) | (floats == 1.0)).any():
            return floats
    located = locate_bad_number(value, name, depth)
    if located is not None:
        report(located[0], located[1])
    elif arr is not None and good_shape:
        # Every element is a finite number a float holds, but numpy kept an integer beyond
        # int64 as a Python int (object or uint64 array).
        return arr.astype(np.float64)
    elif isinstance(value, list) and name == "gt_path_corners" and not value:
        report(name, "empty gt_path_corners: at least the start view is required")
    else:
        if name == "gt_path_corners" and isinstance(value, list):  # a list of views
            views = [(view, f"{name}[{i}]") for i, view in enumerate(value)]
        else:  # one view
            views = [(value, name)]
        for view, path in views:
            misshapen = _misshapen_view(view, path)
            if misshapen is not None:
                report(*misshapen)
                break
        else:  # not reached: a list of 4x2 number lists has that shape
            report(name, "expected views of 4 [lat, lng] corners")
    return None


def _misshapen_view(view: Any, path: str) -> tuple[str, str] | None:
    """(path, problem) of the first part of a view that is not 4 corners of [lat, lng]."""
    if not isinstance(view, list) or len(view) != 4:
        return path, f"expected a view of 4 [lat, lng] corners, got {_list_or_value(view)}"
    for j, corner in enumerate(view):
        if not isinstance(corner, list) or len(corner) != 2:
            return f"{path}[{j}]", f"expected a corner [lat, lng], got {_list_or_value(corner)}"
    return None


def _list_or_value(value: Any) -> str:
    return f"a list of {len(value)}" if isinstance(value, list) else shown(value)


def _check_latlng(value: Any, name: str, report: Any) -> bool:
    if not (isinstance(value, list) and len(value) == 2):
        report(name, f"expected [lat, lng], got {shown(value)}")
        return False
    for i, v in enumerate(value):
        problem = number_problem(v, "coordinate")
        if problem is not None:
            report(f"{name}[{i}]", problem)
            return False
    if not (-90.0 <= value[0] <= 90.0 and -180.0 <= value[1] <= 180.0):
        report(name, f"not a valid [lat, lng]: {value!r}")
        return False
    return True


def _check_scalars(raw: dict[str, Any], report: Any) -> bool:
    ok = True
    map_name = raw["map_name"]
    if not isinstance(map_name, str):
        report("map_name", f"expected a string, got {shown(map_name)}")
        ok = False
    elif not _MAP_NAME.fullmatch(map_name):
        report("map_name", f"expected an xView id such as '1913', got {map_name!r}")
        ok = False
    route = raw["route_index"]
    if not isinstance(route, str):
        report("route_index", f"expected a string, got {shown(route)}")
        ok = False
    else:
        if not _ROUTE_INDEX.fullmatch(route):
            report(
                "route_index",
                "expected '<trajectory>_<round>' in plain decimal digits without leading "
                f"zeros, round >= 1, got {route!r}",
            )
            ok = False
    if ok and len(episode_id_of(map_name, route)) > MAX_EPISODE_ID_CHARS:
        longer = "route_index" if len(route) >= len(map_name) else "map_name"
        report(
            longer,
            f"the episode id map_name__route_index is {len(map_name) + 2 + len(route)} "
            f"characters long, more than {MAX_EPISODE_ID_CHARS}: files are named after it",
        )
        ok = False
    last = raw.get("last_round_idx")
    if "last_round_idx" in raw and (type(last) is not int or last < 1):
        report("last_round_idx", f"expected an integer >= 1, got {shown(last)}")
        ok = False
    if not isinstance(raw["instructions"], str):
        report("instructions", f"expected a string, got {type_name(raw['instructions'])}")
        ok = False
    pre = raw["pre_dialogs"]
    if not isinstance(pre, list):
        report("pre_dialogs", f"expected a list of strings, got {type_name(pre)}")
        ok = False
    else:
        for i, item in enumerate(pre):
            if not isinstance(item, str):
                report(f"pre_dialogs[{i}]", f"expected a string, got {type_name(item)}")
                ok = False
    texts = [raw["instructions"], *pre] if isinstance(pre, list) else [raw["instructions"]]
    # One check in the usual case; the walk names the field when it fails.
    if not (all(isinstance(x, str) for x in texts) and text_ok("".join(texts))):
        for key in ("instructions", "pre_dialogs"):
            if found := unwritable(raw[key], key):
                report(*found)
                ok = False
    ratios_ok = True
    for key in ("lng_ratio", "lat_ratio", "angle"):
        v = raw[key]
        problem = number_problem(v)
        if problem is not None:
            report(key, problem)
            ok = ratios_ok = False
        elif key != "angle" and v <= 0:
            report(key, f"expected degrees per pixel > 0, got {v!r}")
            ok = ratios_ok = False
    corners_ok = _check_latlng(raw["gps_botm_left"], "gps_botm_left", report)
    corners_ok &= _check_latlng(raw["gps_top_right"], "gps_top_right", report)
    if corners_ok:
        (lat0, lng0), (lat1, lng1) = raw["gps_botm_left"], raw["gps_top_right"]
        if not (lat0 < lat1 and lng0 < lng1):
            report("gps_top_right", "must lie north-east of gps_botm_left")
            corners_ok = False
    if corners_ok and ratios_ok:
        ok &= _check_map_size(raw, report)
    if ok and isinstance(route, str) and type(last) is int and last < int(route.split("_")[1]):
        report("last_round_idx", f"{last} is smaller than the round in route_index {route!r}")
        ok = False
    return ok and corners_ok


def _check_map_size(raw: dict[str, Any], report: Any) -> bool:
    """Whether the map the record describes has a size the toolkit can make.

    The ratios are degrees per original image pixel and the bounds the image's corners
    (AVDN.md), so bounds over ratio are the image's size in pixels, and the longitude span
    over ``lat_ratio`` the width the official resize gives it. Only ``> 0`` was checked:
    1e300 made a 0 px wide resize (an OpenCV traceback) and 1e-12 one of 10^9 px. Whether
    the image has that size is checked where it is decoded (``validate``).
    """
    (lat0, lng0), (lat1, lng1) = raw["gps_botm_left"], raw["gps_top_right"]
    sizes = (
        ("lat_ratio", "image height (latitude span / lat_ratio)", (lat1 - lat0) / raw["lat_ratio"]),
        ("lng_ratio", "image width (longitude span / lng_ratio)", (lng1 - lng0) / raw["lng_ratio"]),
        (
            "lat_ratio",
            "resized map width (longitude span / lat_ratio)",
            (lng1 - lng0) / raw["lat_ratio"],
        ),
    )
    for field, what, size_px in sizes:
        if not 1.0 <= size_px <= MAX_MAP_SIDE_PX:
            report(
                field,
                f"{raw[field]!r} degrees per pixel makes the map's {what} {size_px:.3g} px, "
                f"not 1 to {MAX_MAP_SIDE_PX}: ratios are degrees per image pixel",
            )
            return False
    return True


def _check_attention(value: Any, report: Any) -> tuple[AttentionCircle, ...] | None:
    if not isinstance(value, list):
        report("attention_list", f"expected a list, got {type_name(value)}")
        return None
    circles = []
    for i, item in enumerate(value):
        name = f"attention_list[{i}]"
        if not (isinstance(item, list) and len(item) == 2):
            report(name, f"expected [[lat, lng], radius_px], got {item!r}")
            return None
        if not _check_latlng(item[0], f"{name}[0]", report):
            return None
        radius = item[1]
        problem = number_problem(radius)
        if problem is not None or radius < 0:
            report(f"{name}[1]", problem or f"expected a radius >= 0 in pixels, got {radius!r}")
            return None
        circles.append(AttentionCircle((item[0][0], item[0][1]), radius))
    return tuple(circles)


def _check_record(
    raw: Any, index: int, file: str, issues: list[ValidationIssue]
) -> _Pending | None:
    """Per-record checks; appends issues and returns None when the record is invalid."""
    if not isinstance(raw, dict):
        issues.append(ValidationIssue(file, f"expected a JSON object, got {type_name(raw)}", index))
        return None
    map_name, route = raw.get("map_name"), raw.get("route_index")
    # Only valid text in the id: an issue is printed, and a lone surrogate cannot be.
    episode = episode_id_of(map_name, route) if text_ok(map_name) and text_ok(route) else None
    count = len(issues)

    def report(field: str, message: str) -> None:
        issues.append(ValidationIssue(file, message, index, episode, field))

    for key in getattr(raw, "repeated", ()):  # the loader's RepeatedKeys
        report(key, "key given more than once in the record (JSON keeps the last value)")
    missing = [key for key in REQUIRED_KEYS if key not in raw]
    for key in missing:
        report(key, "missing required key")
    if missing:  # what the checks below read is not there; a repeated key is, as its last value
        return None
    _check_scalars(raw, report)
    for key, value in raw.items():
        # Unknown keys are kept and written out verbatim: they must be strict JSON.
        if key in RECORD_KEYS:
            continue
        if not text_ok(key):
            report(
                ascii(key), "not valid Unicode text: an unknown key's name holds a lone surrogate"
            )
        elif found := unwritable(value, key):
            report(*found)
    corners = _corner_array(raw["gt_path_corners"], "gt_path_corners", (4, 2), report)
    destination = None
    if "destination" in raw and raw["destination"] is None:
        # Optional means absent (the format has no null): said, since the fix is plain.
        report("destination", "expected 4 [lat, lng] corners, got null (leave the key out)")
    elif "destination" in raw:
        destination = _corner_array(raw["destination"], "destination", (4, 2), report)
    attention = _check_attention(raw["attention_list"], report)
    if len(issues) > count or corners is None or attention is None:
        return None
    return _Pending(index, raw, corners, destination, attention)


def _view_shapes(
    views: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_]]:
    """Sides and diagonals (metres) of ``(V, 4, 2)`` views, and which are degenerate (an
    edge under ``MIN_EDGE_M``) or, not degenerate, not square within ``SQUARE_TOLERANCE``."""
    # Predicted corners may be any finite float (1e300): an overflow is a refused view.
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        sides = np.linalg.norm(views - np.roll(views, -1, axis=1), axis=-1) * METERS_PER_DEGREE
        diagonals = np.linalg.norm(views[:, [0, 1]] - views[:, [2, 3]], axis=-1) * METERS_PER_DEGREE
        mean_side = sides.mean(axis=1)
        degenerate = sides.min(axis=1, initial=math.inf) < MIN_EDGE_M
        side_err = np.abs(sides / mean_side[:, None] - 1.0).max(axis=1)
        diag_err = np.abs(diagonals / (mean_side[:, None] * math.sqrt(2.0)) - 1.0).max(axis=1)
    not_square = ~degenerate & ((side_err > SQUARE_TOLERANCE) | (diag_err > SQUARE_TOLERANCE))
    return sides, diagonals, degenerate, not_square


def view_problems(
    views: NDArray[np.float64], bounds: tuple[LatLngPair, LatLngPair] | None = None
) -> list[tuple[int, str]]:
    """(index, problem) of each of ``(V, 4, 2)`` views the annotation checks refuse:
    degenerate, not square, or (with the map's ``bounds``, gps_botm_left and gps_top_right)
    off the map. For views made elsewhere (predictions), judged as the ground truth is."""
    sides, diagonals, degenerate, not_square = _view_shapes(views)
    outside: NDArray[np.bool_] = np.zeros(len(views), dtype=bool)
    if bounds is not None:
        lo, hi = np.asarray(bounds[0], dtype=np.float64), np.asarray(bounds[1], dtype=np.float64)
        outside = np.asarray(((views < lo) | (views > hi)).any(axis=(1, 2)), dtype=bool)
    problems = []
    for k in range(len(views)):
        shown_sides = ", ".join(f"{side:.1f}" for side in sides[k])
        if degenerate[k]:
            problems.append((k, _DEGENERATE.format(min=MIN_EDGE_M, sides=shown_sides)))
        elif not_square[k]:
            diags = ", ".join(f"{d:.1f}" for d in diagonals[k])
            problems.append((k, _NOT_SQUARE.format(sides=shown_sides, diags=diags)))
        elif outside[k]:
            problems.append((k, _OUTSIDE))
    return problems


_DEGENERATE = "degenerate view: an edge is shorter than {min} m (sides {sides} m)"
_NOT_SQUARE = "view is not square (sides {sides} m, diagonals {diags} m)"
_OUTSIDE = "view lies outside the map bounds gps_botm_left..gps_top_right"
LatLngPair = tuple[float, float]


def _check_view_geometry(
    pending: list[_Pending], file: str, issues: list[ValidationIssue]
) -> set[int]:
    """Vectorised geometry checks over every view of every record; returns bad indices."""
    if not pending:
        return set()
    counts = np.array([len(p.corners) for p in pending])
    views = np.concatenate([p.corners for p in pending])  # (V, 4, 2)
    owner = np.repeat(np.arange(len(pending)), counts)
    view_k = np.concatenate([np.arange(n) for n in counts])
    sides, diagonals, degenerate, not_square = _view_shapes(views)
    # FL -> FR -> BR -> BL runs clockwise on a north-up map: negative cross product in
    # (east, north) coordinates.
    a = views[:, 1] - views[:, 0]
    b = views[:, 3] - views[:, 0]
    cross = a[:, 1] * b[:, 0] - a[:, 0] * b[:, 1]
    mirrored = ~degenerate & ~not_square & (cross > 0)
    lo = np.array([p.raw["gps_botm_left"] for p in pending])[owner]
    hi = np.array([p.raw["gps_top_right"] for p in pending])[owner]
    outside = ((views < lo[:, None, :]) | (views > hi[:, None, :])).any(axis=(1, 2))
    # The first view faces the start heading (`angle`), its front edge from corner 0 to 1:
    # corners listed from another corner (the right order, shifted round) pass the checks
    # above but turn every step by a multiple of 90 degrees. A gap of more than 45 degrees
    # is no rounding.
    angles = np.array([float(p.raw["angle"]) for p in pending])[owner]
    facing = np.asarray(view_heading_deg(views), dtype=np.float64)
    gap = np.abs((facing - angles + 180.0) % 360.0 - 180.0)
    shifted = (view_k == 0) & ~degenerate & ~not_square & ~mirrored & (gap > 45.0)

    bad: set[int] = set()
    # A record whose every view is off its map but on it read as [lng, lat]: one issue
    # that says so, not a mirrored-order and an off-map issue for each of its views.
    flipped = views[..., ::-1]
    on_if_swapped = ((flipped >= lo[:, None, :]) & (flipped <= hi[:, None, :])).all(axis=(1, 2))
    # Per record, how many of its views are off the map and on it swapped: all of them?
    swapped_views = np.bincount(owner, weights=outside & on_if_swapped, minlength=len(pending))
    swapped = set(np.flatnonzero(swapped_views == counts).tolist())
    for r in sorted(swapped):
        p = pending[r]
        message = (
            "every view lies off the map and would lie on it read as [lng, lat]: corners "
            "are [lat, lng] (swapped?)"
        )
        episode = episode_id_of(p.raw["map_name"], p.raw["route_index"])
        issues.append(ValidationIssue(file, message, p.index, episode, "gt_path_corners"))
        bad.add(p.index)
    problems = (
        (degenerate, _DEGENERATE),
        (not_square, _NOT_SQUARE),
        (mirrored, "corners are not in the order front-left, front-right, back-right, back-left"),
        (outside, _OUTSIDE),
        (
            shifted,
            "the first view faces {facing} degrees but angle (the start heading) is "
            "{angle}: its corners do not start at the front-left corner (listed from "
            "another corner?)",
        ),
    )
    for mask, template in problems:
        for v in np.flatnonzero(mask):
            if owner[v] in swapped:
                continue
            p = pending[owner[v]]
            message = template.format(
                facing=f"{facing[v]:.1f}",
                angle=f"{angles[v]:g}",
                min=MIN_EDGE_M,
                sides=", ".join(f"{s:.1f}" for s in sides[v]),
                diags=", ".join(f"{d:.1f}" for d in diagonals[v]),
            )
            episode = episode_id_of(p.raw["map_name"], p.raw["route_index"])
            issues.append(
                ValidationIssue(file, message, p.index, episode, f"gt_path_corners[{view_k[v]}]")
            )
            bad.add(p.index)
    return bad


def _check_destinations(
    pending: list[_Pending], file: str, issues: list[ValidationIssue]
) -> set[int]:
    """Destination corners are [lat, lng] and the area's centre lies on its map: swapped
    [lng, lat] corners are off the globe or, where they still read as [lat, lng], far
    off the map. Its centre, not every corner as for the views: a destination is a
    landmark's footprint, which may reach past the image's edge (two in the synthetic
    sample do, by about 0.2 m)."""
    have = [(p, p.destination) for p in pending if p.destination is not None]
    if not have:
        return set()
    corners = np.stack([d for _, d in have])  # (R, 4, 2)
    off_globe = (np.abs(corners[..., 0]) > 90.0) | (np.abs(corners[..., 1]) > 180.0)
    centres = corners.mean(axis=1)
    lo = np.array([p.raw["gps_botm_left"] for p, _ in have])
    hi = np.array([p.raw["gps_top_right"] for p, _ in have])
    off_map = ((centres < lo) | (centres > hi)).any(axis=1)
    bad: set[int] = set()
    for r in np.flatnonzero(off_globe.any(axis=1) | off_map):
        p = have[r][0]
        if off_globe[r].any():
            k = int(np.flatnonzero(off_globe[r])[0])
            field = f"destination[{k}]"
            where = f"not a valid [lat, lng]: {corners[r, k].tolist()!r}"
        else:
            field = "destination"
            where = (
                f"destination centre {centres[r].tolist()!r} lies outside the map bounds "
                "gps_botm_left..gps_top_right"
            )
        episode = episode_id_of(p.raw["map_name"], p.raw["route_index"])
        message = f"{where} (corners are [lat, lng]: swapped?)"
        issues.append(ValidationIssue(file, message, p.index, episode, field))
        bad.add(p.index)
    return bad


def _check_attention_on_map(
    pending: list[_Pending], file: str, issues: list[ValidationIssue]
) -> set[int]:
    """Attention circles are centred on their map (a human marked them on its image): a
    swapped [lng, lat] centre that still reads as a valid [lat, lng] lies far off it. A
    tenth of the map's extent is allowed past each edge, for rounding near one."""
    bad: set[int] = set()
    for p in pending:
        if not p.attention:
            continue
        centres = np.array([circle.centre for circle in p.attention], dtype=np.float64)
        lo = np.array(p.raw["gps_botm_left"], dtype=np.float64)
        hi = np.array(p.raw["gps_top_right"], dtype=np.float64)
        margin = 0.1 * (hi - lo)
        off = ((centres < lo - margin) | (centres > hi + margin)).any(axis=1)
        if off.any():
            k = int(np.flatnonzero(off)[0])
            episode = episode_id_of(p.raw["map_name"], p.raw["route_index"])
            message = (
                f"attention centre {centres[k].tolist()!r} lies outside the map bounds "
                "gps_botm_left..gps_top_right (centres are [lat, lng]: swapped?)"
            )
            issues.append(
                ValidationIssue(file, message, p.index, episode, f"attention_list[{k}][0]")
            )
            bad.add(p.index)
    return bad


def _first_records(data: Sequence[Any]) -> dict[str, int]:
    """The first record of each episode id in ``data``, valid or not: a valid record
    whose id an invalid one gave first is a duplicate all the same (it was written out
    under that id while the list of what was left out named it too)."""
    first: dict[str, int] = {}
    for index, raw in enumerate(data):
        if isinstance(raw, dict):
            map_name, route = raw.get("map_name"), raw.get("route_index")
            if text_ok(map_name) and text_ok(route):
                first.setdefault(episode_id_of(map_name, route), index)
    return first


def _check_consistency(
    pending: list[_Pending], first_records: dict[str, int], file: str, issues: list[ValidationIssue]
) -> set[int]:
    """Duplicate episode ids (``first_records``: each id's first record) and maps whose
    records disagree on the geo-reference."""
    bad: set[int] = set()
    georef_of_map: dict[str, tuple[int, tuple[Any, ...]]] = {}  # map -> first record, georef
    for p in pending:
        raw = p.raw
        episode = episode_id_of(raw["map_name"], raw["route_index"])
        first_seen = first_records.get(episode, p.index)
        if first_seen != p.index:
            issues.append(
                ValidationIssue(
                    file,
                    f"duplicate episode id (first seen in record {first_seen})",
                    p.index,
                    episode,
                    "route_index",
                )
            )
            bad.add(p.index)
            continue
        georef = tuple(
            tuple(value) if isinstance(value, list) else value
            for value in (raw[field] for field in _GEOREF_FIELDS)
        )
        first, known = georef_of_map.setdefault(raw["map_name"], (p.index, georef))
        differs = [f for f, a, b in zip(_GEOREF_FIELDS, known, georef, strict=True) if a != b]
        if differs:
            issues.append(
                ValidationIssue(
                    file,
                    f"geo-reference differs from record {first}'s, the first of map "
                    f"{raw['map_name']!r} (here {', '.join(differs)})",
                    p.index,
                    episode,
                    differs[0],
                )
            )
            bad.add(p.index)
    return bad | _check_last_rounds([p for p in pending if p.index not in bad], file, issues)


def _check_last_rounds(
    pending: list[_Pending], file: str, issues: list[ValidationIssue]
) -> set[int]:
    """No record declares its trajectory's last round (``last_round_idx``) before a round
    the file holds of it: ANDH-Full would take another record's larger declaration and
    say nothing. (A declaration beyond the rounds held is a missing round, which building
    the ANDH-Full episode reports.)"""
    bad: set[int] = set()
    rounds: dict[tuple[str, str], list[tuple[int, int, int | None]]] = {}
    for p in pending:
        trajectory, number = str(p.raw["route_index"]).split("_")
        entry = (p.index, int(number), p.raw.get("last_round_idx"))
        rounds.setdefault((str(p.raw["map_name"]), trajectory), []).append(entry)
    for (map_name, trajectory), held in rounds.items():
        latest_index, latest, _ = max(held, key=lambda entry: entry[1])
        for index, round_index, last in held:
            if last is None or last >= latest:
                continue
            problem = f"{last}, but record {latest_index} holds round {latest} of this trajectory"
            episode = episode_id_of(map_name, f"{trajectory}_{round_index}")
            issues.append(ValidationIssue(file, problem, index, episode, "last_round_idx"))
            bad.add(index)
    return bad


#: The fields that place a map on the globe: every record of a map must agree on them.
_GEOREF_FIELDS = ("gps_botm_left", "gps_top_right", "lng_ratio", "lat_ratio")


def _frozen(arr: NDArray[np.float64]) -> NDArray[np.float64]:
    arr.flags.writeable = False
    return arr


def _build(p: _Pending) -> AvdnRecord:
    raw = p.raw
    extra = {k: v for k, v in raw.items() if k not in RECORD_KEYS}
    return AvdnRecord(
        map_name=raw["map_name"],
        route_index=raw["route_index"],
        instructions=raw["instructions"],
        pre_dialogs=tuple(raw["pre_dialogs"]),
        gps_botm_left=(raw["gps_botm_left"][0], raw["gps_botm_left"][1]),
        gps_top_right=(raw["gps_top_right"][0], raw["gps_top_right"][1]),
        lng_ratio=raw["lng_ratio"],
        lat_ratio=raw["lat_ratio"],
        angle=raw["angle"],
        gt_path_corners=_frozen(p.corners),
        attention_list=p.attention,
        last_round_idx=raw.get("last_round_idx"),
        destination=None if p.destination is None else _frozen(p.destination),
        extra=MappingProxyType(extra),
        source=MappingProxyType(raw),
    )


def _check_end_views(
    pending: list[_Pending], split: str | None, file: str, issues: list[ValidationIssue]
) -> set[int]:
    """A path of the start view alone is how test_unseen withholds its ground truth
    (AVDN.md: "In test_unseen, N = 1 (start only)"); in another split it is a record
    without the end view its metrics score against, which passed as valid."""
    if split is None or split == "test_unseen":
        return set()
    bad: set[int] = set()
    for p in pending:
        if len(p.corners) == 1:
            message = (
                f"only the start view: a {split} record's ground truth needs its end view "
                "too (the start view alone is the withheld ground truth of test_unseen)"
            )
            episode = episode_id_of(p.raw["map_name"], p.raw["route_index"])
            issues.append(ValidationIssue(file, message, p.index, episode, "gt_path_corners"))
            bad.add(p.index)
    return bad


def parse_records_indexed(
    data: Sequence[Any], file: str, split: str | None = None
) -> tuple[list[int], list[AvdnRecord], list[ValidationIssue]]:
    """:func:`parse_records`, also returning each valid record's index in ``data``.

    With ``split``, a record of any split but test_unseen needs more than its start view.
    """
    issues: list[ValidationIssue] = []
    pending = [p for i, raw in enumerate(data) if (p := _check_record(raw, i, file, issues))]
    bad = (
        _check_end_views(pending, split, file, issues)
        | _check_view_geometry(pending, file, issues)
        | _check_destinations(pending, file, issues)
        | _check_attention_on_map(pending, file, issues)
    )
    good = [p for p in pending if p.index not in bad]
    bad |= _check_consistency(good, _first_records(data), file, issues)
    kept = [p for p in good if p.index not in bad]
    issues.sort(key=lambda issue: issue.record_index if issue.record_index is not None else -1)
    return [p.index for p in kept], [_build(p) for p in kept], issues


def parse_records(data: Sequence[Any], file: str) -> tuple[list[AvdnRecord], list[ValidationIssue]]:
    """Validate a decoded annotation list; returns the valid records and every issue.

    Records are returned in file order; an invalid record is left out and described by
    at least one issue. Nothing is dropped without an issue.
    """
    _, records, issues = parse_records_indexed(data, file)
    return records, issues


def parse_record(raw: Any, file: str = "<record>", index: int = 0) -> AvdnRecord:
    """Validate and type a single record; raises AvdnValidationError when it is invalid."""
    from skyvln_eval.errors import AvdnValidationError

    records, issues = parse_records([raw], file)
    if issues:
        raise AvdnValidationError(
            [ValidationIssue(i.file, i.message, index, i.episode_id, i.field) for i in issues]
        )
    return records[0]


def undefined_fields(records: Sequence[AvdnRecord]) -> list[str]:
    """The fields of ``records`` the AVDN format does not define (kept in ``extra`` as they
    are), each with how many records carry it and the defined field it may misspell: a
    typo of an optional field (``destinaton``) is otherwise read as its absence."""
    counts = Counter(key for record in records for key in record.extra)
    described = []
    for key, count in sorted(counts.items()):
        close = difflib.get_close_matches(key, sorted(RECORD_KEYS), n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        described.append(f"{key!r} in {count} record(s){hint}")
    return described


def undefined_fields_note(records: Sequence[AvdnRecord]) -> str | None:
    """A note naming the :func:`undefined_fields` of ``records``, or None when all are
    defined: such fields are kept as they are, but a misspelt optional field reads as absent."""
    undefined = undefined_fields(records)
    if not undefined:
        return None
    return f"fields the AVDN format does not define (kept as they are): {'; '.join(undefined)}"


#: The official agent's step, given a stored heading that differs from its view's (both
#: rounded, compared without wrapping) by more than this, adds the stored heading to the
#: turn (``move_view_corners``; it prints "warning, currencting the view area").
OFFICIAL_HEADING_GAP_DEG = 2


def start_heading_note(records: Sequence[AvdnRecord], shown: int = 3) -> str | None:
    """A note on records whose ``angle`` (as the official loader rounds it) is more than
    :data:`OFFICIAL_HEADING_GAP_DEG` off their first view's rounded heading, or None: the
    official agent turns their first step by the stored heading as well (a defect of its
    step that AVDN.md's step, and this toolkit's, do not have), so official figures for
    them are not comparable. The check has no wrap-round, as the official one has none
    (359 against 0 is off)."""
    off = []
    for record in records:
        stored = round(record.angle) % 360
        facing = round(float(view_heading_deg(record.gt_path_corners[0]))) % 360
        if abs(stored - facing) > OFFICIAL_HEADING_GAP_DEG:
            off.append(f"{record.episode_id} ({stored} vs {facing} deg)")
    if not off:
        return None
    more = f" and {len(off) - shown} more" if len(off) > shown else ""
    return (
        f"{len(off)} record(s) start at an angle more than {OFFICIAL_HEADING_GAP_DEG} degrees "
        f"off their first view's heading: {', '.join(off[:shown])}{more}. The official "
        "agent adds such an angle to the first turn (a defect of its step); this toolkit "
        "steps from the view, as AVDN.md does, so their official figures may differ"
    )
