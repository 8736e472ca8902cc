"""The ray march of :mod:`.march` compiled from C (``native/march.c``), loaded with ctypes.

:func:`march_native` gives the depths of :func:`~.march.march_reference`, bit for bit, in
one pass over the rays: each ray is sampled per level from its tile's start level (the
bound of :func:`~.march.march`, computed in C too) until it meets the surface. The height
layer is read only where it can matter: a level where the finest max-pyramid cells under
the ray are below the level is passed, and where those cells are all 0 (open ground, on a
layer without negative heights) the sample is 0. On CPUs with AVX2 eight adjacent rays of
a tile row are marched together, level by level (they meet the surface within a level of
each other), with their heights gathered at once (``benchmarks/render.py`` measures it
against the numpy march); a layer of whole decimetres (the dataset's, :func:`decimetres`)
is gathered there as 16-bit decimetres, two neighbours per read, and divided by 10 as numpy
made its heights: the same values, and about a tenth off the march's time, since the
gathers are what it waits for.
The library also makes the views' rays (:func:`native_rays`) and the map pixel each hit
shows (:func:`native_hit_coords`), the numpy of :mod:`.camera` in one pass each.
The C code does the float operations numpy and ``cv2.remap`` do, in the same
order and precision; whether ``cv2.remap`` fuses its multiply-adds depends on the CPU, so
on load the library's bilinear lookup is checked against ``cv2.remap`` on a probe and told
which to do (a library that matches neither is not used).

The library is built with the system's C compiler on first use and cached on disk
(:mod:`skyvln_eval.cbuild`; key: source, compiler, flags). Without a compiler, or if the
build or the probe fails, :func:`march_native` runs :func:`~.march.march` (numpy) and a
one-line warning says so once per process. The C function keeps no state and ctypes
releases the GIL while it runs, so episode threads render in parallel.
"""

from __future__ import annotations

import ctypes
import logging
import subprocess
import threading
import warnings
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from skyvln_eval.cbuild import cached_library, compiler
from skyvln_eval.sim.march import (
    FloatImage,
    _levels,
    _pyramid,
    map_scale,
    march,
    max_height_m,
    min_height_m,
)
from skyvln_eval.worlds.layers import height_from_decimetres
from skyvln_eval.worlds.tile import WorldTile

log = logging.getLogger(__name__)

SOURCE = Path(__file__).with_name("native") / "march.c"
#: No contraction of a * b + c into one rounding, no fast-math: the float operations stay
#: the ones written (numpy's); the fused ones are explicit ``fmaf`` calls.
CFLAGS = ("-O3", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math")

_f64 = np.ctypeslib.ndpointer(np.float64, flags="C_CONTIGUOUS")
_f32 = np.ctypeslib.ndpointer(np.float32, flags="C_CONTIGUOUS")
_i64, _double = ctypes.c_int64, ctypes.c_double


@dataclass(frozen=True)
class NativeMarch:
    """The loaded library's functions and whether its lookups fuse multiply-adds."""

    march: Any
    sample: Any
    rays: Any
    hit_coords: Any
    fused: bool


_lock = threading.Lock()
_state: dict[str, NativeMarch | None] = {}
_warned = False
_PAIRS: weakref.WeakKeyDictionary[WorldTile, NDArray[np.float32]] = weakref.WeakKeyDictionary()
_DECIMETRES: weakref.WeakKeyDictionary[WorldTile, NDArray[np.uint16] | None] = (
    weakref.WeakKeyDictionary()
)
#: Heights checked per pass when looking for whole decimetres (a block that stays in cache).
_CHUNK = 1 << 18


def native() -> NativeMarch | None:
    """The compiled march (built or loaded once per process), or ``None`` if unavailable."""
    with _lock:
        if "march" not in _state:
            _state["march"] = _load_native()
        return _state["march"]


def available() -> bool:
    return native() is not None


def reset() -> None:
    """Forget the loaded library and the warning (tests load it again under new conditions)."""
    global _warned
    with _lock:
        _state.clear()
        _warned = False


def _load_native() -> NativeMarch | None:
    cc = compiler()
    if cc is None:
        _warn_once("no C compiler found ($CC or gcc)")
        return None
    try:
        loaded = _bind(ctypes.CDLL(str(cached_library("march", SOURCE.read_text(), cc, CFLAGS))))
    except (OSError, AttributeError, subprocess.CalledProcessError) as error:
        detail = getattr(error, "stderr", b"") or b""
        log.debug("building the ray march failed: %s", detail.decode(errors="replace"))
        _warn_once(f"building the compiled ray march failed ({error})")
        return None
    fused = _matching_mode(loaded)
    if fused is None:
        _warn_once("the compiled ray march does not reproduce cv2.remap on this machine")
        return None
    return NativeMarch(loaded.march, loaded.sample, loaded.rays, loaded.hit_coords, fused)


def _warn_once(reason: str) -> None:
    global _warned
    if not _warned:
        warnings.warn(
            f"{reason}: camera rays are marched in numpy (slower)", RuntimeWarning, stacklevel=4
        )
        _warned = True


def _bind(library: ctypes.CDLL) -> NativeMarch:
    march_fn = library.skyvln_march
    march_fn.restype = ctypes.c_int
    march_fn.argtypes = [
        _f64, _i64, _i64, _i64,  # rays (3, V, H, W), views, height, width
        _double, _double, _double, _double, _double,  # origin x, y, z, mpp, top_m
        _f32, _i64, _i64, ctypes.c_void_p,  # heights, rows, cols, decimetres or NULL
        _f32, _i64, _i64, _i64, _f32,  # pyramid, levels, cells_y, cells_x, cell pairs
        _f64, _f32, _f32, _i64,  # z_levels, ks, zs, levels
        ctypes.c_int, ctypes.c_int, ctypes.c_int, _f32,  # fused, heights >= 0, lanes, depth
    ]  # fmt: skip
    sample_fn = library.skyvln_sample
    sample_fn.restype = ctypes.c_int
    sample_fn.argtypes = [_f32, _i64, _i64, _f32, _f32, _i64, ctypes.c_int, _f32]
    rays_fn = library.skyvln_rays
    rays_fn.restype = ctypes.c_int
    rays_fn.argtypes = [_f64, _f64, _i64, _f64, _i64, _f64]
    coords_fn = library.skyvln_hit_coords
    coords_fn.restype = ctypes.c_int
    coords_fn.argtypes = [
        _f64, _f32, _f64, _i64,  # rays (3, n), depths, nudges, n
        _double, _double, _double, _double, ctypes.c_float,  # origin x, y, mpp, top_m, range
        _f32, _f32, _f32,  # px, py, depths beyond the range made inf
    ]  # fmt: skip
    return NativeMarch(march_fn, sample_fn, rays_fn, coords_fn, fused=True)


def _matching_mode(loaded: NativeMarch) -> bool | None:
    """Whether the library must fuse multiply-adds to sample as ``cv2.remap`` does here
    (``None``: it matches in neither mode). The probe covers the layer's edges and beyond."""
    rng = np.random.default_rng(0)
    layer = (rng.random((37, 53)) * 100.0).astype(np.float32)
    px = rng.uniform(-3.0, 56.0, 4096).astype(np.float32)
    py = rng.uniform(-3.0, 40.0, 4096).astype(np.float32)
    expected = cv2.remap(
        layer,
        px.reshape(64, 64),
        py.reshape(64, 64),
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0.0,
    ).ravel()
    for fused in (True, False):
        out = np.empty_like(px)
        loaded.sample(layer, *layer.shape, px, py, len(px), int(fused), out)
        if np.array_equal(out, expected):
            return fused
    return None


def _cell_pairs(world: WorldTile) -> NDArray[np.float32]:
    """Per pair of finest pyramid cell rows and columns, the max over their 2 x 2 cells:
    entry ``(a + 1, b + 1)`` covers cells ``a..a+1`` by ``b..b+1`` (cells beyond the layer
    are 0), so one read bounds a bilinear sample's four neighbours. Made once per world."""
    if world not in _PAIRS:
        cells = _pyramid(world)[0]
        padded = np.pad(cells, 1)
        pairs = np.maximum(
            np.maximum(padded[:-1, :-1], padded[1:, :-1]),
            np.maximum(padded[:-1, 1:], padded[1:, 1:]),
        )
        _PAIRS[world] = np.ascontiguousarray(pairs, dtype=np.float32)
    return _PAIRS[world]


def decimetres(world: WorldTile) -> NDArray[np.uint16] | None:
    """The height layer as whole decimetres, padded with one element before and after (the
    C code's pair reads at the layer's first and last pixel), if every height is
    ``float32(d) / 10`` bit for bit for a ``d`` in 0..65535, as a layer read from the
    dataset's ``height_dm.png`` is (:func:`~skyvln_eval.worlds.layers.height_from_decimetres`);
    else ``None``. Made once per world (a few ms) and held
    while the world is (12.5 MB for a 2500 x 2500 map)."""
    if world not in _DECIMETRES:
        _DECIMETRES[world] = _whole_decimetres(world.height_m)
    return _DECIMETRES[world]


def _whole_decimetres(height_m: NDArray[np.float32] | None) -> NDArray[np.uint16] | None:
    if height_m is None or height_m.dtype != np.float32 or height_m.size == 0:
        return None
    flat = np.ascontiguousarray(height_m).reshape(-1)
    padded = np.zeros(flat.size + 2, np.uint16)
    ten = np.float32(10.0)
    for start in range(0, flat.size, _CHUNK):
        heights = flat[start : start + _CHUNK]
        rounded = np.rint(heights * ten)
        if not (np.all(rounded >= 0.0) and np.all(rounded <= 65535.0)):  # NaN fails too
            return None
        codes = rounded.astype(np.uint16)
        # Compared as bits: -0.0 or a height between decimetres is not one.
        if not np.array_equal(
            height_from_decimetres(codes).view(np.uint32), heights.view(np.uint32)
        ):
            return None
        padded[1 + start : 1 + start + len(codes)] = codes
    return padded


def march_native(
    world: WorldTile,
    origin: NDArray[np.float64],
    rays: NDArray[np.float64],
    levels: int,
    lanes: bool = True,
    whole_decimetres: bool = True,
) -> FloatImage:
    """The depths of :func:`~.march.march_reference` for rays ``(V, H, W, 3)`` seen from one
    ``origin``, marched in C (in numpy by :func:`~.march.march` if the library is missing).
    ``lanes``: eight rays at a time on CPUs with AVX2 (the same depths; ``False`` marches
    one ray at a time, as on other CPUs). ``whole_decimetres``: the eight-ray march reads
    a layer of whole decimetres as its 16-bit :func:`decimetres` (the same depths;
    ``False`` reads the float heights)."""
    loaded = native()
    if loaded is None or world.height_m is None or max_height_m(world) <= 0.0:
        return march(world, origin, rays, levels)
    views, height, width = rays.shape[:3]
    # The C code reads each component contiguously: (3, V, H, W), as render_views builds it.
    components = np.ascontiguousarray(np.moveaxis(rays, -1, 0), dtype=np.float64)
    heights = np.ascontiguousarray(world.height_m, dtype=np.float32)
    pyramid = _pyramid(world)
    z_levels = _levels(world, origin, levels)
    # march_reference's per-level float32 values, rounded as numpy rounds them.
    ks = np.array([np.float32(z - origin[2]) for z in z_levels], np.float32)
    zs = z_levels.astype(np.float32)
    mpp, top_m = map_scale(world)
    depth = np.empty((views, height, width), np.float32)
    # Only the eight-ray march reads it; referenced here until the C code has.
    decimetre_layer = decimetres(world) if lanes and whole_decimetres else None
    loaded.march(
        components, views, height, width,
        float(origin[0]), float(origin[1]), float(origin[2]), mpp, top_m,
        heights, *heights.shape, _address_of_first(decimetre_layer),
        pyramid, *pyramid.shape, _cell_pairs(world),
        z_levels, ks, zs, len(z_levels),
        int(loaded.fused), int(min_height_m(world) >= 0.0), int(lanes), depth,
    )  # fmt: skip
    return depth


def _address_of_first(padded: NDArray[np.uint16] | None) -> int | None:
    """The address of a padded layer's first real element (``None``: NULL)."""
    return None if padded is None else padded.ctypes.data + padded.itemsize


def native_rays(
    bases: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64]
) -> NDArray[np.float64] | None:
    """The camera rays ``(3, V, H, W)`` of views with ``bases`` ``(V, 3, 3)`` (forward,
    right, up) over the image plane ``a``, ``b`` ``(H, W)``, as ``sensing.plane_rays`` computes
    them, bit for bit; ``None`` without the library."""
    if bases.shape[1:] not in ((3, 3), (9,)) or a.shape != b.shape:
        raise ValueError(f"native_rays: bases {bases.shape}, a {a.shape}, b {b.shape}")
    loaded = native()
    if loaded is None:
        return None
    views = len(bases)
    rays = np.empty((3, views, *a.shape))
    loaded.rays(
        np.ascontiguousarray(a, np.float64), np.ascontiguousarray(b, np.float64), a.size,
        np.ascontiguousarray(bases, np.float64), views, rays,
    )  # fmt: skip
    return rays


def native_hit_coords(
    world: WorldTile,
    origin: NDArray[np.float64],
    rays: NDArray[np.float64],
    depth: FloatImage,
    nudge: NDArray[np.float64],
    max_depth_m: float,
) -> tuple[FloatImage, FloatImage, FloatImage] | None:
    """``camera.hit_coordinates`` in one pass of C, bit for bit: for rays ``(3, ...)``,
    their depths and nudges ``(...)``, the map pixel each looks up (``px``, ``py``) and
    the depths with anything beyond ``max_depth_m`` made inf; ``None`` without the
    library."""
    # The C code reads 3 x depth.size ray components and depth.size nudges: check first.
    if rays.shape != (3, *depth.shape) or nudge.shape != depth.shape:
        raise ValueError(
            f"native_hit_coords: rays {rays.shape}, depth {depth.shape}, nudge {nudge.shape}"
        )
    loaded = native()
    if loaded is None:
        return None
    mpp, top_m = map_scale(world)
    rays = np.ascontiguousarray(rays, np.float64)
    depth = np.ascontiguousarray(depth, np.float32)
    nudge = np.ascontiguousarray(nudge, np.float64)
    px, py, out = (np.empty(depth.shape, np.float32) for _ in range(3))
    loaded.hit_coords(
        rays, depth, nudge, depth.size, float(origin[0]), float(origin[1]), mpp, top_m,
        max_depth_m, px, py, out,
    )  # fmt: skip
    return px, py, out
