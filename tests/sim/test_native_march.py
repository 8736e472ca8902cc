"""The ray march in C against the reference march (bit for bit), its cache, and the numpy
fallback without a C compiler."""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from skyvln_eval import cbuild
from skyvln_eval.cbuild import compiler
from skyvln_eval.sensing import plane_rays
from skyvln_eval.sim import native_march
from skyvln_eval.sim.camera import (
    CameraConfig,
    CameraPose,
    _image_plane,
    _nudges,
    camera_basis,
    hit_coordinates,
    render_views,
)
from skyvln_eval.sim.march import march, march_reference
from skyvln_eval.worlds.layers import height_decimetres, height_from_decimetres
from skyvln_eval.worlds.tile import WorldTile
from tests.sim.test_camera_equivalence import seeded_city

needs_cc = pytest.mark.skipif(compiler() is None, reason="no C compiler ($CC or gcc)")


@pytest.fixture
def fresh_library() -> Iterator[None]:
    """The library loaded again under the test's conditions, and again after it."""
    native_march.reset()
    yield
    native_march.reset()


def decision(
    world: WorldTile, rng: np.random.Generator, config: CameraConfig
) -> tuple[np.ndarray, np.ndarray]:
    """A seeded position (some off the map, some low) and five views' rays from it."""
    x, y = rng.uniform(-50.0, 650.0, size=2)
    z = float(rng.uniform(5.0, 170.0))
    yaw = float(rng.uniform(-math.pi, math.pi))
    poses = [
        CameraPose(float(x), float(y), z, yaw + 1.3 * k, float(pitch))
        for k, pitch in enumerate((0, 20, 45, 60, 90))
    ]
    plane = _image_plane(config)
    rays = np.stack([np.moveaxis(plane_rays(pose, *plane), -1, 0) for pose in poses], axis=1)
    return np.array([x, y, z]), np.moveaxis(rays, 0, -1)


def same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and np.array_equal(a, b)


@needs_cc
@pytest.mark.parametrize("lanes", [True, False], ids=["lanes", "one-ray"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_native_depths_are_the_reference_depths_bit_for_bit(seed: int, lanes: bool) -> None:
    """Both marches in C (eight rays at a time where the CPU has AVX2, one at a time)
    against the reference; widths that are not a multiple of eight leave rays to the
    one-ray march in every tile row."""
    world = seeded_city(seed)
    rng = np.random.default_rng(200 + seed)
    assert native_march.available()
    configs = [CameraConfig(width_px=96, height_px=80), CameraConfig(width_px=90, height_px=70)]
    for config in configs * 4 + [CameraConfig()]:
        origin, rays = decision(world, rng, config)
        levels = config.height_levels
        native = native_march.march_native(world, origin, rays, levels, lanes=lanes)
        reference = np.stack([march_reference(world, origin, r, levels) for r in rays])
        assert same(native, reference), (seed, origin)


@needs_cc
def test_a_layer_with_heights_below_the_ground_gets_the_reference_depths() -> None:
    """Where every neighbour's cell is 0 the march takes the sample as 0 without reading
    the layer, which holds only when no height is negative: here some are (pits around
    the blocks' corners), and the depths must still be the reference's."""
    city = seeded_city(7)
    heights = city.height_m.copy()
    heights[::37, ::41] = -3.0
    world = dataclasses.replace(city, map_name="pits", height_m=heights)
    rng = np.random.default_rng(7)
    config = CameraConfig(width_px=96, height_px=80)
    for _ in range(6):
        origin, rays = decision(world, rng, config)
        reference = np.stack(
            [march_reference(world, origin, r, config.height_levels) for r in rays]
        )
        for lanes in (True, False):
            native = native_march.march_native(world, origin, rays, config.height_levels, lanes)
            assert same(native, reference), (origin, lanes)


def in_decimetres(world: WorldTile) -> WorldTile:
    """The world with its heights as the dataset stores them: whole decimetres, read back
    as ``float32(d) / 10`` (``worlds.layers``)."""
    heights = height_from_decimetres(height_decimetres(world.height_m))
    return dataclasses.replace(world, height_m=heights)


@needs_cc
@pytest.mark.parametrize("seed", [3, 4])
def test_a_layer_of_whole_decimetres_is_marched_from_them_to_the_reference_depths(
    seed: int,
) -> None:
    """Heights of whole decimetres are gathered as 16 bits and divided by 10 in C: the
    depths are the reference's, and those of the same march reading the float heights."""
    world = in_decimetres(seeded_city(seed))
    assert native_march.decimetres(world) is not None
    rng = np.random.default_rng(300 + seed)
    for config in [CameraConfig(width_px=96, height_px=80)] * 4 + [CameraConfig()]:
        origin, rays = decision(world, rng, config)
        levels = config.height_levels
        from_decimetres = native_march.march_native(world, origin, rays, levels)
        reference = np.stack([march_reference(world, origin, r, levels) for r in rays])
        assert same(from_decimetres, reference), (seed, origin)
        from_floats = native_march.march_native(world, origin, rays, levels, whole_decimetres=False)
        assert same(from_floats, reference)


def test_only_heights_that_are_whole_decimetres_bit_for_bit_are_read_as_decimetres() -> None:
    """The decimetres are padded by one element each side; a height between decimetres, a
    negative zero (equal to 0, not the same bits), a negative, NaN or one beyond 16 bits
    keeps the float layer."""
    world = in_decimetres(seeded_city(5))
    padded = native_march.decimetres(world)
    assert padded is not None and padded.dtype == np.uint16
    assert padded[0] == 0 and padded[-1] == 0
    np.testing.assert_array_equal(padded[1:-1].astype(np.float32) / 10.0, world.height_m.ravel())
    assert padded[1:-1].max() > 1000  # the 150 m blocks: beyond 8 bits
    assert native_march.decimetres(seeded_city(5)) is None  # uniform draws, not decimetres
    for bad in (0.05, -0.0, -0.1, np.nan, 6553.6):
        heights = world.height_m.copy()
        heights[17, 23] = bad
        assert native_march._whole_decimetres(heights) is None, bad
    assert native_march._whole_decimetres(np.full((3, 3), 6553.5, np.float32)) is not None


@needs_cc
def test_native_views_are_the_numpy_views_in_every_layer() -> None:
    world = seeded_city(4)
    rng = np.random.default_rng(4)
    config = CameraConfig(width_px=96, height_px=80)
    for _ in range(4):
        x, y = rng.uniform(-50.0, 650.0, size=2)
        poses = [
            CameraPose(float(x), float(y), 60.0, 0.7 * k, float(pitch))
            for k, pitch in enumerate((0, 45, 90))
        ]
        native = render_views(world, poses, config, method="native")
        numpy_views = render_views(world, poses, config, method="fast")
        for a, b in zip(native, numpy_views, strict=True):
            assert same(a.depth_m, b.depth_m) and same(a.rgb, b.rgb)
            assert a.semantic is not None and b.semantic is not None
            assert same(a.semantic, b.semantic)
            assert a.instance is not None and b.instance is not None
            assert same(a.instance, b.instance)


@needs_cc
@pytest.mark.parametrize("max_depth_m", [500.0, 80.3])
def test_rays_and_hit_coordinates_in_c_are_numpys_bit_for_bit(max_depth_m: float) -> None:
    """The rays and the map pixels each view looks up, in C and in numpy (the reference):
    sky rays, depths beyond the range (one not a float32) and positions off the map."""
    world = seeded_city(8)
    rng = np.random.default_rng(8)
    config = CameraConfig(width_px=90, height_px=70, max_depth_m=max_depth_m)
    plane = _image_plane(config)
    for _ in range(4):
        origin, along_last = decision(world, rng, config)
        rays = np.ascontiguousarray(np.moveaxis(along_last, -1, 0))
        poses = [
            CameraPose(*origin, float(rng.uniform(-4.0, 4.0)), float(pitch))
            for pitch in (0, 20, 45, 60, 90)
        ]
        bases = np.array([np.concatenate(camera_basis(pose)) for pose in poses])
        expected = np.stack(
            [np.moveaxis(plane_rays(pose, *plane), -1, 0) for pose in poses], axis=1
        )
        in_c = native_march.native_rays(bases, *plane)
        assert in_c is not None and same(in_c, expected)
        depth = native_march.march_native(world, origin, along_last, config.height_levels)
        assert np.isinf(depth).any() and (depth[np.isfinite(depth)] > max_depth_m).any()
        nudge = np.stack([_nudges(config, p.pitch_deg, world.metres_per_pixel) for p in poses])
        reference = hit_coordinates(world, origin, rays, depth, nudge, max_depth_m)
        coords = native_march.native_hit_coords(world, origin, rays, depth, nudge, max_depth_m)
        assert coords is not None
        for a, b in zip(coords, reference, strict=True):
            assert same(a, b)


def test_a_rays_nudge_does_not_depend_on_the_yaw() -> None:
    """One map pixel along each pixel's ray, made once per pitch: what the ray's own
    horizontal length gives at any yaw (to rounding)."""
    config = CameraConfig(width_px=64, height_px=48)
    mpp = 0.4
    for pitch in (0.0, 33.0, 60.0, 90.0):
        nudge = _nudges(config, pitch, mpp)
        for yaw in np.linspace(-math.pi, math.pi, 7):
            rays = plane_rays(CameraPose(0.0, 0.0, 50.0, float(yaw), pitch), *_image_plane(config))
            horizontal = np.maximum(np.hypot(rays[..., 0], rays[..., 1]), 1e-6)
            np.testing.assert_allclose(nudge, np.minimum(mpp / horizontal, 2.0), rtol=1e-12)


@needs_cc
def test_threads_march_at_once_and_get_the_same_depths() -> None:
    world = seeded_city(5)
    config = CameraConfig(width_px=64, height_px=64)
    rng = np.random.default_rng(5)
    cases = [decision(world, rng, config) for _ in range(8)]
    alone = [native_march.march_native(world, o, r, config.height_levels) for o, r in cases]
    with ThreadPoolExecutor(4) as pool:
        together = list(
            pool.map(lambda c: native_march.march_native(world, *c, config.height_levels), cases)
        )
    assert all(same(a, b) for a, b in zip(alone, together, strict=True))


@needs_cc
def test_the_library_is_built_once_into_the_cache(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fresh_library: None
) -> None:
    monkeypatch.setenv("SKYVLN_EVAL_CACHE", str(tmp_path))
    assert native_march.available()
    (built,) = (tmp_path / "native").glob("march-*.so")
    stamp = built.stat().st_mtime_ns
    native_march.reset()

    def no_build(*args: object) -> None:
        raise AssertionError("the cached library should have been loaded")

    monkeypatch.setattr(cbuild, "compile_library", no_build)  # where every library is built
    assert native_march.available()
    assert built.stat().st_mtime_ns == stamp


def test_without_a_compiler_the_numpy_march_runs_with_one_warning(
    monkeypatch: pytest.MonkeyPatch, fresh_library: None
) -> None:
    monkeypatch.setattr(native_march, "compiler", lambda: None)
    world = seeded_city(6)
    config = CameraConfig(width_px=48, height_px=40)
    origin, rays = decision(world, np.random.default_rng(6), config)
    with pytest.warns(RuntimeWarning, match="no C compiler"):
        depth = native_march.march_native(world, origin, rays, config.height_levels)
    assert same(depth, march(world, origin, rays, config.height_levels))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a second march says nothing more
        native_march.march_native(world, origin, rays, config.height_levels)
    assert not native_march.available()


def test_a_failed_build_falls_back_with_a_warning(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fresh_library: None
) -> None:
    monkeypatch.setenv("SKYVLN_EVAL_CACHE", str(tmp_path))
    monkeypatch.setattr(native_march, "CFLAGS", ("-not-a-flag-of-any-compiler",))
    with pytest.warns(RuntimeWarning, match="building the compiled ray march failed"):
        assert not native_march.available()
