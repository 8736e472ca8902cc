"""Synthetic city tiles: deterministic, with consistent semantic, instance and height layers."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from skyvln_eval.worlds import SemanticClass
from skyvln_eval.worlds.city import generate_city


@pytest.fixture(scope="module")
def tile():
    return generate_city(7, 1000.0, 900.0, 0.5)


def digest(*arrays: np.ndarray) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def test_same_seed_same_pixels_other_seed_other_city(tile) -> None:
    again = generate_city(7, 1000.0, 900.0, 0.5)
    c = tile.canvas
    assert digest(c.bgr, c.semantic, c.instance, c.height) == digest(
        again.canvas.bgr, again.canvas.semantic, again.canvas.instance, again.canvas.height
    )
    other = generate_city(8, 1000.0, 900.0, 0.5)
    assert digest(c.bgr) != digest(other.canvas.bgr)


def test_raster_size_follows_metres_per_pixel(tile) -> None:
    assert tile.canvas.bgr.shape == (1800, 2000, 3)
    assert (
        tile.canvas.semantic.shape
        == tile.canvas.instance.shape
        == tile.canvas.height.shape
        == (1800, 2000)
    )


def test_layers_are_consistent(tile) -> None:
    c = tile.canvas
    present = set(np.unique(c.semantic).tolist())
    for cls in (
        SemanticClass.ROAD,
        SemanticClass.BUILDING,
        SemanticClass.GRASS,
        SemanticClass.TREE,
        SemanticClass.VEHICLE,
    ):
        assert cls in present, cls
    buildings = c.semantic == SemanticClass.BUILDING
    assert (c.height[buildings] >= 4.0).mean() > 0.99  # roofs stand above the ground
    roads = c.semantic == SemanticClass.ROAD
    assert c.height[roads].max() == 0.0
    ids = {lm.landmark_id for lm in tile.plan.landmarks}
    in_raster = set(np.unique(c.instance).tolist()) - {0}
    assert in_raster <= ids
    assert len(in_raster) >= 0.8 * len(ids)


def test_every_tile_has_named_landmarks_of_many_kinds(tile) -> None:
    categories = {lm.category for lm in tile.plan.landmarks}
    assert {"restaurant", "church", "gas_station", "park"} <= categories
    assert len({lm.name for lm in tile.plan.landmarks}) == len(tile.plan.landmarks)
    assert all(lm.description for lm in tile.plan.landmarks)


def test_road_graph_is_connected_and_routable(tile) -> None:
    import networkx as nx

    graph = tile.plan.graph
    assert graph.number_of_nodes() > 10
    assert nx.is_connected(graph)
    assert all(data["length_m"] > 0 for _, _, data in graph.edges(data=True))


def test_imagery_looks_like_imagery(tile) -> None:
    bgr = tile.canvas.bgr.astype(np.float32)
    # Texture and noise: no large flat areas of a single exact colour.
    assert bgr.std() > 20
    grass = tile.canvas.semantic == SemanticClass.GRASS
    green = bgr[grass]
    assert (green[:, 1] > green[:, 2]).mean() > 0.9  # grass is greener than red
