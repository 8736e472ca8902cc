"""Landmark detectors: one small interface, a default built on the world's layers, a registry.

:class:`LayerDetector` reads the instance and semantic images a synthetic tile renders
(the camera's "ground-truth segmentation") and makes them imperfect on purpose: visible
landmarks are missed at random, and some ordinary buildings are consistently taken for
landmarks (phantoms) until seen from close by. Scores grow with how much of the landmark
is visible, plus noise. Captions of real landmarks are the landmark's description, i.e.
this detector assumes a perfect captioner; phantoms are described from their pixels only.

:class:`~skyvln_eval.agent.grounding_dino.GroundingDinoDetector` (extra ``vision``)
detects in the RGB image from text phrases instead.
"""

from __future__ import annotations

import weakref
import zlib
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import cv2
import numpy as np
from numpy.typing import NDArray

from skyvln_eval.errors import ConfigError, PerceptionError, UnknownNameError
from skyvln_eval.sim.camera import CameraImages, enu_to_map_px
from skyvln_eval.vocabulary import CATEGORY_LABELS
from skyvln_eval.worlds.tile import SemanticClass, WorldTile

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


@dataclass(frozen=True, eq=False)
class Detection:
    """One detected landmark in one image: label, box, score in [0, 1], caption, optional mask."""

    label: str
    box_px: Box
    score: float
    caption: str = ""
    mask: NDArray[np.bool_] | None = None


class Detector(ABC):
    """``detect(images, phrases) -> detections``; ``reset`` once per episode."""

    name: str = "detector"

    def reset(self, world: WorldTile, seed: int) -> None:  # noqa: B027 - optional hook
        """Prepare for an episode on ``world``; ``seed`` makes imperfections reproducible."""

    @abstractmethod
    def detect(self, images: CameraImages, phrases: Sequence[str] = ()) -> list[Detection]:
        """Landmarks in one capture; text-prompted detectors look for ``phrases``."""

    def settings(self) -> dict[str, Any]:
        return {"name": self.name}


def colour_name(rgb: NDArray[Any]) -> str:
    """The named colour most pixels are closest to (the roof's colour, not the mean of all)."""
    pixels = np.asarray(rgb, dtype=np.float64).reshape(-1, 3)
    names = list(_NAMED_COLOURS)
    palette = np.array([_NAMED_COLOURS[n] for n in names], dtype=np.float64)
    nearest = np.argmin(((pixels[:, None, :] - palette[None, :, :]) ** 2).sum(axis=2), axis=1)
    return names[int(np.bincount(nearest, minlength=len(names)).argmax())]


def _box_of(mask: NDArray[np.bool_]) -> Box:
    rows, cols = np.nonzero(mask)
    return int(cols.min()), int(rows.min()), int(cols.max()) + 1, int(rows.max()) + 1


@dataclass
class _PlainBuildings:
    """The ordinary (unnamed) buildings of a map: connected components, boxes, roof colours.

    They depend on the map only, so they are computed once per world and shared by every
    detector (agents are built per episode); roof colours are named on first use, from the
    building's own pixels (the same pixels as a whole-map mask would select).
    """

    components: NDArray[np.int32]
    boxes: NDArray[np.int32]  # per component: x, y, width, height, area (row 0: background)
    colours: dict[int, str] = field(default_factory=dict)

    @property
    def count(self) -> int:
        return len(self.boxes) - 1

    def colour(self, world: WorldTile, component: int) -> str:
        if component not in self.colours:
            x, y, w, h = (int(v) for v in self.boxes[component][:4])
            inside = self.components[y : y + h, x : x + w] == component
            pixels = world.bgr[y : y + h, x : x + w][inside]
            self.colours[component] = colour_name(pixels[..., ::-1])
        return self.colours[component]


_PLAIN_BUILDINGS: weakref.WeakKeyDictionary[WorldTile, _PlainBuildings] = (
    weakref.WeakKeyDictionary()
)


def _plain_buildings(world: WorldTile) -> _PlainBuildings:
    if world not in _PLAIN_BUILDINGS:
        semantic, instance = world.semantic, world.instance
        if semantic is None or instance is None:
            raise PerceptionError(f"map {world.map_name} has no semantic / instance layers")
        plain = ((semantic == SemanticClass.BUILDING) & (instance == 0)).astype(np.uint8)
        _, components, stats, _ = cv2.connectedComponentsWithStats(plain, connectivity=4)
        _PLAIN_BUILDINGS[world] = _PlainBuildings(
            components.astype(np.int32), stats.astype(np.int32)
        )
    return _PLAIN_BUILDINGS[world]


@dataclass(frozen=True)
class _Phantom:
    """An ordinary building the detector takes for a landmark, whenever it sees it from afar."""

    label: str
    caption: str
    score: float


class LayerDetector(Detector):
    """Detections from the semantic and instance layers, with misses and phantoms.

    * Each visible landmark (at least ``min_pixels``) is missed with probability
      ``miss_rate``, independently in every view.
    * A fraction ``false_positive_rate`` of the map's ordinary buildings are phantoms: the
      detector consistently takes each for a landmark of a random category (the same one
      every time, as a real detector fooled by an appearance would be), captioned from its
      roof colour, unless it looks from closer than ``close_look_m``, where the mistake
      shows and the phantom is not reported.
    """

    name = "layers"

    def __init__(
        self,
        miss_rate: float = 0.1,
        false_positive_rate: float = 0.03,
        min_pixels: int = 25,
        close_look_m: float = 70.0,
        seed: int = 0,
    ) -> None:
        if not 0.0 <= miss_rate <= 1.0:
            raise ConfigError(f"detector miss_rate must be in [0, 1], got {miss_rate}")
        if not 0.0 <= false_positive_rate <= 1.0:
            raise ConfigError(
                f"detector false_positive_rate must be in [0, 1], got {false_positive_rate}"
            )
        self.miss_rate = miss_rate
        self.false_positive_rate = false_positive_rate
        self.min_pixels = min_pixels
        self.close_look_m = close_look_m
        self.seed = seed
        self._world: WorldTile | None = None
        self._components: NDArray[np.int32] | None = None
        self._phantoms: dict[int, _Phantom] = {}
        self._rng = np.random.default_rng(seed)

    def settings(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "miss_rate": self.miss_rate,
            "false_positive_rate": self.false_positive_rate,
            "min_pixels": self.min_pixels,
            "close_look_m": self.close_look_m,
        }

    def reset(self, world: WorldTile, seed: int) -> None:
        if world.instance is None or world.semantic is None:
            raise PerceptionError(
                f"map {world.map_name} has no semantic / instance layers (a real xView map?): "
                "the 'layers' detector cannot see landmarks there; use detector 'grounding_dino' "
                "(pip install 'skyvln-eval[vision]')"
            )
        self._rng = np.random.default_rng([self.seed, seed])
        buildings = _plain_buildings(world)
        self._components = buildings.components
        self._world = world
        count = buildings.count
        chosen = np.nonzero(self._rng.random(count) < self.false_positive_rate)[0] + 1
        # Buildings pass for buildings: a phantom is never a bridge, park or roundabout.
        labels = [
            CATEGORY_LABELS[c] for c in CATEGORY_LABELS if c not in ("bridge", "park", "roundabout")
        ]
        self._phantoms = {}
        for component in chosen.tolist():
            label = labels[int(self._rng.integers(len(labels)))]
            colour = buildings.colour(world, component)
            score = float(self._rng.uniform(0.35, 0.7))
            self._phantoms[component] = _Phantom(label, f"a {label} with a {colour} roof", score)

    def detect(self, images: CameraImages, phrases: Sequence[str] = ()) -> list[Detection]:
        if self._world is None or images.instance is None or images.semantic is None:
            raise PerceptionError(
                "LayerDetector.detect needs reset(world) and a capture with layers"
            )
        ids, counts = np.unique(images.instance, return_counts=True)
        out: list[Detection] = []
        for landmark_id, count in zip(ids.tolist(), counts.tolist(), strict=True):
            if landmark_id == 0 or count < self.min_pixels or self._rng.random() < self.miss_rate:
                continue
            landmark = self._world.landmark(landmark_id)
            mask = images.instance == landmark_id
            visible = min(1.0, float(np.sqrt(count)) / 40.0)
            score = float(np.clip(0.45 + 0.5 * visible + self._rng.normal(0.0, 0.05), 0.05, 0.99))
            label = CATEGORY_LABELS.get(landmark.category, landmark.category.replace("_", " "))
            out.append(Detection(label, _box_of(mask), score, landmark.description, mask))
        return out + self._phantom_detections(images)

    def _phantom_detections(self, images: CameraImages) -> list[Detection]:
        """Phantoms seen in this capture, located through each pixel's ground point."""
        if not self._phantoms or self._world is None or self._components is None:
            return []
        assert images.semantic is not None and images.instance is not None  # checked by detect
        plain = (images.semantic == SemanticClass.BUILDING) & (images.instance == 0)
        plain &= np.isfinite(images.depth_m)
        v, u = np.nonzero(plain)
        if len(u) == 0:
            return []
        points = images.points_enu(u, v)
        px, py = enu_to_map_px(
            self._world, points[:, 0].astype(np.float32), points[:, 1].astype(np.float32)
        )
        rows = np.clip(np.rint(py).astype(int), 0, self._components.shape[0] - 1)
        cols = np.clip(np.rint(px).astype(int), 0, self._components.shape[1] - 1)
        component = self._components[rows, cols]
        out = []
        for cid, phantom in self._phantoms.items():
            here = component == cid
            if int(here.sum()) < self.min_pixels or self._rng.random() < self.miss_rate:
                continue
            if float(np.median(images.depth_m[v[here], u[here]])) < self.close_look_m:
                continue
            mask = np.zeros(images.depth_m.shape, dtype=bool)
            mask[v[here], u[here]] = True
            score = float(np.clip(phantom.score + self._rng.normal(0.0, 0.05), 0.05, 0.99))
            out.append(Detection(phantom.label, _box_of(mask), score, phantom.caption, mask))
        return out


_DETECTORS: Final[dict[str, str]] = {
    "layers": "skyvln_eval.agent.detectors:LayerDetector",
    "grounding_dino": "skyvln_eval.agent.grounding_dino:GroundingDinoDetector",
}


def create_detector(name: str, **options: Any) -> Detector:
    """A detector by registry name (``layers``, ``grounding_dino``), imported on use."""
    import importlib

    if name not in _DETECTORS:
        raise UnknownNameError("detector", name, list(_DETECTORS))
    module_name, _, class_name = _DETECTORS[name].partition(":")
    cls = getattr(importlib.import_module(module_name), class_name)
    detector: Detector = cls(**options)
    return detector


def episode_seed(seed: int, episode_id: str) -> int:
    """A per-episode seed that does not depend on Python's hash randomisation."""
    return (seed * 1_000_003 + zlib.crc32(episode_id.encode("utf-8"))) % (2**32)
