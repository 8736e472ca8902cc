"""Synthetic city tiles that look like urban satellite imagery, with semantic, instance
and height layers and named landmarks. ``generate_city(seed, ...)`` is deterministic.
"""

from skyvln_eval.worlds.city.generate import CityTile, generate_city

__all__ = ["CityTile", "generate_city"]
