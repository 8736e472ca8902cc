"""The default layout of an episode recording in the Rerun viewer.

Left: the map (2-D, map pixels) over the camera view below the drone. Middle: the 3-D
scene (ENU metres, the map on the ground, the eye on the flight) over the control plots.
Right: the episode card, the decision, HSD, memory, dialog and LLM texts in tabs, over
the logs. Everything can be rearranged in the viewer.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from types import ModuleType
from typing import Any

from skyvln_eval.viewer import entities as e
from skyvln_eval.viewer.signals import PLOTS


@dataclass(frozen=True)
class Focus:
    """Where the 3-D view's eye starts (ENU metres) and what it looks at."""

    eye_m: list[float]
    target_m: list[float]


def episode_blueprint(
    rr: ModuleType,
    modules: Sequence[str],
    views: Sequence[str],
    focus: Focus | None = None,
    run_log: bool = True,
) -> Any:
    """The layout; ``modules`` are the LLM modules and ``views`` the detection views
    logged; an episode log (not ``run_log``) shows its ground-truth views where a run's
    log shows what the agent saw."""
    rrb = rr.blueprint
    eye = None
    if focus is not None:
        eye = rrb.EyeControls3D(position=focus.eye_m, look_target=focus.target_m, eye_up=[0, 0, 1])
    below = (
        rrb.Spatial2DView(origin=e.CAMERA_OBSERVATION, name="official view")
        if run_log
        else rrb.Spatial2DView(origin=e.CAMERA_GT_OBSERVATION, name="ground-truth view")
    )
    camera_views = [below] + [
        rrb.Spatial2DView(origin=e.camera_view(v), name=f"camera: {v}") for v in views
    ]
    plots = [
        rrb.TimeSeriesView(origin=f"{e.CONTROL}/{origin}", name=title) for title, origin in PLOTS
    ]
    texts = [
        # The episode first: its status (an error, a degraded run) is what to see first.
        rrb.TextDocumentView(origin=e.EPISODE_INFO, name="episode"),
        rrb.TextDocumentView(origin=e.AGENT_STEP, name="decision"),
        rrb.TextDocumentView(origin=e.AGENT_HSD, name="HSD"),
        rrb.TextDocumentView(origin=e.AGENT_MEMORY, name="memory graph"),
        rrb.TextDocumentView(origin=f"{e.DIALOG}/all", name="dialog"),
        *[rrb.TextDocumentView(origin=f"{e.LLM}/{m}", name=f"LLM {m}") for m in modules],
    ]
    logs = rrb.TextLogView(
        origin="/",
        contents=[e.DIALOG, e.AGENT_LOG, e.LLM_LOG],
        name="dialog, decisions and LLM calls",
    )
    layout = rrb.Horizontal(
        rrb.Vertical(
            rrb.Spatial2DView(origin=e.MAP, name="map (map pixels)"),
            rrb.Tabs(*camera_views),
            row_shares=[3, 2],
        ),
        rrb.Vertical(
            rrb.Spatial3DView(origin=e.WORLD, name="3-D scene (ENU m)", eye_controls=eye),
            rrb.Tabs(*plots),
            row_shares=[3, 2],
        ),
        rrb.Vertical(rrb.Tabs(*texts), logs, row_shares=[3, 2]),
        column_shares=[3, 3, 2],
    )
    return rrb.Blueprint(
        layout,
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        # Simulated time by default: the flight and the control plots move continuously;
        # the decision timeline steps from one decision to the next.
        rrb.TimePanel(timeline=e.SIM_TIMELINE, state="collapsed"),
    )
