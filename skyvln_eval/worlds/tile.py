"""A world tile: the raster an episode flies over, with whatever layers its source has.

All rasters live on the official *resized* map grid (pixels square in degree space, see
:mod:`skyvln_eval.avdn.imagery`), so a view's pixel corners index every layer alike.
xView maps give only the BGR image; synthetic city tiles also give a semantic class
layer, a landmark instance layer (with names) and a height layer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.avdn.constants import METERS_PER_DEGREE
from skyvln_eval.avdn.imagery import MapGeoref
from skyvln_eval.sensing import SemanticClass  # what a semantic camera reports, stored here

__all__ = ["Landmark", "LatLng", "SemanticClass", "WorldTile"]

LatLng = tuple[float, float]


@dataclass(frozen=True)
class Landmark:
    """A named landmark of a tile.

    ``landmark_id`` is its value in the instance layer; ``footprint`` its outline as
    ``(lat, lng)`` points; ``description`` how a person would describe it from above.
    """

    landmark_id: int
    name: str
    category: str
    description: str
    centre: LatLng
    footprint: tuple[LatLng, ...]
    height_m: float


@dataclass(frozen=True, eq=False)
class WorldTile:
    """One map: BGR image plus optional semantic, instance and height layers.

    ``semantic`` is uint8 (:class:`SemanticClass`), ``instance`` uint16 landmark ids
    (0 = none), ``height_m`` float32 metres above ground; all ``(H, W)`` like ``bgr``.
    """

    map_name: str
    georef: MapGeoref
    bgr: NDArray[np.uint8]
    semantic: NDArray[np.uint8] | None = None
    instance: NDArray[np.uint16] | None = None
    height_m: NDArray[np.float32] | None = None
    landmarks: tuple[Landmark, ...] = ()

    @property
    def metres_per_pixel(self) -> float:
        return self.georef.lat_ratio * METERS_PER_DEGREE

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.bgr.shape[0]), int(self.bgr.shape[1])

    @property
    def has_layers(self) -> bool:
        """Whether semantic, instance and height layers are available (synthetic tiles)."""
        return self.semantic is not None and self.instance is not None and self.height_m is not None

    def landmark(self, landmark_id: int) -> Landmark:
        for item in self.landmarks:
            if item.landmark_id == landmark_id:
                return item
        raise KeyError(f"map {self.map_name} has no landmark with id {landmark_id}")
