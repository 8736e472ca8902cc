"""Fill city blocks: generic residential and commercial blocks, and each landmark kind.

Blocks are rectangles in the grid frame (u, v metres), so every footprint is built there
with :meth:`GridFrame.rect` and lands in the world rotated with the street grid.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import shapely

from skyvln_eval.worlds.city.names import ROOF_COLOURS
from skyvln_eval.worlds.city.plan import (
    BGR,
    Area,
    Building,
    Car,
    CityPlan,
    GridFrame,
    Polygon,
    RoofStyle,
    Tree,
)

CAR_COLOURS: tuple[BGR, ...] = (
    (235, 235, 235),
    (30, 30, 30),
    (140, 140, 140),
    (40, 40, 170),
    (150, 80, 30),
    (200, 200, 205),
    (60, 90, 40),
    (50, 160, 220),
    (90, 60, 50),
    (180, 180, 170),
)
HOUSE_ROOFS = (0, 1, 2, 4, 5, 9, 3, 8)  # indices into ROOF_COLOURS, common house roofs
COMMERCIAL_ROOFS = (3, 4, 5, 8, 9)
VIVID_ROOFS = (0, 1, 6, 7, 9, 3)


@dataclass(frozen=True)
class Block:
    """A rectangle of the grid frame between streets (sidewalks excluded)."""

    u0: float
    v0: float
    u1: float
    v1: float

    @property
    def width(self) -> float:
        return self.u1 - self.u0

    @property
    def depth(self) -> float:
        return self.v1 - self.v0

    @property
    def min_side(self) -> float:
        return min(self.width, self.depth)

    def split_u(self, fraction: float, gap: float = 0.0) -> tuple[Block, Block]:
        cut = self.u0 + self.width * fraction
        return Block(self.u0, self.v0, cut - gap / 2, self.v1), Block(
            cut + gap / 2, self.v0, self.u1, self.v1
        )

    def split_v(self, fraction: float, gap: float = 0.0) -> tuple[Block, Block]:
        cut = self.v0 + self.depth * fraction
        return Block(self.u0, self.v0, self.u1, cut - gap / 2), Block(
            self.u0, cut + gap / 2, self.u1, self.v1
        )


class BlockFiller:
    """Adds the content of blocks to a plan; one method per kind of block."""

    def __init__(
        self, plan: CityPlan, frame: GridFrame, rng: np.random.Generator, keep_out: object
    ) -> None:
        self.plan = plan
        self.frame = frame
        self.rng = rng
        self.keep_out = keep_out  # shapely geometry: roads, river, roundabouts

    # ---------------------------------------------------------------- helpers
    def rect(self, u0: float, v0: float, u1: float, v1: float) -> Polygon:
        return self.frame.rect(u0, v0, u1, v1)

    def ellipse(self, uc: float, vc: float, au: float, av: float, n: int = 48) -> Polygon:
        t = np.linspace(0, 2 * math.pi, n, endpoint=False)
        return self.frame.to_world(np.stack([uc + au * np.cos(t), vc + av * np.sin(t)], axis=1))

    def free(self, polygon: Polygon) -> bool:
        """Whether a footprint stays clear of roads, the river and roundabouts."""
        return not shapely.intersects(shapely.Polygon(polygon), self.keep_out)

    def roof(self, choices: tuple[int, ...]) -> tuple[BGR, str]:
        colour, name = ROOF_COLOURS[int(self.rng.choice(choices))]
        # Mostly a brightness change, with a little per-channel variation (weathering).
        gain = self.rng.uniform(0.88, 1.1)
        jitter = self.rng.integers(-4, 5, size=3)
        shaded = (int(np.clip(c * gain + j, 0, 255)) for c, j in zip(colour, jitter, strict=True))
        return tuple(shaded), name  # type: ignore[return-value]

    def add_building(self, building: Building) -> bool:
        if not self.free(building.footprint):
            return False
        self.plan.buildings.append(building)
        return True

    def add_trees(self, b: Block, count: int, radius: tuple[float, float] = (2.5, 5.0)) -> None:
        for _ in range(count):
            u = self.rng.uniform(b.u0 + 2, b.u1 - 2)
            v = self.rng.uniform(b.v0 + 2, b.v1 - 2)
            x, y = self.frame.to_world([(u, v)])[0]
            r = self.rng.uniform(*radius)
            if self.free(self.rect(u - r, v - r, u + r, v + r)):
                self.plan.trees.append(Tree(float(x), float(y), r, r * self.rng.uniform(1.8, 3.2)))

    def add_parking(self, b: Block, fill: float, landmark_id: int = 0) -> None:
        polygon = self.rect(b.u0, b.v0, b.u1, b.v1)
        if not self.free(polygon):
            return
        self.plan.areas.append(Area(polygon, "parking", landmark_id, self.frame.u_axis))
        # Stalls 2.6 m wide, rows 5.5 m deep with a 6 m aisle between row pairs.
        heading = self.frame.theta + math.pi / 2
        v = b.v0 + 2.75
        row = 0
        while v < b.v1 - 2.75:
            u = b.u0 + 1.3
            while u < b.u1 - 1.3:
                if self.rng.random() < fill:
                    x, y = self.frame.to_world([(u, v)])[0]
                    colour = CAR_COLOURS[int(self.rng.integers(len(CAR_COLOURS)))]
                    self.plan.cars.append(Car(float(x), float(y), heading, colour))
                u += 2.6
            v += 5.5 if row % 2 == 0 else 11.5
            row += 1

    def street_trees(self, b: Block, spacing: float = 14.0) -> None:
        for (ua, va), (ub, vb) in (
            ((b.u0, b.v0 - 2), (b.u1, b.v0 - 2)),
            ((b.u0, b.v1 + 2), (b.u1, b.v1 + 2)),
            ((b.u0 - 2, b.v0), (b.u0 - 2, b.v1)),
            ((b.u1 + 2, b.v0), (b.u1 + 2, b.v1)),
        ):
            length = math.hypot(ub - ua, vb - va)
            for s in np.arange(spacing / 2, length, spacing):
                f = s / length
                x, y = self.frame.to_world([(ua + (ub - ua) * f, va + (vb - va) * f)])[0]
                r = self.rng.uniform(2.5, 3.8)
                if not shapely.intersects(shapely.Point(x, y).buffer(1.0), self.keep_out):
                    self.plan.trees.append(Tree(float(x), float(y), r, self.rng.uniform(7, 12)))

    def landmark(
        self, name: str, category: str, description: str, polygon: Polygon, height: float
    ) -> int:
        return self.plan.add_landmark(name, category, description, polygon, height)

    # ---------------------------------------------------------------- generic blocks
    def residential(self, b: Block) -> None:
        self.plan.areas.append(Area(self.rect(b.u0, b.v0, b.u1, b.v1), "lawn"))
        if b.depth >= 90:
            # Deep blocks get a back alley and a second row of houses on each side of it.
            mid = (b.v0 + b.v1) / 2
            self.plan.areas.append(Area(self.rect(b.u0, mid - 2.5, b.u1, mid + 2.5), "plaza"))
            rows = [(b.v0, 1.0), (mid - 2.5, -1.0), (mid + 2.5, 1.0), (b.v1, -1.0)]
        elif b.depth >= 40:
            rows = [(b.v0, 1.0), (b.v1, -1.0)]
        else:
            rows = [(b.v0, 1.0)]
        row_depth = b.depth / len(rows)
        for street_v, inwards in rows:
            u = b.u0 + self.rng.uniform(0, 4)
            while u < b.u1 - 10:
                width = min(self.rng.uniform(15, 24), b.u1 - u)
                self._house_parcel(u, width, street_v, inwards, row_depth)
                u += width
        if self.rng.random() < 0.6:
            self.street_trees(b)

    def _house_parcel(
        self, u: float, width: float, street_v: float, inwards: float, row_depth: float
    ) -> None:
        far_v = street_v + inwards * row_depth
        fence = self.rect(u, min(street_v, far_v), u + width, max(street_v, far_v))
        if self.free(fence):
            self.plan.fences.append(fence)
        margin = self.rng.uniform(2.0, 3.5)
        depth = min(self.rng.uniform(9, 14), row_depth - 6)
        setback = self.rng.uniform(3, 6)
        va = street_v + inwards * setback
        vb = va + inwards * depth
        if width - 2 * margin <= 7 or depth <= 6:
            return
        colour, colour_name = self.roof(HOUSE_ROOFS)
        footprint = self.rect(u + margin, min(va, vb), u + width - margin, max(va, vb))
        style: RoofStyle = "gable" if self.rng.random() < 0.6 else "hip"
        self.add_building(
            Building(
                footprint, style, colour, colour_name, self.rng.uniform(5, 10), self.frame.u_axis
            )
        )
        yard_end = vb + inwards * max(0.0, row_depth - setback - depth - 1)
        yard = Block(u + 1, min(vb, yard_end), u + width - 1, max(vb, yard_end))
        if yard.depth > 7 and self.rng.random() < 0.15:
            pu = u + width / 2
            pool = self.rect(pu - 2, yard.v0 + 1.5, pu + 2.5, yard.v0 + 6.5)
            if self.free(pool):
                self.plan.areas.append(Area(pool, "pool"))
        if yard.depth > 4:
            self.add_trees(yard, int(self.rng.integers(1, 4)))

    def commercial(self, b: Block) -> None:
        self.plan.areas.append(Area(self.rect(b.u0, b.v0, b.u1, b.v1), "plaza"))
        chunks = int(np.clip(round(b.width / self.rng.uniform(28, 50)), 1, 5))
        edges = np.linspace(b.u0, b.u1, chunks + 1)
        depth = min(self.rng.uniform(22, 40), b.depth * 0.45)
        for ua, ub in itertools.pairwise(edges):
            for street_v, inwards in ((b.v0, 1.0), (b.v1, -1.0)):
                if self.rng.random() < 0.2:
                    continue
                va, vb = (
                    street_v + inwards * 1.5,
                    street_v + inwards * (1.5 + depth * self.rng.uniform(0.7, 1.0)),
                )
                colour, colour_name = self.roof(COMMERCIAL_ROOFS)
                self.add_building(
                    Building(
                        self.rect(ua + 1.5, min(va, vb), ub - 1.5, max(va, vb)),
                        "flat",
                        colour,
                        colour_name,
                        float(self.rng.uniform(9, 40)),
                    )
                )
        inner = Block(b.u0 + 4, b.v0 + depth + 4, b.u1 - 4, b.v1 - depth - 4)
        if inner.width > 40 and inner.depth > 25 and self.rng.random() < 0.45:
            colour, colour_name = self.roof(COMMERCIAL_ROOFS)
            core = self.rect(inner.u0 + 4, inner.v0 + 3, inner.u1 - 4, inner.v1 - 3)
            self.add_building(
                Building(core, "flat", colour, colour_name, float(self.rng.uniform(8, 25)))
            )
        elif inner.width > 15 and inner.depth > 12:
            self.add_parking(inner, self.rng.uniform(0.15, 0.55))

    # ---------------------------------------------------------------- landmarks
    def park(self, b: Block, name: str) -> None:
        polygon = self.rect(b.u0, b.v0, b.u1, b.v1)
        lid = self.landmark(name, "park", "a green park with trees and footpaths", polygon, 0.0)
        self.plan.areas.append(Area(polygon, "park", lid))
        for _ in range(2):
            t = np.linspace(0, 1, 24)
            a, c = self.rng.uniform(0.1, 0.9, size=2)
            us = b.u0 + (b.u1 - b.u0) * t
            vs = b.v0 + b.depth * (
                a + (c - a) * t + 0.08 * np.sin(t * math.pi * self.rng.uniform(1, 3))
            )
            path = shapely.LineString(self.frame.to_world(np.stack([us, vs], axis=1))).buffer(1.6)
            self.plan.areas.append(Area(np.asarray(path.exterior.coords), "plaza", lid))
        if self.rng.random() < 0.45 and b.min_side > 60:
            pond = self.ellipse(
                (b.u0 + b.u1) / 2, (b.v0 + b.v1) / 2, b.width * 0.18, b.depth * 0.14, 32
            )
            self.plan.areas.append(Area(pond, "water", lid))
        self.add_trees(b, int(b.width * b.depth / 180), (2.5, 5.5))

    def stadium(self, b: Block, name: str) -> None:
        self.add_parking(b, self.rng.uniform(0.15, 0.45))
        uc, vc = (b.u0 + b.u1) / 2, (b.v0 + b.v1) / 2
        au, av = b.width * 0.42, b.depth * 0.40
        outer = self.ellipse(uc, vc, au, av, 64)
        lid = self.landmark(
            name, "stadium", "an oval stadium with a green field inside", outer, 20.0
        )
        self.plan.buildings.append(
            Building(outer, "flat", (196, 198, 200), "white", 20.0, landmark_id=lid)
        )
        self.plan.areas_top.append(
            Area(self.ellipse(uc, vc, au * 0.78, av * 0.74, 64), "track", lid)
        )
        field = self.rect(uc - au * 0.5, vc - av * 0.42, uc + au * 0.5, vc + av * 0.42)
        self.plan.areas_top.append(Area(field, "field", lid))

    def church(self, b: Block, name: str) -> Block:
        spot, rest = b.split_u(min(0.55, 60 / b.width))
        self.plan.areas.append(Area(self.rect(spot.u0, spot.v0, spot.u1, spot.v1), "lawn"))
        uc, vc = (spot.u0 + spot.u1) / 2, (spot.v0 + spot.v1) / 2
        nave_l, nave_w = min(spot.width * 0.7, 40.0), 12.0
        colour, colour_name = self.roof((0, 1, 3, 5, 4))
        nave = self.rect(uc - nave_l / 2, vc - nave_w / 2, uc + nave_l / 2, vc + nave_w / 2)
        transept = self.rect(
            uc + nave_l * 0.1, vc - nave_w * 1.1, uc + nave_l * 0.1 + 10, vc + nave_w * 1.1
        )
        tower = self.rect(uc - nave_l / 2 - 7, vc - 4, uc - nave_l / 2 + 1, vc + 4)
        hull = shapely.MultiPoint(np.concatenate([nave, transept, tower])).convex_hull
        lid = self.landmark(
            name,
            "church",
            f"a church with a cross-shaped {colour_name} roof and a bell tower",
            np.asarray(hull.exterior.coords)[:-1],
            35.0,
        )
        self.plan.buildings.append(
            Building(nave, "gable", colour, colour_name, 16.0, self.frame.u_axis, lid)
        )
        self.plan.buildings.append(
            Building(transept, "gable", colour, colour_name, 15.0, self.frame.v_axis, lid)
        )
        self.plan.buildings.append(Building(tower, "hip", colour, colour_name, 35.0, None, lid))
        self.add_trees(Block(spot.u0, spot.v0, spot.u1, vc - nave_w * 1.3), 3)
        return rest

    def gas_station(self, b: Block, name: str) -> Block:
        spot, rest = b.split_u(min(0.6, 50 / b.width))
        apron = self.rect(spot.u0, spot.v0, spot.u1, spot.v0 + min(spot.depth, 42))
        self.plan.areas.append(Area(apron, "apron"))
        uc = (spot.u0 + spot.u1) / 2
        canopy = self.rect(uc - 12, spot.v0 + 6, uc + 12, spot.v0 + 20)
        stripe = ((40, 40, 200), (190, 110, 20), (30, 140, 30), (20, 160, 230))[
            int(self.rng.integers(4))
        ]
        lid = self.landmark(
            name,
            "gas_station",
            "a gas station with a white canopy over the pumps",
            self.rect(spot.u0, spot.v0, spot.u1, spot.v0 + min(spot.depth, 42)),
            6.0,
        )
        self.plan.buildings.append(
            Building(
                canopy,
                "flat",
                (236, 236, 236),
                "white",
                6.0,
                landmark_id=lid,
                roof_mark="stripe",
                mark_colour=stripe,
            )
        )
        shop = self.rect(uc - 8, spot.v0 + 26, uc + 8, spot.v0 + 36)
        colour, colour_name = self.roof(COMMERCIAL_ROOFS)
        self.plan.buildings.append(
            Building(shop, "flat", colour, colour_name, 4.5, landmark_id=lid)
        )
        for k in range(int(self.rng.integers(1, 4))):
            x, y = self.frame.to_world([(uc - 8 + 5 * k, spot.v0 + 10)])[0]
            colour_car = CAR_COLOURS[int(self.rng.integers(len(CAR_COLOURS)))]
            self.plan.cars.append(
                Car(float(x), float(y), self.frame.theta + math.pi / 2, colour_car)
            )
        return Block(rest.u0, rest.v0, rest.u1, rest.v1)

    def restaurant(self, b: Block, name: str) -> Block:
        spot, rest = b.split_u(min(0.5, 32 / b.width))
        w, d = self.rng.uniform(14, 20), self.rng.uniform(11, 16)
        uc = (spot.u0 + spot.u1) / 2
        footprint = self.rect(uc - w / 2, spot.v0 + 4, uc + w / 2, spot.v0 + 4 + d)
        colour, colour_name = self.roof(VIVID_ROOFS)
        style: RoofStyle = "flat" if self.rng.random() < 0.5 else "hip"
        lid = self.landmark(
            f"{name} restaurant" if "restaurant" not in name.lower() else name,
            "restaurant",
            f"a small restaurant with a {colour_name} roof",
            footprint,
            6.0,
        )
        self.plan.areas.append(Area(self.rect(spot.u0, spot.v0, spot.u1, spot.v1), "plaza"))
        self.plan.buildings.append(
            Building(footprint, style, colour, colour_name, 6.0, self.frame.u_axis, lid)
        )
        lot = Block(spot.u0 + 1, spot.v0 + 8 + d, spot.u1 - 1, min(spot.v1, spot.v0 + 30 + d))
        if lot.depth > 8:
            self.add_parking(lot, 0.5)
        return rest

    def school(self, b: Block, name: str) -> None:
        self.plan.areas.append(Area(self.rect(b.u0, b.v0, b.u1, b.v1), "lawn"))
        left, right = b.split_u(0.45, gap=6)
        colour, colour_name = self.roof((3, 4, 8))
        wing_a = self.rect(left.u0 + 4, left.v0 + 4, left.u1 - 4, left.v0 + 20)
        wing_b = self.rect(left.u0 + 4, left.v0 + 20, left.u0 + 20, left.v1 - 6)
        lid = self.landmark(
            name,
            "school",
            f"a school with an L-shaped {colour_name} building and a running track",
            self.rect(b.u0, b.v0, b.u1, b.v1),
            10.0,
        )
        for wing in (wing_a, wing_b):
            self.plan.buildings.append(
                Building(wing, "flat", colour, colour_name, 10.0, landmark_id=lid)
            )
        uc, vc = (right.u0 + right.u1) / 2, (right.v0 + right.v1) / 2
        self.plan.areas.append(
            Area(self.ellipse(uc, vc, right.width * 0.45, right.depth * 0.42, 48), "track", lid)
        )
        self.plan.areas.append(
            Area(
                self.rect(
                    uc - right.width * 0.28,
                    vc - right.depth * 0.25,
                    uc + right.width * 0.28,
                    vc + right.depth * 0.25,
                ),
                "field",
                lid,
            )
        )

    def hospital(self, b: Block, name: str) -> None:
        self.add_parking(b, 0.45)
        main, _ = b.split_v(0.6, gap=8)
        footprint = self.rect(main.u0 + 6, main.v0 + 6, main.u1 - 6, main.v1 - 4)
        lid = self.landmark(
            name, "hospital", "a large white hospital with a red cross on its roof", footprint, 30.0
        )
        self.plan.buildings.append(
            Building(
                footprint,
                "flat",
                (226, 228, 230),
                "white",
                30.0,
                landmark_id=lid,
                roof_mark="cross",
                mark_colour=(40, 40, 210),
            )
        )

    def mall(self, b: Block, name: str) -> None:
        self.add_parking(b, 0.5)
        uc, vc = (b.u0 + b.u1) / 2, (b.v0 + b.v1) / 2
        hw, hd = b.width * 0.33, b.depth * 0.28
        footprint = self.rect(uc - hw, vc - hd, uc + hw, vc + hd)
        colour, colour_name = self.roof((4, 8, 3))
        lid = self.landmark(
            name,
            "mall",
            f"a shopping mall with a large flat {colour_name} roof surrounded by parking",
            self.rect(b.u0, b.v0, b.u1, b.v1),
            14.0,
        )
        self.plan.buildings.append(
            Building(footprint, "flat", colour, colour_name, 14.0, landmark_id=lid)
        )

    def hotel(self, b: Block, name: str) -> Block:
        spot, rest = b.split_u(min(0.6, 55 / b.width))
        self.plan.areas.append(Area(self.rect(spot.u0, spot.v0, spot.u1, spot.v1), "lawn"))
        uc = (spot.u0 + spot.u1) / 2
        footprint = self.rect(uc - 16, spot.v0 + 5, uc + 16, spot.v0 + 25)
        colour, colour_name = self.roof((3, 6, 4))
        height = float(self.rng.uniform(45, 80))
        lid = self.landmark(
            name,
            "hotel",
            f"a tall hotel with a {colour_name} roof and a swimming pool",
            footprint,
            height,
        )
        self.plan.buildings.append(
            Building(footprint, "flat", colour, colour_name, height, landmark_id=lid)
        )
        pool = self.rect(uc - 8, spot.v0 + 30, uc + 8, spot.v0 + 38)
        if self.free(pool):
            self.plan.areas.append(Area(pool, "pool", lid))
        return rest

    def tower(self, b: Block, name: str) -> Block:
        spot, rest = b.split_u(min(0.5, 45 / b.width))
        self.plan.areas.append(Area(self.rect(spot.u0, spot.v0, spot.u1, spot.v1), "plaza"))
        uc, vc = (spot.u0 + spot.u1) / 2, (spot.v0 + spot.v1) / 2
        side = min(30.0, spot.min_side * 0.7)
        footprint = self.rect(uc - side / 2, vc - side / 2, uc + side / 2, vc + side / 2)
        height = float(self.rng.uniform(90, 160))
        lid = self.landmark(name, "tower", "a skyscraper with a dark glass roof", footprint, height)
        self.plan.buildings.append(
            Building(footprint, "flat", (70, 52, 40), "dark blue", height, landmark_id=lid)
        )
        return rest

    def water_tower(self, b: Block, name: str) -> None:
        uc, vc = (b.u0 + b.u1) / 2 + b.width * 0.3, (b.v0 + b.v1) / 2
        footprint = self.ellipse(uc, vc, 8.0, 8.0, 32)
        if not self.free(footprint):
            return
        lid = self.landmark(name, "water_tower", "a round light blue water tower", footprint, 35.0)
        self.plan.buildings.append(
            Building(footprint, "dome", (215, 190, 150), "light blue", 35.0, landmark_id=lid)
        )
