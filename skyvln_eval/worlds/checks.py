"""Check that each map image decodes and is the image its records describe (``validate``).

A record's bounds and ratios give the size its map must have once width-resized
(:meth:`~skyvln_eval.avdn.imagery.MapGeoref.described_shape_px`). A map that decodes to
another size is reported on the records, naming the field to fix, not on the image: a
``lng_ratio`` ten times too large and a ``map_name`` switched to another map both read
as "the layers belong to another version of this map" before. A map that does not
decode at all is reported on the file, with how many records use it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from skyvln_eval.avdn.imagery import MapGeoref, georef_misfit
from skyvln_eval.avdn.records import AvdnRecord
from skyvln_eval.errors import FormatVersionError, MapImageError, MapShapeError, ValidationIssue
from skyvln_eval.worlds.loading import load_world


@dataclass(frozen=True)
class _Decoded:
    """What decoding one map with one geo-reference gave: the width-resized map's shape
    (None when it did not decode) and the problem met, if any."""

    shape_px: tuple[int, int] | None
    problem: str | None


@dataclass
class MapCheck:
    """Maps decoded so far, by (dataset, map, geo-reference): each is decoded once for a
    whole dataset, and its problem reported once, however many splits use it."""

    decoded: dict[tuple[Path, str, MapGeoref], _Decoded] = field(default_factory=dict)

    def check(
        self,
        data_dir: Path,
        file: str,
        records: Sequence[AvdnRecord],
        indices: Sequence[int],
    ) -> tuple[list[ValidationIssue], list[str]]:
        """Issues of ``records`` (at ``indices`` in ``file``) whose map image is not the one
        their geo-reference describes, and the problems of images that do not decode."""
        users: dict[tuple[str, MapGeoref], list[tuple[int, AvdnRecord]]] = {}
        for index, record in zip(indices, records, strict=True):
            users.setdefault((record.map_name, record.georef), []).append((index, record))
        issues: list[ValidationIssue] = []
        problems: list[str] = []
        for (map_name, georef), using in users.items():
            key = (data_dir, map_name, georef)
            known = key in self.decoded
            if not known:
                self.decoded[key] = _decode(data_dir, map_name, georef)
            decoded = self.decoded[key]
            misfit = None if decoded.shape_px is None else georef_misfit(georef, decoded.shape_px)
            if misfit is not None:
                issues += _misfit_issues(file, map_name, misfit, using, users)
            elif decoded.problem is not None and not known:
                problems.append(f"{decoded.problem} ({len(using)} record(s) use map {map_name})")
        return issues, problems


def _decode(data_dir: Path, map_name: str, georef: MapGeoref) -> _Decoded:
    try:
        tile = load_world(data_dir, map_name, georef)
    except MapShapeError as exc:  # decoded, but of a shape it cannot be used in
        return _Decoded(exc.map_shape_px, str(exc))
    except (MapImageError, FormatVersionError) as exc:
        return _Decoded(None, str(exc))
    return _Decoded((tile.bgr.shape[0], tile.bgr.shape[1]), None)


def _misfit_issues(
    file: str,
    map_name: str,
    misfit: tuple[str, str],
    using: Sequence[tuple[int, AvdnRecord]],
    users: dict[tuple[str, MapGeoref], list[tuple[int, AvdnRecord]]],
) -> list[ValidationIssue]:
    """One issue per record: on ``map_name`` when another map's records give this very
    geo-reference (the record names the wrong map), else on the ratio that disagrees."""
    field_name, problem = misfit
    georef = using[0][1].georef
    others = [
        (m, i) for (m, g), rows in users.items() if g == georef and m != map_name for i, _ in rows
    ]
    if others:
        other_map, other_index = others[0]
        field_name = "map_name"
        problem = (
            f"map {map_name}'s image is not the one this record's geo-reference describes, "
            f"which is map {other_map}'s (record {other_index}): map_name names another "
            f"map ({problem.split(': ')[0]})"
        )
    return [
        ValidationIssue(file, problem, index, record.episode_id, field_name)
        for index, record in using
    ]
