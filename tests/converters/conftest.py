"""Fixtures for the converter tests: the sample converted once per session, small worlds."""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from skyvln_eval.avdn import SPLITS, Episode, MapGeoref, load_split
from skyvln_eval.converters import DEFAULT_OPTIONS, ConvertOptions, McapLogWriter, convert_episode
from skyvln_eval.converters.batch import ConvertReport, convert_split
from skyvln_eval.worlds import WorldTile
from tests.conftest import BOTM_LEFT, TOP_RIGHT


@dataclass(frozen=True)
class ConvertedSample:
    """The whole sample converted in both modes: episodes from the AVDN reader and reports."""

    data_dir: Path
    out_dir: Path
    episodes: dict[tuple[str, str], list[Episode]]
    reports: dict[tuple[str, str], ConvertReport]


@pytest.fixture(scope="session")
def converted_sample(sample_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> ConvertedSample:
    out = tmp_path_factory.mktemp("converted")
    episodes = {}
    reports = {}
    for split in SPLITS:
        loaded = load_split(sample_dir, split)
        for mode in ("andh", "andh-full"):
            episodes[(split, mode)] = loaded.episodes(mode)
            reports[(split, mode)] = convert_split(sample_dir, split, out, mode)  # type: ignore[arg-type]
    return ConvertedSample(sample_dir, out, episodes, reports)


def synthetic_world(map_name: str = "1913", seed: int = 0) -> WorldTile:
    """A random-texture world on the 0.01 degree map of tests.conftest.make_record.

    make_record's ratios are 1e-5 degree per pixel, so the map grid is 1000 x 1000 pixels.
    """
    rng = np.random.default_rng(seed)
    size_px = round((TOP_RIGHT[0] - BOTM_LEFT[0]) / 1e-5)
    bgr = rng.integers(0, 256, (size_px, size_px, 3), dtype=np.uint8)
    georef = MapGeoref(BOTM_LEFT, TOP_RIGHT, 1e-5, 1e-5)
    return WorldTile(map_name=map_name, georef=georef, bgr=bgr)


def convert_to_bytes(
    episode: Episode, world: WorldTile | None, options: ConvertOptions = DEFAULT_OPTIONS
) -> bytes:
    """Convert in memory, as a converter is meant to be tested."""
    buffer = io.BytesIO()
    with McapLogWriter(buffer) as writer:
        convert_episode(episode, world, writer, options)
    return buffer.getvalue()


def chunk_payload_span(data: bytes) -> tuple[int, int]:
    """(start, end) of the first chunk's compressed records, from the chunk index."""
    summary = make_reader(io.BytesIO(data)).get_summary()
    assert summary is not None
    index = summary.chunk_indexes[0]
    # Chunk record: opcode, length, start/end time, uncompressed size and CRC,
    # compression string, records length, then the compressed records.
    offset = index.chunk_start_offset + 1 + 8 + 8 + 8 + 8 + 4
    (compression_len,) = struct.unpack_from("<I", data, offset)
    offset += 4 + compression_len
    (records_len,) = struct.unpack_from("<Q", data, offset)
    return offset + 8, offset + 8 + records_len
