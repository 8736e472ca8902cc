"""Where a recording is drawn: the open stream, its clock and the rows logged per entity.

:class:`Canvas` wraps a Rerun ``RecordingStream``: it sets both timelines for a message
time (the decision index is the last decision made at or before it), logs archetypes and
counts the rows of every entity, and draws line strips in map pixels (2-D) or metres (3-D).
"""

from __future__ import annotations

import bisect
from collections import Counter
from collections.abc import Sequence
from types import ModuleType
from typing import Any

import numpy as np

from skyvln_eval.viewer import entities as e
from skyvln_eval.viewer.scene import Strip


class Canvas:
    """One episode's recording stream with its map frame and decision clock."""

    def __init__(
        self, rr: ModuleType, rec: Any, frame: e.MapFrame, decision_times_ns: Sequence[int]
    ) -> None:
        self.rr = rr
        self.rec = rec
        self.frame = frame
        self.decision_times_ns = sorted(decision_times_ns) or [0]
        self.rows: Counter[str] = Counter()
        self.t_ns = 0
        self.decision = 0

    def at(self, t_ns: int, continuous: bool = False) -> None:
        """Log what follows at ``t_ns`` on the ``sim_time`` and ``decision`` timelines.

        A ``continuous`` signal (the flight's poses, control steps, obstacles) is on the
        decision timeline only at a decision's own time: logged there between decisions,
        decision k would show the drone where it was just before decision k+1, away from
        the view, image and text of decision k."""
        self.t_ns = t_ns
        self.decision = max(0, bisect.bisect_right(self.decision_times_ns, t_ns) - 1)
        if continuous and self.decision_times_ns[self.decision] != t_ns:
            self.rec.disable_timeline(e.DECISION_TIMELINE)
        else:
            self.rec.set_time(e.DECISION_TIMELINE, sequence=self.decision)
        self.rec.set_time(e.SIM_TIMELINE, duration=np.timedelta64(t_ns, "ns"))

    def put(self, path: str, archetype: Any, static: bool = False) -> None:
        """Log one row (counted) at the current time, or timeless when ``static``."""
        self.rec.log(path, archetype, static=static)
        self.rows[path] += 1

    def markdown(self, path: str, text: str, static: bool = False) -> None:
        document = self.rr.TextDocument(text, media_type=self.rr.MediaType.MARKDOWN)
        self.put(path, document, static=static)

    def strips2d(self, strips: Sequence[Strip], width_pt: float = 1.5) -> Any:
        """Line strips given in ENU metres, drawn in map pixels."""
        return self.rr.LineStrips2D(
            [self.frame.pixels(s.points) for s in strips],
            colors=[s.rgba for s in strips],
            radii=self.rr.Radius.ui_points(width_pt),
        )

    def strips3d(self, strips: Sequence[Strip], width_pt: float = 1.5) -> Any:
        return self.rr.LineStrips3D(
            [s.points for s in strips],
            colors=[s.rgba for s in strips],
            radii=self.rr.Radius.ui_points(width_pt),
        )
