"""Load the world of an episode: its map image and, for synthetic maps, its layers."""

from __future__ import annotations

from pathlib import Path

from skyvln_eval.avdn.constants import IMAGES_DIR
from skyvln_eval.avdn.imagery import MapGeoref, load_map_bgr, map_image_path
from skyvln_eval.errors import MapImageError
from skyvln_eval.worlds.layers import read_world_layers
from skyvln_eval.worlds.tile import WorldTile


def load_world(data_dir: str | Path, map_name: str, georef: MapGeoref) -> WorldTile:
    """The map as the official loader sees it (BGR, width-resized) plus any layers.

    Real xView maps give the image only; synthetic maps also give semantic, instance and
    height layers and landmarks, which must match the resized image's shape.
    """
    path = map_image_path(Path(data_dir) / IMAGES_DIR, map_name)
    bgr = load_map_bgr(path, georef)
    layers = read_world_layers(data_dir, map_name)
    if layers is None:
        return WorldTile(map_name=map_name, georef=georef, bgr=bgr)
    semantic, instance, height, landmarks = layers
    if semantic.shape != bgr.shape[:2]:
        raise MapImageError(
            str(path),
            f"world layers have shape {semantic.shape} but the resized map is {bgr.shape[:2]}; "
            "the layers belong to another version of this map",
        )
    return WorldTile(map_name, georef, bgr, semantic, instance, height, landmarks)
