"""Landmark detectors: one small interface, each detector saying which sensors it needs.

``detect(images, phrases) -> detections`` on one capture; ``road_bearings`` reads the roads
leaving from below the drone, where a detector can. Detectors see pixels only: a capture
(:class:`~skyvln_eval.sensing.CameraImages`) carries no landmark's name or description.

* :class:`SimulatedDetector` (``simulated``; the default on synthetic data) reads the
  semantic camera: boxes from each landmark instance's mask, the label from the instance's
  category, attributes (the colour of its roof or ground) measured from the RGB pixels of
  the mask. It is imperfect on purpose: landmarks are missed at random, labels confused at
  random, and some ordinary buildings are taken for landmarks (phantoms: the same building
  every time it is seen from afar) until seen from close by.
* ``grounding_dino`` (extra ``vision``) and ``vlm`` (a vision-language model over the OpenAI
  protocol) detect in the RGB image from the instruction's landmark phrases.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Final

import cv2
import numpy as np
from numpy.typing import NDArray

from skyvln_eval.agent.order_stats import column_medians
from skyvln_eval.errors import ConfigError, PerceptionError, UnknownNameError
from skyvln_eval.llm_records import LlmCall, ModuleFailure
from skyvln_eval.sensing import CameraImages, SemanticClass, SensorKind, instance_pixel_counts
from skyvln_eval.vocabulary import CATEGORY_LABELS

if TYPE_CHECKING:
    from skyvln_eval.llm.client import LLMClient

Box = tuple[int, int, int, int]  # x0, y0, x1, y1 in pixels, x1 / y1 exclusive

_NAMED_COLOURS: Final = {
    "red": (200, 40, 40),
    "orange": (230, 130, 40),
    "yellow": (230, 210, 60),
    "green": (60, 150, 60),
    "blue": (50, 90, 200),
    "white": (235, 235, 235),
    "grey": (128, 128, 128),
    "black": (30, 30, 30),
    "beige": (215, 195, 150),
    "brown": (120, 80, 40),
}
_PLACE_SAMPLES: Final = 200
ROAD_CLASSES: Final = (SemanticClass.ROAD, SemanticClass.VEHICLE, SemanticClass.BRIDGE)
#: Landmark labels an ordinary building can pass for (never a bridge, park or roundabout).
_BUILDING_LABELS: Final = tuple(
    label
    for category, label in CATEGORY_LABELS.items()
    if category not in ("bridge", "park", "roundabout")
)


@dataclass(frozen=True, eq=False)
class Detection:
    """One detected landmark in one image: label, box, score in [0, 1], caption, optional mask."""

    label: str
    box_px: Box
    score: float
    caption: str = ""
    mask: NDArray[np.bool_] | None = None


@dataclass
class DetectorCalls:
    """The LLM calls a detector made since they were last taken (a VLM's), for the agent's
    accounting and the run log."""

    records: list[LlmCall] = field(default_factory=list)
    exchanges: list[dict[str, Any]] = field(default_factory=list)
    failures: list[ModuleFailure] = field(default_factory=list)


class Detector(ABC):
    """``detect(images, phrases) -> detections``; ``reset`` once per episode.

    ``requires`` names the sensors a detector needs; a run whose sensors or data cannot
    give them refuses to start.
    """

    name: str = "detector"
    requires: frozenset[SensorKind] = frozenset({"rgb"})

    def reset(self, seed: int) -> None:  # noqa: B027 - optional hook
        """Start an episode; ``seed`` makes imperfections reproducible."""

    @abstractmethod
    def detect(self, images: CameraImages, phrases: Sequence[str] = ()) -> list[Detection]:
        """Landmarks in one capture; text-prompted detectors look for ``phrases``."""

    def road_bearings(self, below: CameraImages, heading_deg: float) -> tuple[float, ...]:
        """Compass bearings of roads leaving the point below the drone (none if unknown)."""
        return ()

    def take_calls(self) -> DetectorCalls:
        """The LLM calls made since the last take (none for detectors that make none)."""
        return DetectorCalls()

    def llm_clients(self) -> tuple[LLMClient, ...]:
        """The LLM clients the detector calls through (none for detectors that call none)."""
        return ()

    def settings(self) -> dict[str, Any]:
        return {"name": self.name, "requires": sorted(self.requires)}


_COLOUR_NAMES: Final = tuple(_NAMED_COLOURS)
_PALETTE: Final = np.array([_NAMED_COLOURS[n] for n in _COLOUR_NAMES], dtype=np.float64)


# For uint8 pixels, every colour's 16 (|c|^2 - 2 p.c) + its index, an exact int32: the
# smallest over the palette is the nearest colour's, the first of tied ones.
_KEY_PER_CHANNEL: Final = (-32 * _PALETTE.T).astype(np.int32)[:, :, None]  # (3, k, 1)
_KEY_OFFSET: Final = (16 * (_PALETTE**2).sum(axis=1) + np.arange(len(_PALETTE))).astype(np.int32)
assert len(_PALETTE) <= 16, "the colour's index is kept in a key's low 4 bits"


def colour_name(rgb: NDArray[Any]) -> str:
    """The named colour most pixels are closest to (the roof's colour, not the mean of all)."""
    pixels = np.asarray(rgb)
    if pixels.dtype == np.uint8:  # a camera's pixels
        nearest = _nearest_colours_by_box(pixels)
    else:
        values = pixels.astype(np.float64).reshape(-1, 3)
        # ||p - c||^2 - ||p||^2 = |c|^2 - 2 p.c: one matrix product instead of an (n, k, 3)
        # difference array; exact for integer pixels, so the nearest colour (ties included) is.
        nearest = np.argmin(values @ (-2.0 * _PALETTE.T) + (_PALETTE**2).sum(axis=1), axis=1)
    return _COLOUR_NAMES[int(np.bincount(nearest, minlength=len(_COLOUR_NAMES)).argmax())]


def _nearest_colours(rgb: NDArray[np.uint8]) -> NDArray[np.int32]:
    """Each uint8 pixel's nearest palette colour, as the float path finds it: the same
    integers (|c|^2 - 2 p.c, in int32 and shifted to carry the colour's index in the
    low 4 bits), so the same nearest colour, ties included; one elementwise minimum over
    the palette instead of a BLAS product (threaded, slow on a busy machine) and argmin."""
    channels = rgb.reshape(-1, 3).T.astype(np.int32)
    red, green, blue = _KEY_PER_CHANNEL
    keys = red * channels[0] + green * channels[1] + blue * channels[2] + _KEY_OFFSET[:, None]
    nearest: NDArray[np.int32] = np.min(keys, axis=0) & 15
    return nearest


#: Colours by boxes of 4 x 4 x 4 values (the top bits of each channel). A box whose eight
#: corners have one nearest colour (ties broken as :func:`_nearest_colours` breaks them) has
#: it at every value inside: each ordering "c before d" holds at the corners and is an
#: affine inequality (strict where d wins ties), so it holds on the box they span. 93% of
#: the boxes are such, and about 97 in 100 of a roof's pixels fall in one.
_BOX_BITS: Final = 2
_BOX_SIDE: Final = 256 >> _BOX_BITS
_box_colours: NDArray[np.int8] | None = None


def _box_table() -> NDArray[np.int8]:
    """Each box's nearest colour, -1 where its corners differ (made once per process, about
    0.1 s). Box ``(r, g, b)`` (the values' top bits) is entry ``(r * side + g) * side + b``."""
    global _box_colours
    if _box_colours is None:
        low = np.arange(_BOX_SIDE) << _BOX_BITS
        corner = np.stack(np.meshgrid(low, low, low, indexing="ij"), axis=-1).reshape(-1, 3)
        span = (1 << _BOX_BITS) - 1
        at_corners = [
            _nearest_colours((corner + span * np.array(offset)).astype(np.uint8))
            for offset in np.ndindex(2, 2, 2)
        ]
        first = at_corners[0]
        pure = np.logical_and.reduce([nearest == first for nearest in at_corners[1:]])
        _box_colours = np.where(pure, first, -1).astype(np.int8)
    return _box_colours


def _nearest_colours_by_box(rgb: NDArray[np.uint8]) -> NDArray[np.int32]:
    """:func:`_nearest_colours` of each pixel: read from its box's entry, computed only for
    pixels in boxes whose corners differ (three times faster on roofs)."""
    flat = rgb.reshape(-1, 3)
    top = (flat >> _BOX_BITS).astype(np.intp)
    box = (top[:, 0] * _BOX_SIDE + top[:, 1]) * _BOX_SIDE + top[:, 2]
    nearest = _box_table().take(box).astype(np.int32)
    mixed = np.flatnonzero(nearest < 0)
    if len(mixed):
        nearest[mixed] = _nearest_colours(flat[mixed])
    return nearest


def box_of(mask: NDArray[np.bool_]) -> Box:
    # The rows and columns holding any of the mask: far fewer than its pixels to list.
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return int(cols.min()), int(rows.min()), int(cols.max()) + 1, int(rows.max()) + 1


def clip_box(box: Sequence[float], width: int, height: int) -> Box | None:
    """A box ``(x0, y0, x1, y1)`` in pixels, grown to whole pixels and clipped to the image
    (``x1`` / ``y1`` exclusive); ``None`` when nothing of it lies inside."""
    x0, y0, x1, y1 = (float(v) for v in box)
    if not all(math.isfinite(v) for v in (x0, y0, x1, y1)):
        return None
    left, top = max(0, math.floor(min(x0, x1))), max(0, math.floor(min(y0, y1)))
    right, bottom = min(width, math.ceil(max(x0, x1))), min(height, math.ceil(max(y0, y1)))
    if right <= left or bottom <= top:
        return None
    return left, top, right, bottom


def road_bearings(
    semantic: NDArray[np.uint8],
    heading_deg: float,
    min_fraction: float = 0.75,
    separation_deg: float = 35.0,
) -> tuple[float, ...]:
    """Compass bearings of roads leaving the centre of a straight-down semantic image.

    Rays from the centre (image up = ``heading_deg``, clockwise to the right) are scored
    by the share of road pixels along them (cars and bridges count as road; small gaps
    such as a boulevard's median are closed first); the best-scoring directions at least
    ``separation_deg`` apart with a share above ``min_fraction`` are the roads.
    """
    road = cv2.morphologyEx(
        np.isin(semantic, ROAD_CLASSES).astype(np.uint8), cv2.MORPH_CLOSE, np.ones((9, 9), np.uint8)
    )
    height, width = road.shape
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    angles = np.arange(0.0, 360.0, 2.0)
    radii = np.linspace(0.12, 0.47, 12) * min(height, width)
    a = np.radians(angles)[:, None]
    cols = np.clip(np.rint(cx + radii[None, :] * np.sin(a)), 0, width - 1).astype(int)
    rows = np.clip(np.rint(cy - radii[None, :] * np.cos(a)), 0, height - 1).astype(int)
    share = road[rows, cols].mean(axis=1)
    # A wide road scores full over a range of angles: smooth so its middle scores best.
    window = np.ones(7) / 7.0
    share = np.convolve(np.concatenate([share[-3:], share, share[:3]]), window, mode="valid")
    found: list[float] = []
    for i in np.argsort(-share, kind="stable"):
        if share[i] < min_fraction:
            break
        if all(abs((angles[i] - f + 180.0) % 360.0 - 180.0) >= separation_deg for f in found):
            found.append(float(angles[i]))
    return tuple(sorted(round((heading_deg + f) % 360.0, 1) for f in found))


class SimulatedDetector(Detector):
    """Detections from the semantic camera, imperfect on purpose; see the module docstring.

    * Each visible landmark (at least ``min_pixels``) is missed with probability
      ``miss_rate``, independently in every view, and given a wrong label with probability
      ``confusion_rate``.
    * A share ``false_positive_rate`` of ordinary buildings are phantoms, decided when the
      building is first seen and remembered by where it stands (within
      ``phantom_cell_m``), so the same building fools the detector every time; it is not
      reported when seen from closer than ``close_look_m``.
    """

    name = "simulated"
    requires = frozenset({"rgb", "semantic"})

    def __init__(
        self,
        miss_rate: float = 0.1,
        false_positive_rate: float = 0.03,
        confusion_rate: float = 0.05,
        min_pixels: int = 25,
        close_look_m: float = 70.0,
        phantom_cell_m: float = 30.0,
        seed: int = 0,
    ) -> None:
        for what, rate in (
            ("miss_rate", miss_rate),
            ("false_positive_rate", false_positive_rate),
            ("confusion_rate", confusion_rate),
        ):
            if not 0.0 <= rate <= 1.0:
                raise ConfigError(f"detector {what} must be in [0, 1], got {rate}")
        self.miss_rate = miss_rate
        self.false_positive_rate = false_positive_rate
        self.confusion_rate = confusion_rate
        self.min_pixels = min_pixels
        self.close_look_m = close_look_m
        self.phantom_cell_m = phantom_cell_m
        self.seed = seed
        self._rng = np.random.default_rng(seed)
        # Ordinary buildings met this episode: where, and whether each is a phantom.
        self._buildings = _KnownBuildings()

    def settings(self) -> dict[str, Any]:
        return {
            **super().settings(),
            "miss_rate": self.miss_rate,
            "false_positive_rate": self.false_positive_rate,
            "confusion_rate": self.confusion_rate,
            "min_pixels": self.min_pixels,
            "close_look_m": self.close_look_m,
            "phantom_cell_m": self.phantom_cell_m,
        }

    def reset(self, seed: int) -> None:
        self._rng = np.random.default_rng([self.seed, seed])
        self._buildings = _KnownBuildings()

    def _check(self, images: CameraImages) -> tuple[NDArray[np.uint8], NDArray[np.uint16]]:
        if images.semantic is None or images.instance is None:
            raise PerceptionError(
                "the 'simulated' detector reads the semantic camera, and this capture has "
                "none (sensors.semantic is off, or the map has no semantic layers): use "
                "detector 'grounding_dino' or 'vlm' on RGB"
            )
        return images.semantic, images.instance

    def detect(self, images: CameraImages, phrases: Sequence[str] = ()) -> list[Detection]:
        semantic, instance = self._check(images)
        ids, counts = instance_pixel_counts(instance)
        out: list[Detection] = []
        for landmark_id, count in zip(ids.tolist(), counts.tolist(), strict=True):
            if landmark_id == 0 or count < self.min_pixels or self._rng.random() < self.miss_rate:
                continue
            category = images.instance_categories.get(landmark_id, "landmark")
            label = CATEGORY_LABELS.get(category, category.replace("_", " "))
            if self._rng.random() < self.confusion_rate:
                label = _BUILDING_LABELS[int(self._rng.integers(len(_BUILDING_LABELS)))]
            mask = instance == landmark_id
            visible = min(1.0, float(np.sqrt(count)) / 40.0)
            score = float(np.clip(0.45 + 0.5 * visible + self._rng.normal(0.0, 0.05), 0.05, 0.99))
            box = box_of(mask)
            # The mask's pixels, in the same order, picked from its box, not the whole image.
            window = (slice(box[1], box[3]), slice(box[0], box[2]))
            inside = mask[window]
            caption = _caption(label, images.rgb[window][inside], semantic[window][inside])
            out.append(Detection(label, box, score, caption, mask))
        return out + self._phantoms(images, semantic, instance)

    def _phantoms(
        self, images: CameraImages, semantic: NDArray[np.uint8], instance: NDArray[np.uint16]
    ) -> list[Detection]:
        """Ordinary buildings in this capture that the detector takes for landmarks.

        Each plain building (a connected component of building pixels outside every
        landmark) with at least ``min_pixels`` pixels of known ground point is placed at
        the median of a few hundred of those points, and asked, in component order, whether
        it is a phantom. What does not depend on earlier answers (the pixels, the places,
        the look-up among buildings met before) is computed for all buildings at once.
        """
        if self.false_positive_rate <= 0.0:
            return []
        plain = (semantic == SemanticClass.BUILDING) & (instance == 0)
        # Labels only (numbered in raster order of first pixel, as with stats), at a third
        # of the cost: the stats' areas would only repeat the check on pixel counts below.
        count, components = cv2.connectedComponents(plain.view(np.uint8), connectivity=4)
        buildings = _plain_buildings(images, plain, components, count, self.min_pixels)
        camera = np.array([images.pose.x_m, images.pose.y_m, images.pose.z_m])
        places = buildings.places()
        # The buildings met before this capture are looked up for all places at once; only
        # those met in it (they come later in the order met) are scanned place by place.
        met_before = len(self._buildings)
        earlier = self._buildings.first_within(places, self.phantom_cell_m)
        out = []
        for k, ((x, y), known) in enumerate(zip(places, earlier, strict=True)):
            if known is None:
                known = self._buildings.first_within_since(met_before, x, y, self.phantom_cell_m)
            phantom = self._phantom_at(x, y, known)
            if phantom is None:
                continue
            points = buildings.sample(k)
            if float(np.median(np.linalg.norm(points - camera, axis=1))) < self.close_look_m:
                continue  # seen from close by, the mistake shows
            if self._rng.random() < self.miss_rate:
                continue
            label, base = phantom
            score = float(np.clip(base + self._rng.normal(0.0, 0.05), 0.05, 0.99))
            v, u = buildings.pixels(k)
            mask = np.zeros(plain.shape, dtype=bool)
            mask[v, u] = True
            caption = _caption(label, images.rgb[v, u], semantic[v, u])
            box = (int(u.min()), int(v.min()), int(u.max()) + 1, int(v.max()) + 1)
            out.append(Detection(label, box, score, caption, mask))
        return out

    def _phantom_at(self, x_m: float, y_m: float, known: int | None) -> tuple[str, float] | None:
        """Whether the building at ``(x_m, y_m)`` fools the detector (its label and base
        score), decided the first time it is seen and remembered for the episode, so the
        same building is the same phantom from every view; ``known`` is the building met
        before that stands there (:meth:`_KnownBuildings.first_within`), if any."""
        if known is not None:
            return self._buildings.decisions[known]
        decision: tuple[str, float] | None = None
        if self._rng.random() < self.false_positive_rate:
            label = _BUILDING_LABELS[int(self._rng.integers(len(_BUILDING_LABELS)))]
            decision = (label, float(self._rng.uniform(0.35, 0.7)))
        self._buildings.add(x_m, y_m, decision)
        return decision

    def road_bearings(self, below: CameraImages, heading_deg: float) -> tuple[float, ...]:
        semantic, _ = self._check(below)
        return road_bearings(semantic, heading_deg)


class _KnownBuildings:
    """The ordinary buildings met in an episode, in the order met: where each stands (in a
    growing array, so looking many up is one vectorised pass) and whether it is a phantom.

    A building is the first one met within ``radius_m`` (by ``math.hypot``) of a place.
    """

    def __init__(self) -> None:
        self._xy: NDArray[np.float64] = np.empty((64, 2))
        self.decisions: list[tuple[str, float] | None] = []

    def __len__(self) -> int:
        return len(self.decisions)

    def add(self, x_m: float, y_m: float, decision: tuple[str, float] | None) -> None:
        n = len(self.decisions)
        if n == len(self._xy):
            self._xy = np.concatenate([self._xy, np.empty_like(self._xy)])
        self._xy[n] = (x_m, y_m)
        self.decisions.append(decision)

    def first_within(
        self, places: Sequence[tuple[float, float]], radius_m: float
    ) -> list[int | None]:
        """For each place, the index of the first building met within ``radius_m``."""
        found: list[int | None] = [None] * len(places)
        n = len(self.decisions)
        if n == 0 or not places:
            return found
        here = np.array(places, dtype=np.float64)
        dx = self._xy[None, :n, 0] - here[:, None, 0]
        dy = self._xy[None, :n, 1] - here[:, None, 1]
        # Squared distances only shortlist: they round differently from math.hypot, so a
        # hair of slack keeps every building it would accept (NaN ones too), and math.hypot
        # then decides, place by place in the order met, as a plain scan would.
        slack = radius_m * (1.0 + 1e-9)
        for k, i in np.argwhere(~(dx * dx + dy * dy > slack * slack)).tolist():
            if found[k] is None and math.hypot(float(dx[k, i]), float(dy[k, i])) <= radius_m:
                found[k] = i
        return found

    def first_within_since(self, start: int, x_m: float, y_m: float, radius_m: float) -> int | None:
        """The first building met from the ``start``-th on within ``radius_m`` of the place:
        a plain scan, for the few met since a batched look-up."""
        for i, (bx, by) in enumerate(self._xy[start : len(self.decisions)].tolist(), start):
            if math.hypot(bx - x_m, by - y_m) <= radius_m:
                return i
        return None


@dataclass(frozen=True)
class _PlainBuildings:
    """The plain buildings of one capture big enough to be taken for landmarks, in
    component order: their pixels with a known ground point (flat indices, one building
    after another, each in raster order) and, for every building, the ENU points of a
    sample of those pixels (one building after another too)."""

    flat: NDArray[np.intp]
    starts: NDArray[np.intp]
    counts: NDArray[np.intp]
    width: int
    points: NDArray[np.float64]
    point_starts: NDArray[np.intp]
    point_counts: NDArray[np.intp]

    def __len__(self) -> int:
        return len(self.counts)

    def pixels(self, k: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Rows and columns of building ``k``'s pixels."""
        flat = self.flat[self.starts[k] : self.starts[k] + self.counts[k]]
        rows, cols = np.divmod(flat, self.width)
        return rows, cols

    def sample(self, k: int) -> NDArray[np.float64]:
        """The ENU points of building ``k``'s sampled pixels."""
        start = int(self.point_starts[k])
        return self.points[start : start + int(self.point_counts[k])]

    def places(self) -> list[tuple[float, float]]:
        """Where each building stands: the medians of its sample's east and north, as
        ``np.median(sample[:, :2], axis=0)`` gives them, bit for bit."""
        return [column_medians(self.sample(k)[:, :2]) for k in range(len(self))]


def _plain_buildings(
    images: CameraImages,
    plain: NDArray[np.bool_],
    components: NDArray[np.int32],
    count: int,
    min_pixels: int,
) -> _PlainBuildings:
    """The components of ``plain`` (``count`` labels of ``cv2.connectedComponents``, 0 the
    background) with at least ``min_pixels`` pixels with a known ground point (see
    :class:`_PlainBuildings`). Such a component has at least ``min_pixels`` pixels in all,
    so no separate check of its area is needed."""
    labels = components.ravel()
    flat = np.flatnonzero((plain & images.finite_depth()).ravel())
    # Stable, so each building's pixels stay in raster order, the order np.nonzero gives.
    flat = flat[np.argsort(labels[flat], kind="stable")]
    sizes = np.bincount(labels[flat], minlength=count)
    starts = np.cumsum(sizes) - sizes
    keep = np.flatnonzero(sizes >= min_pixels)
    keep = keep[keep > 0]  # not the background
    starts, sizes = starts[keep], sizes[keep]
    # Where a building stands: a few hundred of its pixels (every step-th) place it as well
    # as all; the samples of every building go through one points_enu call.
    steps = np.maximum(1, sizes // _PLACE_SAMPLES)
    taken = -(-sizes // steps)  # len(range(0, size, step))
    first = np.cumsum(taken) - taken
    within = np.arange(int(taken.sum())) - np.repeat(first, taken)
    sampled = flat[np.repeat(starts, taken) + within * np.repeat(steps, taken)]
    rows, cols = np.divmod(sampled, components.shape[1])
    return _PlainBuildings(
        flat=flat,
        starts=starts,
        counts=sizes,
        width=components.shape[1],
        points=images.points_enu(cols, rows),
        point_starts=first,
        point_counts=taken,
    )


def _caption(label: str, rgb: NDArray[np.uint8], semantic: NDArray[np.uint8]) -> str:
    """What the pixels show of a detection: its label and measured colour."""
    colour = colour_name(rgb)
    if np.mean(semantic == SemanticClass.BUILDING) >= 0.5:
        return f"a {label} with a {colour} roof"
    return f"a {colour} {label}"


_DETECTORS: Final[dict[str, str]] = {
    "simulated": "skyvln_eval.agent.detectors:SimulatedDetector",
    "grounding_dino": "skyvln_eval.agent.grounding_dino:GroundingDinoDetector",
    "vlm": "skyvln_eval.agent.vlm_detector:VlmDetector",
}


def detector_class(name: str) -> type[Detector]:
    """A detector class by registry name, imported on use (``did you mean`` when unknown)."""
    import importlib

    if name not in _DETECTORS:
        raise UnknownNameError("detector", name, list(_DETECTORS))
    module_name, _, class_name = _DETECTORS[name].partition(":")
    cls: type[Detector] = getattr(importlib.import_module(module_name), class_name)
    return cls


def known_detectors() -> list[str]:
    return sorted(_DETECTORS)


def create_detector(name: str, **options: Any) -> Detector:
    """A detector by registry name (``simulated``, ``grounding_dino``, ``vlm``)."""
    return detector_class(name)(**options)
