"""The paper's 6-DOF figures: position and attitude, reference vs flown, with error curves.

One figure per scenario (e.g. static and dynamic obstacle cases), one line per
controller, from control logs (:data:`skyvln_eval.metrics.CONTROL_LOG_COLUMNS`). Layout,
4 rows x 3 columns: x / y / z position; x / y / z error; roll / pitch / yaw; roll /
pitch / yaw error; then a row across of the keep-out clearance over time, collisions
marked (tracking error alone would rank a controller that flies through obstacles
best). The position and yaw reference is drawn once in red when every
controller tracked the same reference (the usual case), else dashed per controller;
roll and pitch references are each controller's commanded angles (dotted), and their
error panels say "minus command": the attitude loop's steady gain is below 1 (about 0.75
for roll), so a steady offset there is the loop's, not a tracking fault. Errors are flown
minus reference (yaw wrapped to (-pi, pi]); yaw itself is drawn unwrapped (no vertical
line at +-180 degrees); angles in degrees. Yaw is held by the plant's own heading loop
under every controller (none of them commands it): its error panel says so, since its
dips differ between controllers only by when each reference turns. A figure draws one
flight per controller: a log holding several episodes of one controller is refused
(their times would interleave); controllers that flew different routes (from dynamics
runs, where each agent chose its own) are drawn, with a title saying that the comparison
is not like for like (the same route flown at another pace is one route).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from skyvln_eval.errors import DataError
from skyvln_eval.metrics.safety import check_control_log, tracking_errors
from skyvln_eval.reports.render import new_figure

if TYPE_CHECKING:  # matplotlib is imported when a figure is made (render.new_figure)
    from matplotlib.figure import Figure

_POSITION = (("x", "x_m", "ref_x_m"), ("y", "y_m", "ref_y_m"), ("z", "z_m", "ref_z_m"))
_ATTITUDE = (
    ("roll", "roll_rad", "cmd_roll_rad"),
    ("pitch", "pitch_rad", "cmd_pitch_rad"),
    ("yaw", "yaw_rad", "ref_yaw_rad"),
)
REFERENCE_COLOUR = "tab:red"
# skyvln_eval.control.recordings names the paper route's scenarios paper_<case> (kept out of
# an import: that module brings CasADi in).
_PAPER_SCENARIO_PREFIX = "paper_"


def control_figure_name(scenario: str, suffix: str) -> str:
    """The file name of a scenario's control figure, ``control_<case>.<suffix>``, for
    ``reproduce`` and ``plot control`` alike: the paper route's scenarios (``paper_dynamic``)
    are named by their case (``control_dynamic.png``), so that a figure drawn again from
    reproduce's control_runs/ replaces the one reproduce wrote instead of sitting beside it."""
    return f"control_{scenario.removeprefix(_PAPER_SCENARIO_PREFIX)}.{suffix}"


def _shared_reference(groups: dict[str, pd.DataFrame], column: str) -> bool:
    series = [g[["t_s", column]].to_numpy() for g in groups.values()]
    return all(s.shape == series[0].shape and np.allclose(s, series[0]) for s in series[1:])


def control_figure(
    log: pd.DataFrame, scenario: str | None = None, title: str | None = None
) -> Figure:
    """The 6-DOF figure of one scenario of ``log`` (every controller in it)."""
    check_control_log(log)
    scenarios = sorted(log["scenario"].unique())
    if scenario is None:
        if len(scenarios) != 1:
            raise DataError(f"the log has scenarios {scenarios}; choose one")
        scenario = scenarios[0]
    sel = log[log["scenario"] == scenario]
    if sel.empty:
        raise DataError(f"no rows for scenario {scenario!r}; the log has {scenarios}")
    groups = {c: g.sort_values("t_s") for c, g in sel.groupby("controller", sort=True)}
    for controller, g in groups.items():
        episodes = sorted(g["episode_id"].unique()) if "episode_id" in g else []
        if len(episodes) > 1:
            raise DataError(
                f"the log holds {len(episodes)} episodes of controller {controller!r} in "
                f"scenario {scenario!r} ({', '.join(map(str, episodes[:5]))}"
                f"{', ...' if len(episodes) > 5 else ''}): a figure "
                "draws one flight per controller, so pass one episode's control log"
            )
    colours = {c: f"C{k if k < 3 else k + 1}" for k, c in enumerate(groups)}  # C3 is red-like
    figure = new_figure(12.0, 12.0)
    grid = figure.add_gridspec(5, 3, height_ratios=[1, 1, 1, 1, 0.8])
    first = figure.add_subplot(grid[0, 0])
    axes = np.array(
        [
            [first if (r, c) == (0, 0) else figure.add_subplot(grid[r, c], sharex=first)
             for c in range(3)]
            for r in range(4)
        ]
    )  # fmt: skip
    for col, (axis, flown, ref) in enumerate(_POSITION):
        _plot_pair(axes[0, col], axes[1, col], groups, colours, axis, flown, ref, "m", 1.0)
    for col, (axis, flown, ref) in enumerate(_ATTITUDE):
        _plot_pair(
            axes[2, col], axes[3, col], groups, colours, axis, flown, ref, "deg", 180.0 / np.pi
        )
    _plot_clearance(figure.add_subplot(grid[4, :], sharex=first), groups, colours)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside lower center", ncols=len(labels))
    heading = title or f"6-DOF curves and errors, scenario: {scenario}"
    if not _same_route(groups):
        # From dynamics runs, each controller flew the route its own agent chose: the
        # panels compare different flights through different encounters.
        heading += "\nthe controllers flew different routes: not a like-for-like comparison"
    figure.suptitle(heading)
    return figure


#: How far apart two references' paths may pass and still be one route (m): the spacing
#: of a reference's points at cruise speed is about 1.2 m.
_SAME_ROUTE_M = 2.0


def _same_route(groups: dict[str, pd.DataFrame]) -> bool:
    """Whether every controller's reference passes where the first one's does (and back),
    whatever the timing: on the paper's route each segment starts when the drone arrives,
    so a slower controller's reference is the same path, later."""
    from scipy.spatial import cKDTree

    paths = [g[["ref_x_m", "ref_y_m", "ref_z_m"]].to_numpy(np.float64) for g in groups.values()]
    first = cKDTree(paths[0])
    for path in paths[1:]:
        there, back = first.query(path)[0], cKDTree(path).query(paths[0])[0]
        if max(there.max(), back.max()) > _SAME_ROUTE_M:
            return False
    return True


def _plot_clearance(ax: object, groups: dict[str, pd.DataFrame], colours: dict[str, str]) -> None:
    """Keep-out clearance over time (each step's least, over the step), collisions marked:
    a controller that tracks best by flying through the obstacles shows it here."""
    from matplotlib.axes import Axes

    assert isinstance(ax, Axes)
    ax.axhline(0.0, color=REFERENCE_COLOUR, lw=0.8, ls="--")
    drawn = False
    for controller, g in groups.items():
        clearance = g["min_clearance_m"].to_numpy(np.float64)
        if np.isposinf(clearance).all():
            continue  # no obstacles in this scenario
        drawn = True
        hits = int(g["collision"].sum())
        label = f"{controller}: {hits} collision step(s)" if hits else f"{controller}: no collision"
        ax.plot(g["t_s"], clearance, color=colours[controller], lw=1.1, label=label)
        inside = g["collision"].to_numpy(bool)
        ax.plot(g["t_s"][inside], clearance[inside], "x", color=colours[controller], ms=4)
    ax.set_title(
        "keep-out clearance (below 0: inside r_obs + r_s; x: a collision)"
        if drawn
        else "keep-out clearance: no obstacles in this scenario"
    )
    ax.set_ylabel("clearance (m)")
    ax.set_xlabel("time (s)")
    ax.grid(True, lw=0.3, alpha=0.6)
    if drawn:
        ax.legend(fontsize="small", loc="upper right")


def _plot_pair(
    ax_value: object,
    ax_error: object,
    groups: dict[str, pd.DataFrame],
    colours: dict[str, str],
    axis: str,
    flown: str,
    ref: str,
    unit: str,
    scale: float,
) -> None:
    from matplotlib.axes import Axes

    assert isinstance(ax_value, Axes) and isinstance(ax_error, Axes)
    is_command = ref.startswith("cmd_")
    shared = not is_command and _shared_reference(groups, ref)
    # Yaw is drawn unwrapped: a heading through +-180 degrees is not a jump.
    shown = np.unwrap if axis == "yaw" else np.asarray
    if shared:
        first = next(iter(groups.values()))
        ax_value.plot(
            first["t_s"],
            shown(first[ref].to_numpy()) * scale,
            color=REFERENCE_COLOUR,
            lw=1.6,
            ls="--",
            label="reference",
        )
    for controller, g in groups.items():
        colour = colours[controller]
        ax_value.plot(
            g["t_s"], shown(g[flown].to_numpy()) * scale, color=colour, lw=1.2, label=controller
        )
        if not shared:
            label = f"{controller} command" if is_command else f"{controller} reference"
            ax_value.plot(
                g["t_s"],
                shown(g[ref].to_numpy()) * scale,
                color=colour,
                lw=0.9,
                ls=":" if is_command else "--",
                label=label,
            )
        err_column = f"err_{axis}_{'m' if unit == 'm' else 'rad'}"
        ax_error.plot(g["t_s"], tracking_errors(g)[err_column] * scale, color=colour, lw=1.1)
    what = "position" if unit == "m" else "angle" + (" (dotted: command)" if is_command else "")
    ax_value.set_title(f"{axis} {what}")
    ax_value.set_ylabel(f"{axis} ({unit})")
    ax_error.set_title(
        f"{axis} minus command"
        if is_command
        # Two lines: on one, a panel's width cut it off.
        else f"{axis} error\n(the plant's heading loop, under every controller)"
        if axis == "yaw"
        else f"{axis} error"
    )
    ax_error.set_ylabel(f"error ({unit})")
    ax_error.axhline(0.0, color="0.6", lw=0.6)
    for ax in (ax_value, ax_error):
        ax.grid(True, lw=0.3, alpha=0.6)
