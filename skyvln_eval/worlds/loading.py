"""Load the world of an episode: its map image and, for synthetic maps, its layers."""

from __future__ import annotations

from pathlib import Path

from skyvln_eval.avdn.constants import IMAGES_DIR
from skyvln_eval.avdn.imagery import MapGeoref, load_map_bgr, map_image_path
from skyvln_eval.errors import MapShapeError
from skyvln_eval.worlds.decoded import Rasters, decoded_rasters
from skyvln_eval.worlds.layers import (
    LAYER_FILES,
    LAYERS_FORMAT_VERSION,
    layers_dir,
    read_landmarks,
    read_layer_rasters,
)
from skyvln_eval.worlds.tile import WorldTile


def load_world(data_dir: str | Path, map_name: str, georef: MapGeoref) -> WorldTile:
    """The map as the official loader sees it (BGR, width-resized) plus any layers.

    Real xView maps give the image only; synthetic maps also give semantic, instance and
    height layers and landmarks, which must match the resized image's shape. The decoded
    rasters come from the machine's cache of decoded maps when it holds them (read-only
    arrays; see :mod:`skyvln_eval.worlds.decoded`).
    """
    path = map_image_path(Path(data_dir) / IMAGES_DIR, map_name)
    landmarks = read_landmarks(data_dir, map_name)
    sources = [path]
    if landmarks is not None:
        sources += [layers_dir(data_dir, map_name) / name for name in LAYER_FILES]

    def decode() -> Rasters:
        bgr = load_map_bgr(path, georef)
        if landmarks is None:
            return {"bgr": bgr}
        semantic, instance, height_m = read_layer_rasters(data_dir, map_name)
        if semantic.shape != bgr.shape[:2]:
            raise MapShapeError(
                str(path),
                f"world layers have shape {semantic.shape} but the resized map is "
                f"{bgr.shape[:2]}; the layers belong to another version of this map",
                (bgr.shape[0], bgr.shape[1]),
            )
        return {"bgr": bgr, "semantic": semantic, "instance": instance, "height_m": height_m}

    # The width resize depends on the ratios only; the layers' meaning on their version.
    recipe = {"resize": [georef.lng_ratio, georef.lat_ratio], "layers": LAYERS_FORMAT_VERSION}
    rasters = decoded_rasters(sources, recipe, decode)
    if landmarks is None:
        return WorldTile(map_name=map_name, georef=georef, bgr=rasters["bgr"])
    return WorldTile(
        map_name,
        georef,
        rasters["bgr"],
        rasters["semantic"],
        rasters["instance"],
        rasters["height_m"],
        landmarks,
    )
