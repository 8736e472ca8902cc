"""Read and write the extra layers of synthetic tiles, next to the AVDN layout.

``<data_dir>/world_layers/<map_name>/`` holds ``semantic.png`` (uint8 classes),
``instance.png`` (uint16 landmark ids), ``height_dm.png`` (uint16 decimetres) and
``landmarks.json``; all on the official resized grid of the map. PNG keeps the files
lossless, byte-identical for identical input, and viewable with any image tool.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import cv2
import numpy as np
from numpy.typing import NDArray

from skyvln_eval.errors import FormatVersionError, MapImageError
from skyvln_eval.fileio import atomic_write_bytes, atomic_write_json
from skyvln_eval.worlds.tile import Landmark

LAYERS_DIR = "world_layers"
LAYERS_FORMAT = "skyvln-eval/world-layers"
LAYERS_FORMAT_VERSION = 1

T = TypeVar("T")


def layers_dir(data_dir: str | Path, map_name: str) -> Path:
    return Path(data_dir) / LAYERS_DIR / map_name


def height_decimetres(height_m: NDArray[Any]) -> NDArray[np.uint16]:
    """Heights in metres as ``height_dm.png`` stores them: whole decimetres, 0..65535."""
    return np.clip(np.round(height_m * 10.0), 0, 65535).astype(np.uint16)


def height_from_decimetres(decimetres: NDArray[Any]) -> NDArray[np.float32]:
    """Heights in metres as ``height_dm.png`` is read: ``float32(d) / 10`` (one rounding)."""
    return decimetres.astype(np.float32) / 10.0


def _png(array: NDArray[Any]) -> bytes:
    ok, buf = cv2.imencode(".png", array, [cv2.IMWRITE_PNG_COMPRESSION, 6])
    if not ok:  # pragma: no cover - OpenCV always encodes these dtypes
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def write_world_layers(
    data_dir: str | Path,
    map_name: str,
    semantic: NDArray[np.uint8],
    instance: NDArray[np.uint16],
    height_m: NDArray[np.float32],
    landmarks: list[Landmark],
    meta: dict[str, Any],
) -> None:
    folder = layers_dir(data_dir, map_name)
    atomic_write_bytes(folder / "semantic.png", _png(semantic.astype(np.uint8)))
    atomic_write_bytes(folder / "instance.png", _png(instance.astype(np.uint16)))
    atomic_write_bytes(folder / "height_dm.png", _png(height_decimetres(height_m)))
    atomic_write_json(
        folder / "landmarks.json",
        {
            "format": LAYERS_FORMAT,
            "version": LAYERS_FORMAT_VERSION,
            "map_name": map_name,
            "meta": meta,
            "landmarks": [
                {
                    "landmark_id": lm.landmark_id,
                    "name": lm.name,
                    "category": lm.category,
                    "description": lm.description,
                    "centre": list(lm.centre),
                    "footprint": [list(p) for p in lm.footprint],
                    "height_m": lm.height_m,
                }
                for lm in landmarks
            ],
        },
        indent=1,
    )


def _read_png(path: Path, flags: int) -> NDArray[Any]:
    image = cv2.imread(str(path), flags)
    if image is None:
        raise MapImageError(str(path), "missing or unreadable layer image")
    return image


#: The raster layers' files, in the order :func:`read_layer_rasters` returns them.
LAYER_FILES = ("semantic.png", "instance.png", "height_dm.png")


def read_landmarks(data_dir: str | Path, map_name: str) -> tuple[Landmark, ...] | None:
    """The landmarks of a synthetic map, or None when the map has no layers (real xView).

    A file that is not JSON, or a landmark without a field, raises :class:`MapImageError`
    naming the file, the landmark's position in its list and the field.
    """
    meta_path = layers_dir(data_dir, map_name) / "landmarks.json"
    if not meta_path.is_file():
        return None
    try:
        info = json.loads(meta_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MapImageError(str(meta_path), f"not a JSON file ({exc})") from exc
    if not isinstance(info, dict):
        raise MapImageError(str(meta_path), "expected a JSON object")
    if info.get("format") != LAYERS_FORMAT or info.get("version") != LAYERS_FORMAT_VERSION:
        raise FormatVersionError(
            str(meta_path),
            info.get("version"),
            LAYERS_FORMAT_VERSION,
            "Regenerate the synthetic dataset with this version (`skyvln-eval sample --force`).",
        )
    items = info.get("landmarks")
    if not isinstance(items, list):
        raise MapImageError(str(meta_path), "field 'landmarks': expected a list")
    return tuple(_landmark(meta_path, index, item) for index, item in enumerate(items))


def _point(value: Any) -> tuple[float, float]:
    return (float(value[0]), float(value[1]))


def _landmark(meta_path: Path, index: int, item: Any) -> Landmark:
    """Landmark ``index`` of ``landmarks.json``, or an error naming it and its field."""

    def field(name: str, convert: Callable[[Any], T]) -> T:
        try:
            return convert(item[name])
        except (KeyError, IndexError, TypeError, ValueError) as exc:
            problem = "missing" if isinstance(exc, KeyError) else f"invalid ({exc})"
            raise MapImageError(
                str(meta_path), f"landmark {index}, field '{name}': {problem}"
            ) from exc

    return Landmark(
        landmark_id=field("landmark_id", int),
        name=field("name", str),
        category=field("category", str),
        description=field("description", str),
        centre=field("centre", _point),
        footprint=field("footprint", lambda points: tuple(_point(p) for p in points)),
        height_m=field("height_m", float),
    )


def read_layer_rasters(
    data_dir: str | Path, map_name: str
) -> tuple[NDArray[np.uint8], NDArray[np.uint16], NDArray[np.float32]]:
    """The semantic, instance and height (metres) layers of a synthetic map."""
    semantic_png, instance_png, height_png = (
        layers_dir(data_dir, map_name) / name for name in LAYER_FILES
    )
    semantic = _read_png(semantic_png, cv2.IMREAD_UNCHANGED).astype(np.uint8)
    instance = _read_png(instance_png, cv2.IMREAD_UNCHANGED).astype(np.uint16)
    height = height_from_decimetres(_read_png(height_png, cv2.IMREAD_UNCHANGED))
    return semantic, instance, height


def has_world_layers(data_dir: str | Path, map_name: str) -> bool:
    """Whether a map has semantic layers (synthetic tiles do; real xView imagery does not)."""
    return (layers_dir(data_dir, map_name) / "semantic.png").is_file()
