"""The camera views an agent shows a model that takes images: JPEG, with a size cap."""

from __future__ import annotations

from typing import Final

import cv2
import numpy as np
from numpy.typing import NDArray

from skyvln_eval.agent.perception import Panorama
from skyvln_eval.llm.types import ImagePart

JPEG_QUALITY: Final = 85


def jpeg_image(rgb: NDArray[np.uint8], max_side_px: int, label: str) -> ImagePart | None:
    """An RGB image as a JPEG no larger than ``max_side_px`` on its long side (``None`` if
    OpenCV cannot encode it); ``label`` says in the run log what it shows."""
    height, width = rgb.shape[:2]
    scale = min(1.0, max_side_px / max(height, width))
    bgr: np.ndarray = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)  # not a reversed view (slow to copy)
    if scale < 1.0:
        size = (max(1, round(width * scale)), max(1, round(height * scale)))
        bgr = cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)
    ok, buffer = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    return ImagePart(buffer.tobytes(), "image/jpeg", label) if ok else None


def panorama_images(panorama: Panorama, max_side_px: int) -> list[ImagePart]:
    """Every view of the panorama as a JPEG no larger than ``max_side_px`` on its long side.

    Each part is labelled with the view's name and heading, so the run log says which
    views were sent.
    """
    parts = []
    for view in panorama.views:
        label = f"view {view.name} (facing {view.heading_deg:.0f} deg)"
        part = jpeg_image(view.images.rgb, max_side_px, label)
        if part is not None:
            parts.append(part)
    return parts
