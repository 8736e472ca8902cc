"""Worlds: map rasters an episode flies over.

:func:`load_world` gives an episode's map as the official loader sees it (xView GeoTIFF
or synthetic tile) with any semantic / instance / height layers; :mod:`.city` generates
synthetic city tiles and :mod:`.sample` the synthetic AVDN-format dataset built from them.
"""

from skyvln_eval.worlds.loading import load_world
from skyvln_eval.worlds.tile import Landmark, SemanticClass, WorldTile

__all__ = ["Landmark", "SemanticClass", "WorldTile", "load_world"]
