"""Map georeference, GPS <-> pixel conversion, map loading and the observation warp.

The geo-reference of an AVDN map comes from the annotation record, never from the TIFF.
The official loader first resizes the image width to ``int(W * lng_ratio / lat_ratio)``
(height kept, INTER_AREA) so that a pixel spans ``lat_ratio`` degrees on both axes; all
pixel coordinates here refer to that resized image.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyvln_eval.avdn.constants import MAX_MAP_SIDE_PX, OBSERVATION_SIZE_PX
from skyvln_eval.errors import MapImageError, MapShapeError

LatLng = tuple[float, float]

#: How far (relative, plus one pixel for the resize's truncation) a width-resized map's
#: size may be from the one its record's bounds give in ``lat_ratio``-degree pixels. The
#: ratios are degrees per image pixel and the bounds the image's corners, so the two
#: agree up to rounding; a wrong ratio or map is off by far more (10% and more). 5%, not
#: less: the real release's images could not be measured here, and a check this loose
#: cannot call its good records bad on a difference of a few pixels' convention.
GEOREF_SIZE_TOLERANCE = 0.05


@dataclass(frozen=True)
class MapGeoref:
    """Geo-reference of one map image, as given by every record on that map.

    ``gps_botm_left`` and ``gps_top_right`` are the south-west and north-east corners
    ``(lat, lng)``; ``lng_ratio`` and ``lat_ratio`` are degrees per *original* pixel.
    """

    gps_botm_left: LatLng
    gps_top_right: LatLng
    lng_ratio: float
    lat_ratio: float

    def resized_width(self, original_width_px: int) -> int:
        """Width of the official width-resized image, pixels."""
        return int(original_width_px * self.lng_ratio / self.lat_ratio)

    def described_shape_px(self) -> tuple[float, float]:
        """(height, width) of the width-resized map the bounds span in pixels of
        ``lat_ratio`` degrees: the shape the map image must resize to (pixels)."""
        (lat0, lng0), (lat1, lng1) = self.gps_botm_left, self.gps_top_right
        return (lat1 - lat0) / self.lat_ratio, (lng1 - lng0) / self.lat_ratio

    def contains(self, points: ArrayLike) -> Any:
        """Whether ``[lat, lng]`` points lie strictly inside the map box (official test)."""
        p = np.asarray(points, dtype=np.float64)
        (lat0, lng0), (lat1, lng1) = self.gps_botm_left, self.gps_top_right
        inside = (p[..., 0] > lat0) & (p[..., 0] < lat1) & (p[..., 1] > lng0) & (p[..., 1] < lng1)
        return inside if inside.ndim else bool(inside)

    def gps_to_pixel_float(self, points: ArrayLike) -> NDArray[np.float64]:
        """``[lat, lng]`` to sub-pixel ``[x, y]`` in the resized image (x east, y south)."""
        p = np.asarray(points, dtype=np.float64)
        x = (p[..., 1] - self.gps_botm_left[1]) / self.lat_ratio
        y = (self.gps_top_right[0] - p[..., 0]) / self.lat_ratio
        return np.stack([x, y], axis=-1)

    def gps_to_pixel(self, points: ArrayLike) -> NDArray[np.int64]:
        """``[lat, lng]`` to integer ``[x, y]`` pixels, rounded half-to-even as officially.

        ``lat_ratio`` is used for both axes on purpose: the width was resized to make
        pixels square in degrees.
        """
        return np.rint(self.gps_to_pixel_float(points)).astype(np.int64)

    def pixel_to_gps(self, pixels: ArrayLike) -> NDArray[np.float64]:
        """Sub-pixel ``[x, y]`` of the resized image back to ``[lat, lng]``."""
        p = np.asarray(pixels, dtype=np.float64)
        lat = self.gps_top_right[0] - p[..., 1] * self.lat_ratio
        lng = self.gps_botm_left[1] + p[..., 0] * self.lat_ratio
        return np.stack([lat, lng], axis=-1)


def map_image_path(images_dir: str | Path, map_name: str) -> Path:
    """Path of a map's GeoTIFF: ``<images_dir>/<map_name>.tif``."""
    return Path(images_dir) / f"{map_name}.tif"


def georef_misfit(georef: MapGeoref, map_shape_px: tuple[int, int]) -> tuple[str, str] | None:
    """(field, problem) when a map whose width-resized raster is ``map_shape_px`` (height,
    width) is not the image ``georef`` describes, else None.

    The height is the image's own, so it tests ``lat_ratio`` against the bounds; the width
    is ``int(W * lng_ratio / lat_ratio)``, so with ``lat_ratio`` right it tests ``lng_ratio``.
    """
    described = georef.described_shape_px()
    for axis, field, extent in ((0, "lat_ratio", "latitude"), (1, "lng_ratio", "longitude")):
        have, want = map_shape_px[axis], described[axis]
        if abs(have - want) > GEOREF_SIZE_TOLERANCE * want + 1.0:
            side = "high" if axis == 0 else "wide once width-resized (W x lng_ratio / lat_ratio)"
            return field, (
                f"the map image is {have} px {side}, but the record's {extent} bounds span "
                f"{want:.1f} px of lat_ratio degrees: {field} ({getattr(georef, field)!r}) "
                "is not the bounds' extent per image pixel (or map_name names another map)"
            )
    return None


def resize_to_degree_grid(
    image: NDArray[Any], georef: MapGeoref, path: str = "<image>"
) -> NDArray[Any]:
    """The official width resize (INTER_AREA), making pixels square in degree space.

    Raises :class:`MapShapeError` naming ``path`` for a width below 1 px (OpenCV's own
    error, a traceback) or above ``MAX_MAP_SIDE_PX`` (gigabytes).
    """
    height, width = image.shape[:2]
    new_width = georef.resized_width(width)
    if new_width == width:
        return image
    if not 1 <= new_width <= MAX_MAP_SIDE_PX:
        raise MapShapeError(
            path,
            f"lng_ratio / lat_ratio ({georef.lng_ratio!r} / {georef.lat_ratio!r}) resize this "
            f"{width} px wide image to {new_width} px (1 to {MAX_MAP_SIDE_PX} allowed): the "
            "records' ratios do not describe this image (`skyvln-eval validate` names them)",
            (height, new_width),
        )
    return cv2.resize(image, (new_width, height), interpolation=cv2.INTER_AREA)


def load_map_bgr(path: str | Path, georef: MapGeoref) -> NDArray[np.uint8]:
    """Read a map as 8-bit BGR and apply the official width resize.

    Raises :class:`MapImageError` naming the file when it is missing or not an image, and
    :class:`MapShapeError` when the record's ratios resize it to no usable width.
    """
    path = Path(path)
    if not path.is_file():
        raise MapImageError(str(path), "map image not found")
    try:
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise MapImageError(str(path), "not a readable image (OpenCV could not decode it)")
        return resize_to_degree_grid(image, georef, str(path))
    except cv2.error as exc:  # a damaged file OpenCV half-reads: its text, not a traceback
        # Out of memory is the machine's, not the file's.
        if getattr(exc, "code", None) == cv2.Error.StsNoMem:
            raise MemoryError(f"{path}: OpenCV ran out of memory reading it") from None
        reason = str(exc).strip().splitlines()[-1]
        raise MapImageError(str(path), f"OpenCV could not read it ({reason})") from None


def observation_transform(corners: ArrayLike, georef: MapGeoref, size_px: int) -> Any:
    """Perspective matrix taking a view quad (in map pixels) to a heading-up square.

    Corners are rounded to whole pixels first, as the official code does; front-left maps
    to (0, 0), front-right to (size-1, 0), back-right to (size-1, size-1), back-left to
    (0, size-1).
    """
    src = georef.gps_to_pixel(corners).astype(np.float32)
    last = float(size_px - 1)
    dst = np.array([[0, 0], [last, 0], [last, last], [0, last]], dtype=np.float32)
    return cv2.getPerspectiveTransform(src, dst)


def observe_view(
    map_image: NDArray[Any],
    corners: ArrayLike,
    georef: MapGeoref,
    size_px: int = OBSERVATION_SIZE_PX,
    interpolation: int = cv2.INTER_LINEAR,
) -> NDArray[Any]:
    """The official observation: the view quad warped to ``size x size``, front at the top.

    Works on any raster in the resized map grid (BGR image, semantic or height layer; pass
    ``cv2.INTER_NEAREST`` for label layers). Outside the map is 0 (black).
    """
    matrix = observation_transform(corners, georef, size_px)
    return cv2.warpPerspective(
        map_image,
        matrix,
        (size_px, size_px),
        flags=interpolation,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    )
