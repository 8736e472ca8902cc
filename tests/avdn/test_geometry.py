"""Official geometry: centres, edges, hull-IoU, strict containment, pixels and the warp."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from skyvln_eval.avdn import (
    METERS_PER_DEGREE,
    MapGeoref,
    degrees_to_metres,
    distance_m,
    hull_iou,
    load_map_bgr,
    metres_to_degrees,
    observe_view,
    point_in_view_strict,
    resize_to_degree_grid,
    view_centre,
    view_edge_m,
    view_from_pose,
)
from skyvln_eval.errors import MapImageError, MapShapeError


def square(x0: float, y0: float, side: float) -> np.ndarray:
    """An axis-aligned square as a view, corners FL, FR, BR, BL with north up ([lat, lng])."""
    return np.array([[y0 + side, x0], [y0 + side, x0 + side], [y0, x0 + side], [y0, x0]])


def test_degrees_and_metres_use_111300() -> None:
    assert degrees_to_metres(1.0) == 111_300.0
    assert metres_to_degrees(111_300.0) == 1.0
    # No cos(latitude): one degree of longitude is 111.3 km at 60 degrees north too.
    assert distance_m([60.0, 10.0], [60.0, 11.0]) == pytest.approx(111_300.0)


def test_centre_and_edge() -> None:
    view = square(40.0, 30.0, 0.001)
    assert np.allclose(view_centre(view), [30.0005, 40.0005])
    assert view_edge_m(view) == pytest.approx(111.3)
    stacked = np.stack([view, square(40.0, 30.0, 0.002)])
    assert np.allclose(view_edge_m(stacked), [111.3, 222.6])


def test_view_from_pose_is_square_with_the_given_edge() -> None:
    view = view_from_pose((30.0, 40.0), 37.0, 150.0)
    sides = np.linalg.norm(view - np.roll(view, -1, axis=0), axis=1) * METERS_PER_DEGREE
    assert np.allclose(sides, 150.0)
    assert np.allclose(view_centre(view), [30.0, 40.0])


def test_hull_iou_hand_computed() -> None:
    a = square(0.0, 0.0, 1.0)
    assert hull_iou(a, a) == pytest.approx(1.0)
    assert hull_iou(a, square(5.0, 5.0, 1.0)) == 0.0
    assert hull_iou(a, square(1.0, 0.0, 1.0)) == 0.0  # touching edge: no area in common
    # Half overlap along one axis: intersection 0.5, hull = union = 1.5.
    assert hull_iou(a, square(0.5, 0.0, 1.0)) == pytest.approx(1 / 3)
    # Diagonal offset: intersection 0.25, union 1.75 but hull 2.0.
    diagonal = square(0.5, 0.5, 1.0)
    assert hull_iou(a, diagonal) == pytest.approx(0.125)
    union_iou = 0.25 / 1.75
    assert hull_iou(a, diagonal) < union_iou
    # A view inside a bigger one: intersection = small area, hull = big area.
    assert hull_iou(square(0.0, 0.0, 2.0), square(0.5, 0.5, 1.0)) == pytest.approx(0.25)


def test_hull_iou_is_vectorised() -> None:
    a = np.stack([square(0.0, 0.0, 1.0)] * 3)
    b = np.stack([square(0.0, 0.0, 1.0), square(0.5, 0.5, 1.0), square(3.0, 3.0, 1.0)])
    assert np.allclose(hull_iou(a, b), [1.0, 0.125, 0.0])


def test_point_in_view_is_strict() -> None:
    view = square(0.0, 0.0, 1.0)
    assert point_in_view_strict([0.5, 0.5], view) is True
    assert point_in_view_strict([0.0, 0.5], view) is False  # on the boundary
    assert point_in_view_strict([1.0, 1.0], view) is False  # a corner
    assert point_in_view_strict([2.0, 0.5], view) is False
    inside = point_in_view_strict(np.array([[0.5, 0.5], [0.5, 1.0]]), view)
    assert inside.tolist() == [True, False]


def test_gps_to_pixel_uses_lat_ratio_on_both_axes_and_rounds_half_to_even() -> None:
    georef = MapGeoref((10.0, 20.0), (10.01, 20.02), lng_ratio=2e-5, lat_ratio=1e-5)
    # int() truncates, in the official order of operations: 1000 * 2e-5 / 1e-5 is
    # 1999.9999999999998, so the official code resizes to 1999 pixels, and so do we.
    assert georef.resized_width(1000) == 1999
    assert MapGeoref((0, 0), (1, 1), lng_ratio=0.375, lat_ratio=0.25).resized_width(1001) == 1501
    exact = MapGeoref((0.0, 20.0), (10.0, 30.0), lng_ratio=0.25, lat_ratio=0.25)
    pixel = exact.gps_to_pixel([10.0 - 0.625, 20.0 + 0.875])
    assert pixel.tolist() == [4, 2]  # x 3.5 -> 4 and y 2.5 -> 2: half to even, as round()
    back = georef.pixel_to_gps(georef.gps_to_pixel_float([10.005, 20.013]))
    assert np.allclose(back, [10.005, 20.013])
    assert georef.contains([10.005, 20.01]) is True
    assert georef.contains([10.01, 20.01]) is False  # open box


def test_map_loading_resizes_the_width(tmp_path) -> None:
    georef = MapGeoref((10.0, 20.0), (10.01, 20.02), lng_ratio=0.375, lat_ratio=0.25)
    path = tmp_path / "7.tif"
    image = np.zeros((40, 60, 3), np.uint8)
    image[:, :, 2] = 200  # red in BGR
    cv2.imwrite(str(path), image)
    loaded = load_map_bgr(path, georef)
    assert loaded.shape == (40, 90, 3)
    assert loaded[0, 0].tolist() == [0, 0, 200]
    assert resize_to_degree_grid(image, MapGeoref((0, 0), (1, 1), 1e-5, 1e-5)) is image
    with pytest.raises(MapImageError, match="not found"):
        load_map_bgr(tmp_path / "missing.tif", georef)
    (tmp_path / "bad.tif").write_bytes(b"not an image")
    with pytest.raises(MapImageError, match="not a readable image"):
        load_map_bgr(tmp_path / "bad.tif", georef)


def test_observation_puts_the_front_at_the_top() -> None:
    georef = MapGeoref((0.0, 0.0), (0.01, 0.01), lng_ratio=1e-5, lat_ratio=1e-5)
    image = np.zeros((1000, 1000, 3), np.uint8)
    image[:500, :, 0] = 255  # northern half blue
    image[:, :500, 1] = 255  # western half green
    view_north = view_from_pose((0.005, 0.005), 0.0, 400 * 1e-5 * METERS_PER_DEGREE)
    obs = observe_view(image, view_north, georef)
    assert obs.shape == (224, 224, 3)
    assert obs[10, 10].tolist() == [255, 255, 0]  # front-left = north-west
    assert obs[213, 213].tolist() == [0, 0, 0]  # back-right = south-east
    view_east = view_from_pose((0.005, 0.005), 90.0, 400 * 1e-5 * METERS_PER_DEGREE)
    obs = observe_view(image, view_east, georef)
    assert obs[10, 10].tolist() == [255, 0, 0]  # front-left = north-east
    assert obs[213, 10].tolist() == [255, 255, 0]  # back-left = north-west
    assert obs[213, 213].tolist() == [0, 255, 0]  # back-right = south-west
    outside = view_from_pose((0.0, 0.0), 0.0, 400 * 1e-5 * METERS_PER_DEGREE)
    assert observe_view(image, outside, georef)[200, 20].tolist() == [0, 0, 0]
    assert math.isclose(float(view_edge_m(view_north)), 445.2)


def test_a_resize_to_no_usable_width_names_the_file_and_ratios(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A width of 0 px was OpenCV's traceback ("inv_scale_x > 0"); of 549,822 px, 4 GB.
    path = tmp_path / "7.tif"
    cv2.imwrite(str(path), np.zeros((40, 60, 3), np.uint8))
    zero = MapGeoref((10.0, 20.0), (10.01, 20.02), lng_ratio=1e-3, lat_ratio=1.0)
    with pytest.raises(MapShapeError) as info:
        load_map_bgr(path, zero)
    assert str(info.value) == (
        f"{path}: lng_ratio / lat_ratio (0.001 / 1.0) resize this 60 px wide image to 0 px "
        "(1 to 20000 allowed): the records' ratios do not describe this image "
        "(`skyvln-eval validate` names them)"
    )
    assert info.value.map_shape_px == (40, 0)
    huge = MapGeoref((10.0, 20.0), (10.01, 20.02), lng_ratio=1e-3, lat_ratio=1e-6)
    with pytest.raises(MapShapeError, match="to 60000 px") as info:
        load_map_bgr(path, huge)
    assert info.value.map_shape_px == (40, 60000)

    def damaged(*_: object) -> None:
        raise cv2.error("OpenCV(4.10.0) grfmt_tiff.cpp:1: error: (-2:Unspecified) bad strip")

    monkeypatch.setattr(cv2, "imread", damaged)
    with pytest.raises(MapImageError) as failed:
        load_map_bgr(path, zero)
    assert str(failed.value) == (
        f"{path}: OpenCV could not read it (OpenCV(4.10.0) grfmt_tiff.cpp:1: error: "
        "(-2:Unspecified) bad strip)"
    )

    def out_of_memory(*_: object) -> None:  # the machine's, not a bad map (an audit)
        error = cv2.error("OpenCV(4.10.0) alloc.cpp:73: error: (-4:Insufficient memory)")
        error.code = cv2.Error.StsNoMem
        raise error

    monkeypatch.setattr(cv2, "imread", out_of_memory)
    with pytest.raises(MemoryError, match="OpenCV ran out of memory reading it"):
        load_map_bgr(path, zero)
