"""The simulated detector as it was before it was vectorised, kept as the reference its
test compares with and the baseline its benchmark times (``benchmarks/detector.py``): a
loop over the landmarks, a Python loop over every plain building (its pixels, points and
medians one by one, inside the building's box), a linear scan of the buildings met, and
colours by one float matrix product. Not package code."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from skyvln_eval.agent.detectors import _BUILDING_LABELS, _NAMED_COLOURS, _PALETTE, Detection
from skyvln_eval.sensing import CameraImages, SemanticClass
from skyvln_eval.vocabulary import CATEGORY_LABELS

#: Pixels that place a building (every n-th of its pixels, n = pixels // this).
PLACE_SAMPLES = 200


class ReferenceDetector:
    """SimulatedDetector's rules and random draws, written as the earlier code was."""

    def __init__(self, **settings: Any) -> None:
        self.miss_rate = settings.get("miss_rate", 0.1)
        self.false_positive_rate = settings.get("false_positive_rate", 0.03)
        self.confusion_rate = settings.get("confusion_rate", 0.05)
        self.min_pixels = settings.get("min_pixels", 25)
        self.close_look_m = settings.get("close_look_m", 70.0)
        self.phantom_cell_m = settings.get("phantom_cell_m", 30.0)
        self.seed = settings.get("seed", 0)
        self.rng = np.random.default_rng(self.seed)
        self.buildings: list[tuple[float, float, tuple[str, float] | None]] = []

    def reset(self, seed: int) -> None:
        self.rng = np.random.default_rng([self.seed, seed])
        self.buildings = []

    def detect(self, images: CameraImages) -> list[Detection]:
        semantic, instance = images.semantic, images.instance
        assert semantic is not None and instance is not None
        ids, counts = np.unique(instance, return_counts=True)
        out = []
        for landmark_id, count in zip(ids.tolist(), counts.tolist(), strict=True):
            if landmark_id == 0 or count < self.min_pixels or self.rng.random() < self.miss_rate:
                continue
            category = images.instance_categories.get(landmark_id, "landmark")
            label = CATEGORY_LABELS.get(category, category.replace("_", " "))
            if self.rng.random() < self.confusion_rate:
                label = _BUILDING_LABELS[int(self.rng.integers(len(_BUILDING_LABELS)))]
            mask = instance == landmark_id
            visible = min(1.0, float(np.sqrt(count)) / 40.0)
            score = float(np.clip(0.45 + 0.5 * visible + self.rng.normal(0.0, 0.05), 0.05, 0.99))
            caption = reference_caption(label, images.rgb[mask], semantic[mask])
            out.append(Detection(label, reference_box(mask), score, caption, mask))
        return out + self.phantoms(images, semantic, instance)

    def phantoms(
        self, images: CameraImages, semantic: np.ndarray, instance: np.ndarray
    ) -> list[Detection]:
        if self.false_positive_rate <= 0.0:
            return []
        plain = ((semantic == SemanticClass.BUILDING) & (instance == 0)).astype(np.uint8)
        count, components, stats, _ = cv2.connectedComponentsWithStats(plain, connectivity=4)
        out = []
        finite = images.finite_depth()
        for component in range(1, count):
            x0, y0, w, h, area = (int(value) for value in stats[component])
            if area < self.min_pixels:
                continue
            window = (slice(y0, y0 + h), slice(x0, x0 + w))
            v, u = np.nonzero((components[window] == component) & finite[window])
            if len(u) < self.min_pixels:
                continue
            v, u = v + y0, u + x0
            step = max(1, len(u) // PLACE_SAMPLES)
            points = images.points_enu(u[::step], v[::step])
            x, y = float(np.median(points[:, 0])), float(np.median(points[:, 1]))
            phantom = self.phantom_at(x, y)
            if phantom is None:
                continue
            camera = np.array([images.pose.x_m, images.pose.y_m, images.pose.z_m])
            if float(np.median(np.linalg.norm(points - camera, axis=1))) < self.close_look_m:
                continue
            if self.rng.random() < self.miss_rate:
                continue
            label, base = phantom
            score = float(np.clip(base + self.rng.normal(0.0, 0.05), 0.05, 0.99))
            mask = np.zeros(plain.shape, dtype=bool)
            mask[v, u] = True
            caption = reference_caption(label, images.rgb[v, u], semantic[v, u])
            out.append(Detection(label, reference_box(mask), score, caption, mask))
        return out

    def phantom_at(self, x_m: float, y_m: float) -> tuple[str, float] | None:
        for bx, by, known in self.buildings:
            if math.hypot(bx - x_m, by - y_m) <= self.phantom_cell_m:
                return known
        decision = None
        if self.rng.random() < self.false_positive_rate:
            label = _BUILDING_LABELS[int(self.rng.integers(len(_BUILDING_LABELS)))]
            decision = (label, float(self.rng.uniform(0.35, 0.7)))
        self.buildings.append((x_m, y_m, decision))
        return decision


def reference_box(mask: np.ndarray) -> tuple[int, int, int, int]:
    rows, cols = np.nonzero(mask)
    return int(cols.min()), int(rows.min()), int(cols.max()) + 1, int(rows.max()) + 1


def reference_colour_name(rgb: np.ndarray) -> str:
    """The earlier colour measure: one float matrix product, the majority over pixels."""
    pixels = np.asarray(rgb, dtype=np.float64).reshape(-1, 3)
    nearest = np.argmin(pixels @ (-2.0 * _PALETTE.T) + (_PALETTE**2).sum(axis=1), axis=1)
    return list(_NAMED_COLOURS)[int(np.bincount(nearest, minlength=len(_PALETTE)).argmax())]


def reference_caption(label: str, rgb: np.ndarray, semantic: np.ndarray) -> str:
    colour = reference_colour_name(rgb)
    if np.mean(semantic == SemanticClass.BUILDING) >= 0.5:
        return f"a {label} with a {colour} roof"
    return f"a {colour} {label}"
