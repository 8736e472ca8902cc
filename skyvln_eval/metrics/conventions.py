"""The conventions every score depends on, in one object written into every output.

Peers disagree on 2-D vs 3-D distance, strict vs non-strict thresholds, the SPL reference
length and the DTW flavour; a number without its conventions cannot be compared. Every
scores file, table and CSV this package writes carries ``MetricConventions.to_dict()``.

The official AVDN metrics (success, oracle success, SPL, GP) do not depend on these
choices except ``legacy_gp`` and ``collision_fails``; they always use hull-IoU 0.4 and
flat 2-D degrees.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields
from typing import TYPE_CHECKING, Any, Literal

from skyvln_eval.avdn.constants import SUCCESS_IOU
from skyvln_eval.errors import ConfigError, MetricInputError

if TYPE_CHECKING:
    import pandas as pd

DistanceMode = Literal["2d", "3d"]

#: Version of the metric definitions; bumped when a formula changes (2: a flight that
#: touched an obstacle never succeeds, ``collision_fails``; 3: an episode that ended in
#: error has nDTW and CLS 0, as one that raised before its first view had).
METRICS_VERSION = 3


@dataclass(frozen=True)
class MetricConventions:
    """Choices behind the R2R-family metrics, plus the official-metric options.

    - ``distance``: ``"2d"`` uses view centres in flat metres (111,300 m/deg, as the
      official code); ``"3d"`` adds a height of ``edge_m / 2`` to each centre (a 90
      degree camera looking down sees an edge of twice its height).
    - ``threshold_m``: the R2R success radius, also the nDTW / SDTW / CLS normaliser
      ``d_th`` (as VLN-CE does). 20 m is the aerial-VLN custom (AerialVLN, CityNav).
    - ``strict_threshold``: success is ``NE < threshold_m`` if true, ``<=`` if false.
    - ``legacy_gp``: official GP against ``G[N-2]`` instead of ``G[N-1]``, as the
      official code computed it until November 2023.
    - ``collision_fails``: an episode whose flight touched an obstacle (dynamics mode)
      never succeeds (SR, OSR, SPL, R2R SR/OSR/SPL/SDTW are 0 for it), as an episode
      that ended in error never does: a crashed drone did not complete its task, and by
      default the crash ends the flight where it happened, which may lie in the
      destination's view (AVDN's success reads the final view only) with a path shorter
      than the shortest one, an SPL of 1. False scores such flights on their views alone.
    - ``success_iou``: the official hull-IoU threshold (fixed at 0.4; recorded only).
    - ``metrics_version``: version of the formulas in this package.

    The SPL of the R2R family uses the ground-truth path length as the reference; the
    DTW is exact (full dynamic programme, no window) with a Euclidean cost.
    """

    distance: DistanceMode = "2d"
    threshold_m: float = 20.0
    strict_threshold: bool = True
    legacy_gp: bool = False
    collision_fails: bool = True
    success_iou: float = SUCCESS_IOU
    spl_reference: Literal["gt_path_length"] = "gt_path_length"
    dtw: Literal["exact_euclidean"] = "exact_euclidean"
    metrics_version: int = METRICS_VERSION

    def __post_init__(self) -> None:
        if self.distance not in ("2d", "3d"):
            raise ConfigError(f"distance must be '2d' or '3d', not {self.distance!r}")
        if not (isinstance(self.threshold_m, int | float) and math.isfinite(self.threshold_m)):
            raise ConfigError(f"threshold_m must be a finite number, not {self.threshold_m!r}")
        if self.threshold_m <= 0:
            raise ConfigError(f"threshold_m must be positive, not {self.threshold_m!r}")
        if self.success_iou != SUCCESS_IOU:
            raise ConfigError(
                f"success_iou is the official {SUCCESS_IOU} and cannot be changed "
                f"(got {self.success_iou!r}); use the SR-vs-threshold curve for other radii"
            )
        if self.metrics_version != METRICS_VERSION:
            raise ConfigError(
                f"scored with metrics_version {self.metrics_version}; this toolkit's formulas "
                f"are version {METRICS_VERSION} (a definition changed): score the results "
                "again with `skyvln-eval score`"
            )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def to_json(self) -> str:
        """One compact, key-sorted line (stable across runs), for file headers."""
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))

    def describe(self) -> str:
        """A one-line human summary for table footnotes."""
        cmp = "<" if self.strict_threshold else "<="
        gp = "G[N-2] (legacy)" if self.legacy_gp else "G[N-1]"
        crash = (
            "a flight that touched an obstacle never succeeds"
            if self.collision_fails
            else "flights that touched an obstacle are scored on their views alone"
        )
        return (
            f"official AVDN SR/OSR/SPL (hull-IoU {self.success_iou}), GP vs {gp}; "
            f"R2R family on {self.distance.upper()} view centres, success NE {cmp} "
            f"{self.threshold_m:g} m, SPL vs GT path length, exact Euclidean DTW; {crash} "
            f"(metrics v{self.metrics_version})"
        )

    @classmethod
    def from_dict(cls, data: Any, where: str = "conventions") -> MetricConventions:
        if not isinstance(data, dict):
            raise ConfigError(f"{where}: expected an object, got {type(data).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"{where}: unknown field(s) {unknown}; known: {sorted(known)}")
        return cls(**data)


#: Where a scores frame (and its summary) keeps the :class:`MetricConventions` that
#: scored it (``frame.attrs``).
CONVENTIONS_ATTR = "skyvln_conventions"


def check_conventions(frame: pd.DataFrame, conventions: MetricConventions, what: str) -> None:
    """Refuse to label ``frame`` with other conventions than those that scored it, when it
    says (pandas keeps ``attrs`` through most operations; a frame that lost them is not
    checked)."""
    scored = frame.attrs.get(CONVENTIONS_ATTR)
    if isinstance(scored, MetricConventions) and scored != conventions:
        raise MetricInputError(
            f"{what} would say the conventions {conventions.describe()}, but its scores were "
            f"made with {scored.describe()}: pass the conventions that scored them"
        )
