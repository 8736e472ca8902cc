"""Control signals of a flown episode as scalar series: 6-DoF states, references, commands.

Each ``/control/step`` message adds one sample to every series it has a value for. The
samples are numbers only (a few hundred bytes per step), so they are collected while the
log streams and sent as columns at the end, one call per series.

Series (under ``control/``; a plot's origin groups a state with its reference):
``x_m``, ``y_m``, ``z_m``, ``yaw_rad`` (``state`` and ``reference``), ``roll_rad`` and
``pitch_rad`` (``state`` and ``command``: the attitude references the controller sends),
``velocity_m_s/{x,y,z}``, ``thrust_m_s2/command``, ``solve_time_ms``, ``iterations``,
``min_clearance_m``, and ``flags/{relaxed,solve_failed,constraint_violation,collision}``
(1 on a step so flagged, else 0).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

Json = Mapping[str, Any]


def _item(key: str, index: int) -> Callable[[Json], Any]:
    def get(step: Json) -> Any:
        values = step.get(key)
        return values[index] if isinstance(values, list) and len(values) > index else None

    return get


def _flag(key: str, when: Any = True) -> Callable[[Json], Any]:
    """1.0 where the step's ``key`` is ``when``, else 0.0 (None where the step lacks it)."""

    def get(step: Json) -> Any:
        return None if key not in step else float(step[key] == when)

    return get


def _field(*keys: str) -> Callable[[Json], Any]:
    def get(step: Json) -> Any:
        value: Any = step
        for key in keys:
            value = value.get(key) if isinstance(value, Mapping) else None
        return value

    return get


#: Series path under ``control/`` and how to read it from a ControlStep message.
SERIES: dict[str, Callable[[Json], Any]] = {
    "x_m/state": _item("position_m", 0),
    "x_m/reference": _item("reference_position_m", 0),
    "y_m/state": _item("position_m", 1),
    "y_m/reference": _item("reference_position_m", 1),
    "z_m/state": _item("position_m", 2),
    "z_m/reference": _item("reference_position_m", 2),
    "yaw_rad/state": _item("attitude_rad", 2),
    "yaw_rad/reference": _field("reference_yaw_rad"),
    "roll_rad/state": _item("attitude_rad", 0),
    "roll_rad/command": _field("command", "roll_rad"),
    "pitch_rad/state": _item("attitude_rad", 1),
    "pitch_rad/command": _field("command", "pitch_rad"),
    "velocity_m_s/x": _item("velocity_m_s", 0),
    "velocity_m_s/y": _item("velocity_m_s", 1),
    "velocity_m_s/z": _item("velocity_m_s", 2),
    "thrust_m_s2/command": _field("command", "thrust_m_s2"),
    "solve_time_ms": _field("solve_time_ms"),
    "iterations": _field("iterations"),
    "min_clearance_m": _field("min_clearance_m"),
    # Steps flagged (1) or not (0): the plan relaxed the obstacle constraint (its slack
    # used), the solve failed (the controller fell back), inside the keep-out sphere, a crash.
    "flags/relaxed": _flag("status", "solved_soft"),
    "flags/solve_failed": _flag("solve_failed"),
    "flags/constraint_violation": _flag("constraint_violation"),
    "flags/collision": _flag("collision"),
}

#: Plot groups for the default layout: title and the series origins it shows.
PLOTS: tuple[tuple[str, str], ...] = (
    ("x (m)", "x_m"),
    ("y (m)", "y_m"),
    ("z (m)", "z_m"),
    ("yaw (rad)", "yaw_rad"),
    ("roll (rad)", "roll_rad"),
    ("pitch (rad)", "pitch_rad"),
    ("velocity (m/s)", "velocity_m_s"),
    ("thrust (m/s²)", "thrust_m_s2"),
    ("solve time (ms)", "solve_time_ms"),
    ("QP iterations", "iterations"),
    ("keep-out clearance (m)", "min_clearance_m"),  # to radius + safety margin
    ("flagged steps (0/1)", "flags"),
)


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    number = float(value)
    return number if math.isfinite(number) else None


@dataclass
class Series:
    """Samples of one series: simulated time (ns) and value."""

    t_ns: list[int] = field(default_factory=list)
    values: list[float] = field(default_factory=list)


@dataclass
class ControlSignals:
    """Collects the samples of every series as ``/control/step`` messages stream past."""

    series: dict[str, Series] = field(default_factory=dict)
    steps: int = 0

    def add(self, step: Json, t_ns: int) -> None:
        self.steps += 1
        for name, read in SERIES.items():
            value = _number(read(step))
            if value is None:
                continue
            samples = self.series.setdefault(name, Series())
            samples.t_ns.append(t_ns)
            samples.values.append(value)
