"""Figures that describe a loaded split: sizes, path lengths, views, dialog rounds."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from skyvln_eval.avdn.geometry import distance_m, hull_iou, view_centre, view_edge_m
from skyvln_eval.avdn.loader import AvdnSplit
from skyvln_eval.avdn.step import replay_ground_truth


@dataclass(frozen=True)
class SplitSummary:
    split: str
    records: int
    skipped_records: int
    trajectories: int
    maps: int
    rounds: dict[int, int]  # number of trajectories with that many rounds
    mean_views: float
    mean_gt_length_m: float
    mean_d_net_m: float
    min_edge_m: float
    max_edge_m: float
    mean_dialog_turns: float
    ground_truth_withheld: bool
    gt_replay_min_iou: float | None  # None when the ground truth is withheld


def summarise_split(split: AvdnSplit, replay: bool = True) -> SplitSummary:
    """Describe a split; with ``replay``, also fly every GT path with official actions.

    The replay figure is the smallest hull-IoU between a replayed end view and its GT end
    view; 1 means every GT path is reproduced by the official step.
    """
    records = split.records
    trajectories = split.trajectories()
    lengths, d_net, views, edges, turns = [], [], [], [], []
    replay_ious = []
    for record in records:
        corners = record.gt_path_corners
        centres = view_centre(corners)
        lengths.append(float(distance_m(centres[1:], centres[:-1]).sum()))
        d_net.append(float(distance_m(centres[0], centres[-1])))
        views.append(len(corners))
        edges.extend(np.atleast_1d(view_edge_m(corners)).tolist())
        turns.append(len(record.dialog()))
        if replay and record.has_ground_truth:
            replayed = replay_ground_truth(corners, record.gps_botm_left, record.gps_top_right)
            replay_ious.append(float(hull_iou(replayed[-1], corners[-1])))

    def mean(values: list[float] | list[int]) -> float:
        return float(np.mean(values)) if values else float("nan")

    return SplitSummary(
        split=split.split,
        records=len(records),
        skipped_records=len(split.skipped_record_indices),
        trajectories=len(trajectories),
        maps=len(split.map_names()),
        rounds=dict(sorted(Counter(len(r) for r in trajectories.values()).items())),
        mean_views=mean(views),
        mean_gt_length_m=mean(lengths),
        mean_d_net_m=mean(d_net),
        min_edge_m=min(edges) if edges else float("nan"),
        max_edge_m=max(edges) if edges else float("nan"),
        mean_dialog_turns=mean(turns),
        ground_truth_withheld=split.ground_truth_withheld,
        gt_replay_min_iou=min(replay_ious) if replay_ious else None,
    )
