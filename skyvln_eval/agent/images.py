"""The camera views an agent shows a model that takes images: JPEG, with a size cap."""

from __future__ import annotations

from typing import Final

import cv2
import numpy as np

from skyvln_eval.agent.perception import Panorama
from skyvln_eval.llm.types import ImagePart

JPEG_QUALITY: Final = 85


def panorama_images(panorama: Panorama, max_side_px: int) -> list[ImagePart]:
    """Every view of the panorama as a JPEG no larger than ``max_side_px`` on its long side.

    Each part is labelled with the view's name and heading, so the run log says which
    views were sent.
    """
    parts = []
    for view in panorama.views:
        height, width = view.images.rgb.shape[:2]
        scale = min(1.0, max_side_px / max(height, width))
        bgr: np.ndarray = view.images.rgb[..., ::-1]
        if scale < 1.0:
            size = (max(1, round(width * scale)), max(1, round(height * scale)))
            bgr = cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)
        ok, buffer = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if ok:
            label = f"view {view.name} (facing {view.heading_deg:.0f} deg)"
            parts.append(ImagePart(buffer.tobytes(), "image/jpeg", label))
    return parts
