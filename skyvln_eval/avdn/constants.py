"""Constants of the official AVDN code, kept in one place.

The official code works in raw (lat, lng) degrees with a flat 111,300 m per degree and
approximates pi/2 by 1.57 (heading) and pi by 3.14159 (step). Reproducing official rollouts
to the millimetre and their stored headings to the degree needs exactly these values, so
every module that must agree with the official code imports them from here.
"""

from __future__ import annotations

from typing import Final, Literal

#: Metres per degree, for both latitude and longitude (no cos(latitude) term).
METERS_PER_DEGREE: Final = 111_300.0

#: The official heading function divides arctan by this instead of pi/2.
OFFICIAL_HALF_PI: Final = 1.57

#: The official step converts degrees to radians (and atan2 to turns) with this pi.
OFFICIAL_PI: Final = 3.14159

#: View edge ("altitude") range of the official action space, metres.
MIN_VIEW_EDGE_M: Final = 40.0
MAX_VIEW_EDGE_M: Final = 400.0
#: ``target_edge_m = round(ALTITUDE_SPAN_M * clip(a, 0, 1)) + MIN_VIEW_EDGE_M``.
ALTITUDE_SPAN_M: Final = 360.0

#: Largest side, pixels, of a map (original or width-resized) the toolkit makes: the
#: synthetic maps are 2,500 px and xView's images a few thousand. A record's ratios that
#: describe a larger map are wrong (a 2500 x 549,822 px resize took 4 GB).
MAX_MAP_SIDE_PX: Final = 20_000

#: Side of the heading-up observation image, pixels.
OBSERVATION_SIZE_PX: Final = 224

#: Official success and oracle-success threshold on hull-IoU.
SUCCESS_IOU: Final = 0.4

#: Views per episode in the AVDN paper scripts, start view included.
DEFAULT_MAX_ACTION_LEN: Final = 10

Split = Literal["train", "val_seen", "val_unseen", "test_unseen"]
SPLITS: Final[tuple[Split, ...]] = ("train", "val_seen", "val_unseen", "test_unseen")

EpisodeMode = Literal["andh", "andh-full"]
EPISODE_MODES: Final[tuple[EpisodeMode, ...]] = ("andh", "andh-full")

ANNOTATIONS_DIR: Final = "annotations"
IMAGES_DIR: Final = "train_images"


def annotation_file_name(split: str) -> str:
    """File name of a split's annotations, e.g. ``val_unseen_data.json``."""
    return f"{split}_data.json"
