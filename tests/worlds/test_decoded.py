"""The machine's cache of decoded maps: same arrays, read-only, decoded once, bounded."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from skyvln_eval.avdn import AvdnRecord, load_split
from skyvln_eval.errors import ConfigError, MapImageError
from skyvln_eval.worlds import decoded, load_world
from skyvln_eval.worlds.decoded import BUDGET_ENV, budget_bytes, decoded_rasters
from skyvln_eval.worlds.layers import read_layer_rasters


def _source(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


class _Decoder:
    """Counts its calls; its arrays depend on the source's text."""

    def __init__(self, source: Path) -> None:
        self.source = source
        self.calls = 0

    def __call__(self) -> decoded.Rasters:
        self.calls += 1
        value = len(self.source.read_text())
        return {"a": np.full((3, 4), value, np.uint16), "b": np.arange(5, dtype=np.float32)}


def test_second_request_is_read_from_the_cache_read_only(tmp_path: Path) -> None:
    source = _source(tmp_path, "map.tif", "xyz")
    decode = _Decoder(source)
    first = decoded_rasters([source], {"r": 1}, decode, cache_dir=tmp_path / "cache")
    second = decoded_rasters([source], {"r": 1}, decode, cache_dir=tmp_path / "cache")
    assert decode.calls == 1
    for name in ("a", "b"):
        assert type(second[name]) is np.ndarray
        assert second[name].dtype == first[name].dtype
        np.testing.assert_array_equal(second[name], first[name])
        assert not second[name].flags.writeable
    with pytest.raises(ValueError, match="read-only"):
        second["a"][0, 0] = 1


def test_a_changed_source_or_recipe_is_decoded_again(tmp_path: Path) -> None:
    source = _source(tmp_path, "map.tif", "xyz")
    decode = _Decoder(source)
    cache = tmp_path / "cache"
    decoded_rasters([source], {"r": 1}, decode, cache_dir=cache)
    decoded_rasters([source], {"r": 2}, decode, cache_dir=cache)
    assert decode.calls == 2
    replacement = _source(tmp_path, "new.tif", "longer text")
    replacement.replace(source)  # a new file in the old one's place
    again = decoded_rasters([source], {"r": 1}, decode, cache_dir=cache)
    assert decode.calls == 3
    assert int(again["a"][0, 0]) == len("longer text")


def test_least_recently_used_entries_go_when_over_budget(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cache = tmp_path / "cache"
    sources = [_source(tmp_path, f"map{k}.tif", "x" * k) for k in range(3)]
    for source in sources:
        decoded_rasters([source], {}, _Decoder(source), cache_dir=cache)
    assert len(list(cache.iterdir())) == 3
    first = decoded.entry_key([sources[0]], {})
    os.utime(cache / first / "names.json", (1.0, 1.0))  # the oldest use
    entry_size = sum(p.stat().st_size for p in (cache / first).iterdir())
    monkeypatch.setenv(BUDGET_ENV, str(3.5 * entry_size / 2**30))
    extra = _source(tmp_path, "map9.tif", "y")
    decoded_rasters([extra], {}, _Decoder(extra), cache_dir=cache)
    kept = {p.name for p in cache.iterdir()}
    assert first not in kept and decoded.entry_key([extra], {}) in kept
    assert len(kept) == 3
    monkeypatch.setenv(BUDGET_ENV, "0")
    other = _source(tmp_path, "map8.tif", "z")
    decoded_rasters([other], {}, _Decoder(other), cache_dir=cache)
    assert [p.name for p in cache.iterdir()] == [decoded.entry_key([other], {})]


def test_an_unwritable_cache_still_gives_the_arrays_with_a_notice(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = _source(tmp_path, "map.tif", "xyz")
    blocker = _source(tmp_path, "not-a-folder", "")
    monkeypatch.setattr(decoded, "_warned", type(decoded._warned)())
    with pytest.warns(RuntimeWarning, match="decoded maps are not cached"):
        rasters = decoded_rasters([source], {}, _Decoder(source), cache_dir=blocker / "cache")
    assert int(rasters["a"][0, 0]) == 3


def test_budget_must_be_a_non_negative_number(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(BUDGET_ENV, "lots")
    with pytest.raises(ConfigError, match=BUDGET_ENV):
        budget_bytes()
    monkeypatch.setenv(BUDGET_ENV, "-1")
    with pytest.raises(ConfigError, match=BUDGET_ENV):
        budget_bytes()


_SampleCopy = tuple[Path, AvdnRecord]


@pytest.fixture
def sample_copy(sample_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> _SampleCopy:
    """A copy of the sample (its files may be changed) with a map's first record, and a
    cache of its own under ``tmp_path / "cache"``."""
    data = tmp_path / "data"
    shutil.copytree(sample_dir, data)
    monkeypatch.setenv("SKYVLN_EVAL_CACHE", str(tmp_path / "cache"))
    return data, load_split(data, "val_seen").records[0]


def test_cached_world_equals_a_fresh_decode(sample_copy: _SampleCopy) -> None:
    data, record = sample_copy
    fresh = load_world(data, record.map_name, record.georef)  # decoded and stored
    cached = load_world(data, record.map_name, record.georef)  # mapped from the store
    semantic, instance, height_m = read_layer_rasters(data, record.map_name)
    for name, expected in (("semantic", semantic), ("instance", instance), ("height_m", height_m)):
        for world in (fresh, cached):
            array = getattr(world, name)
            assert array.dtype == expected.dtype
            np.testing.assert_array_equal(array, expected)
    np.testing.assert_array_equal(cached.bgr, fresh.bgr)
    assert cached.landmarks == fresh.landmarks
    assert cached.height_m is not None and fresh.height_m is not None
    assert not cached.height_m.flags.writeable
    # A layer rewritten with other content is read again, not served from the store.
    height_png = data / "world_layers" / record.map_name / "height_dm.png"
    shutil.copyfile(data / "world_layers" / record.map_name / "semantic.png", height_png)
    changed = load_world(data, record.map_name, record.georef).height_m
    assert changed is not None and not np.array_equal(changed, fresh.height_m)


def test_a_process_that_stored_the_entry_first_wins(tmp_path: Path) -> None:
    """Two processes decode one map at once: the second's rename finds the first's entry,
    keeps it and returns the stored arrays."""
    source = _source(tmp_path, "map.tif", "xyz")
    cache = tmp_path / "cache"

    def racing_decode() -> decoded.Rasters:
        decoded_rasters([source], {}, _Decoder(source), cache_dir=cache)  # the other one
        return {"a": np.zeros((3, 4), np.uint16), "b": np.zeros(5, np.float32)}

    rasters = decoded_rasters([source], {}, racing_decode, cache_dir=cache)
    assert int(rasters["a"][0, 0]) == 3  # the stored entry, not this decode's zeros
    assert not rasters["a"].flags.writeable
    assert [p.name for p in cache.iterdir()] == [decoded.entry_key([source], {})]


def test_a_read_only_cache_is_still_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A cache filled by someone else may not let us mark entries as used: still a hit."""
    source = _source(tmp_path, "map.tif", "xyz")
    cache = tmp_path / "cache"
    decoded_rasters([source], {}, _Decoder(source), cache_dir=cache)

    def refuse(*args: object, **kwargs: object) -> None:
        raise PermissionError("read-only file system")

    monkeypatch.setattr(decoded.os, "utime", refuse)
    decode = _Decoder(source)
    rasters = decoded_rasters([source], {}, decode, cache_dir=cache)
    assert decode.calls == 0 and int(rasters["a"][0, 0]) == 3


def test_a_missing_file_is_reported_by_the_decoder_naming_it(
    sample_copy: _SampleCopy, tmp_path: Path
) -> None:
    data, record = sample_copy
    instance_png = data / "world_layers" / record.map_name / "instance.png"
    instance_png.unlink()
    with pytest.raises(MapImageError, match=r"instance\.png: missing or unreadable layer image"):
        load_world(data, record.map_name, record.georef)
    map_tif = data / "train_images" / f"{record.map_name}.tif"
    map_tif.unlink()
    with pytest.raises(MapImageError, match=rf"{record.map_name}\.tif: map image not found"):
        load_world(data, record.map_name, record.georef)
    assert not (tmp_path / "cache" / "decoded-maps").exists()  # nothing stored for them
