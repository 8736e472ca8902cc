"""Build a synthetic dataset in the exact AVDN layout and schema.

``annotations/{train,val_seen,val_unseen,test_unseen}_data.json`` and
``train_images/<map_name>.tif`` as in the real release (the TIFF at its native width, so
the official width resize applies), plus ``world_layers/`` with the synthetic layers.
Seen maps serve train and val_seen; unseen maps serve one split each. Unlike the real
release, test_unseen keeps its full ground truth. Identical spec, identical bytes.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import shapely

from skyvln_eval.avdn.constants import (
    ANNOTATIONS_DIR,
    IMAGES_DIR,
    METERS_PER_DEGREE,
    annotation_file_name,
)
from skyvln_eval.avdn.geometry import view_heading_deg
from skyvln_eval.avdn.imagery import MapGeoref
from skyvln_eval.fileio import atomic_write_bytes, atomic_write_json, sha256_file
from skyvln_eval.worlds.city import CityTile, generate_city
from skyvln_eval.worlds.city.generate import GENERATOR_VERSION
from skyvln_eval.worlds.layers import write_world_layers
from skyvln_eval.worlds.sample.dialogs import DIALOG_VERSION, attention_circles, render_trajectory
from skyvln_eval.worlds.sample.facts import FactFinder, RoundFacts
from skyvln_eval.worlds.sample.phrasebook import SPLIT_FAMILIES
from skyvln_eval.worlds.sample.pilot import (
    FLIGHT_VERSION,
    PilotFailed,
    PlanGeo,
    fly_route,
    plan_edges,
    start_heading_deg,
)
from skyvln_eval.worlds.sample.routes import plan_route
from skyvln_eval.worlds.sample.sources import DIALOGS_FILE, TrajectoryDialog, dialogs_document
from skyvln_eval.worlds.tile import Landmark

DATASET_INFO = "DATASET_INFO.json"
SPLIT_CODES = {"train": 1, "val_seen": 2, "val_unseen": 3, "test_unseen": 4}
#: (lat, lng) of the south-west corners of invented cities; tiles spread around them.
LOCATIONS = (
    (37.77, -122.42),
    (46.48, 30.72),
    (40.42, -3.70),
    (32.72, -117.16),
    (47.61, -122.33),
    (-33.92, 18.42),
)


@dataclass(frozen=True)
class DatasetSpec:
    """What to generate; the spec (with the generator version) determines every byte."""

    name: str
    seed: int
    map_id_base: int
    tile_m: float
    metres_per_px: float
    seen_maps: int
    val_unseen_maps: int
    test_unseen_maps: int
    records: Mapping[str, int] = field(default_factory=dict)

    def map_splits(self) -> list[tuple[str, tuple[str, ...]]]:
        """(map name, splits it serves) for every map, in order."""
        out: list[tuple[str, tuple[str, ...]]] = []
        groups = (
            (self.seen_maps, ("train", "val_seen")),
            (self.val_unseen_maps, ("val_unseen",)),
            (self.test_unseen_maps, ("test_unseen",)),
        )
        for count, splits in groups:
            for _ in range(count):
                out.append((str(self.map_id_base + len(out) + 1), splits))
        return out

    def quota(self, split: str, map_name: str) -> int:
        """Records of ``split`` on ``map_name``: the split's total spread evenly."""
        maps = [m for m, splits in self.map_splits() if split in splits]
        base, extra = divmod(self.records[split], len(maps))
        return base + (1 if maps.index(map_name) < extra else 0)


SAMPLE_SPEC = DatasetSpec(
    "sample",
    seed=20261121,
    map_id_base=9100,
    tile_m=1000.0,
    metres_per_px=0.4,
    seen_maps=3,
    val_unseen_maps=2,
    test_unseen_maps=2,
    records={"train": 40, "val_seen": 30, "val_unseen": 30, "test_unseen": 30},
)
FULL_SPEC = DatasetSpec(
    "full",
    seed=20261121,
    map_id_base=9200,
    tile_m=1000.0,
    metres_per_px=0.4,
    seen_maps=36,
    val_unseen_maps=10,
    test_unseen_maps=20,
    records={"train": 4591, "val_seen": 370, "val_unseen": 411, "test_unseen": 897},
)
SPECS = {"sample": SAMPLE_SPEC, "full": FULL_SPEC}


def map_georef(
    spec: DatasetSpec, map_index: int, height_px: int, width_px: int
) -> tuple[MapGeoref, int]:
    """Georeference a tile like an xView GeoTIFF: square metre pixels, so lng_ratio > lat_ratio.

    The TIFF is stored ``round(width * cos(lat))`` pixels wide (returned with the
    georeference); ``lng_ratio`` is chosen so that the official resize
    ``int(W * lng_ratio / lat_ratio)`` gives back ``width_px``.
    """
    base_lat, base_lng = LOCATIONS[map_index % len(LOCATIONS)]
    lat0 = base_lat + 0.02 * (map_index // len(LOCATIONS))
    lng0 = base_lng + 0.03 * (map_index // len(LOCATIONS))
    lat_ratio = spec.metres_per_px / METERS_PER_DEGREE
    native_width = round(width_px * math.cos(math.radians(lat0)))
    lng_ratio = lat_ratio * (width_px + 0.5) / native_width
    georef = MapGeoref(
        gps_botm_left=(lat0, lng0),
        gps_top_right=(lat0 + height_px * lat_ratio, lng0 + native_width * lng_ratio),
        lng_ratio=lng_ratio,
        lat_ratio=lat_ratio,
    )
    return georef, native_width


def _landmarks_latlng(city: CityTile, geo: PlanGeo) -> list[Landmark]:
    out = []
    for spec in city.plan.landmarks:
        footprint = geo.to_latlng(spec.polygon)
        centre = geo.to_latlng(spec.polygon.mean(axis=0))
        out.append(
            Landmark(
                spec.landmark_id,
                spec.name,
                spec.category,
                spec.description,
                (float(centre[0]), float(centre[1])),
                tuple((float(p[0]), float(p[1])) for p in footprint),
                float(spec.height_m),
            )
        )
    return out


def _destination_corners(geo: PlanGeo, polygon: np.ndarray) -> list[list[float]]:
    rect = shapely.minimum_rotated_rectangle(shapely.Polygon(polygon))
    corners = np.asarray(rect.exterior.coords)[:4]
    return geo.to_latlng(corners).tolist()


def _rounds_count(rng: np.random.Generator, remaining: int) -> int:
    wanted = int(rng.choice([1, 2, 3, 4], p=[0.35, 0.35, 0.2, 0.1]))
    return min(wanted, remaining)


def wording_seed(spec: DatasetSpec, map_index: int, split: str, traj: int) -> int:
    """The seed of one trajectory's wording stream, apart from the stream of its route."""
    sequence = np.random.SeedSequence([spec.seed, map_index, SPLIT_CODES[split], traj])
    return int(sequence.generate_state(1)[0])


def _trajectory_records(
    rng: np.random.Generator,
    city: CityTile,
    geo: PlanGeo,
    map_name: str,
    traj: int,
    n_rounds: int,
    families: tuple[str, ...],
    seed: int,
) -> tuple[list[dict[str, Any]], TrajectoryDialog]:
    """Plan, fly and describe one trajectory; one AVDN record per round. ``seed``: the
    trajectory's wording seed, which seeds its start heading's stream too (apart from the
    route's ``rng``)."""
    start_heading = start_heading_deg(seed)
    for _ in range(300):
        route = plan_route(rng, city.plan, n_rounds)
        if route is None:
            continue
        size = float(np.ptp(route.destination.polygon, axis=0).max())
        try:
            flight = plan_edges(rng, n_rounds, size)
            rounds = fly_route(rng, route, geo, flight, start_heading)
        except PilotFailed:
            continue
        break
    else:  # pragma: no cover - a tile without any flyable route would be a generator bug
        raise RuntimeError(f"could not plan a {n_rounds}-round trajectory on map {map_name}")
    finder = FactFinder(rng, route, geo, city.plan.landmarks)
    facts: list[RoundFacts] = []
    used: set[int] = set()
    for r, views in enumerate(rounds):
        round_facts = finder.round_facts(r, views, used)
        used |= set(round_facts.mentioned_ids)
        if r > 0:
            round_facts = replace(round_facts, question=finder.question(r))
        facts.append(round_facts)
    utterances = render_trajectory(facts, families, seed)
    by_id = {lm.landmark_id: lm for lm in city.plan.landmarks}
    georef = geo.georef
    destination = _destination_corners(geo, route.destination.polygon)
    records: list[dict[str, Any]] = []
    texts: list[str] = []
    attention: list[list[Any]] = []
    for r, (views, utterance) in enumerate(zip(rounds, utterances, strict=True)):
        mentioned = [by_id[i] for i in facts[r].mentioned_ids]
        attention = attention + attention_circles(
            geo, mentioned, route.point_at(route.stop_s[r]), city.metres_per_px
        )
        angle = start_heading if r == 0 else float(view_heading_deg(views[0]))
        records.append(
            {
                "map_name": map_name,
                "route_index": f"{traj}_{r + 1}",
                "last_round_idx": len(rounds),
                "instructions": utterance.text,
                "pre_dialogs": list(texts),
                "gps_botm_left": list(georef.gps_botm_left),
                "gps_top_right": list(georef.gps_top_right),
                "lng_ratio": georef.lng_ratio,
                "lat_ratio": georef.lat_ratio,
                "angle": angle,
                "destination": destination,
                "gt_path_corners": [v.tolist() for v in views],
                "attention_list": list(attention),
            }
        )
        texts.append(utterance.text)
    dialog = TrajectoryDialog(
        map_name, str(traj), seed, tuple(facts), tuple(u.frames for u in utterances)
    )
    return records, dialog


@dataclass(frozen=True)
class MapOutput:
    """One map's share of a split: its records and its trajectories' dialogs."""

    records: list[dict[str, Any]]
    dialogs: list[TrajectoryDialog]


def build_map(spec: DatasetSpec, map_index: int, out_dir: str | Path) -> dict[str, MapOutput]:
    """Generate one map (image, layers) and its records for every split it serves."""
    out_dir = Path(out_dir)
    map_name, splits = spec.map_splits()[map_index]
    city = generate_city(spec.seed * 1000 + map_index, spec.tile_m, spec.tile_m, spec.metres_per_px)
    height_px, width_px = city.canvas.bgr.shape[:2]
    georef, native_width = map_georef(spec, map_index, height_px, width_px)
    geo = PlanGeo(georef)
    native = cv2.resize(city.canvas.bgr, (native_width, height_px), interpolation=cv2.INTER_AREA)
    ok, tif = cv2.imencode(".tif", native)
    if not ok:  # pragma: no cover
        raise RuntimeError("TIFF encoding failed")
    atomic_write_bytes(out_dir / IMAGES_DIR / f"{map_name}.tif", tif.tobytes())
    write_world_layers(
        out_dir,
        map_name,
        city.canvas.semantic,
        city.canvas.instance,
        city.canvas.height,
        _landmarks_latlng(city, geo),
        {
            "generator_version": GENERATOR_VERSION,
            "seed": city.seed,
            "metres_per_px": spec.metres_per_px,
        },
    )
    out: dict[str, MapOutput] = {}
    traj = 0
    for split in splits:
        rng = np.random.default_rng(
            np.random.SeedSequence([spec.seed, map_index, SPLIT_CODES[split]])
        )
        remaining = spec.quota(split, map_name)
        records: list[dict[str, Any]] = []
        dialogs: list[TrajectoryDialog] = []
        while remaining > 0:
            n_rounds = _rounds_count(rng, remaining)
            seed = wording_seed(spec, map_index, split, traj)
            new, dialog = _trajectory_records(
                rng, city, geo, map_name, traj, n_rounds, SPLIT_FAMILIES[split], seed
            )
            records += new
            dialogs.append(dialog)
            remaining -= n_rounds
            traj += 1
        out[split] = MapOutput(records, dialogs)
    return out


def build_dataset(
    spec: DatasetSpec,
    out_dir: str | Path,
    workers: int = 1,
    on_map_done: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Write the whole dataset under ``out_dir``; returns the dataset info it also writes."""
    out_dir = Path(out_dir)
    maps = spec.map_splits()
    per_map: list[dict[str, MapOutput]] = []
    if workers > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = [pool.submit(build_map, spec, i, out_dir) for i in range(len(maps))]
            for (name, _), future in zip(maps, futures, strict=True):
                per_map.append(future.result())
                if on_map_done:
                    on_map_done(name)
    else:
        for i, (name, _) in enumerate(maps):
            per_map.append(build_map(spec, i, out_dir))
            if on_map_done:
                on_map_done(name)
    counts = {}
    dialogs: dict[str, list[TrajectoryDialog]] = {}
    empty = MapOutput([], [])
    for split in SPLIT_CODES:
        records = [r for result in per_map for r in result.get(split, empty).records]
        atomic_write_json(out_dir / ANNOTATIONS_DIR / annotation_file_name(split), records)
        counts[split] = len(records)
        dialogs[split] = [d for m in per_map for d in m.get(split, empty).dialogs]
    atomic_write_json(out_dir / DIALOGS_FILE, dialogs_document(dialogs), indent=1)
    files = sorted(p for p in out_dir.rglob("*") if p.is_file() and p.name != DATASET_INFO)
    info = {
        "format": "skyvln-eval/synthetic-avdn",
        "generator_version": GENERATOR_VERSION,
        "dialog_version": DIALOG_VERSION,
        "flight_version": FLIGHT_VERSION,
        "spec": {**asdict(spec), "records": dict(spec.records)},
        "records": counts,
        "maps": {name: list(splits) for name, splits in maps},
        "files": {p.relative_to(out_dir).as_posix(): sha256_file(p) for p in files},
    }
    atomic_write_json(out_dir / DATASET_INFO, info, indent=1)
    return info
