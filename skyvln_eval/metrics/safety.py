"""Safety and control metrics from closed-loop control logs.

A control log is a pandas DataFrame with one row per control step and the columns of
:data:`CONTROL_LOG_COLUMNS` (x east, y north, z up in metres; angles in radians; for
roll and pitch the reference is the commanded angle). ``min_clearance_m`` and
``collision`` are each step's over its whole duration, not at its sample alone
(:meth:`~skyvln_eval.sim.ObstacleScenario.swept_clearance_m`); ``min_clearance_m`` is
``inf`` when a scenario has no obstacles. Logs may hold several controllers and scenarios (and
an optional ``episode_id`` column); every metric is computed per group.

Per group: steps, duration, collision steps, minimum clearance (``None`` without
obstacles), constraint-violation steps, solver failures, tracking RMSE per axis (yaw
error wrapped to (-pi, pi]) and solve-time mean / median / 95th percentile / max.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from skyvln_eval.errors import DataError
from skyvln_eval.metrics.records import ControlSummary

CONTROL_LOG_COLUMNS: dict[str, str] = {
    "controller": "str",
    "scenario": "str",
    "t_s": "float",
    "x_m": "float",
    "y_m": "float",
    "z_m": "float",
    "vx_m_s": "float",
    "vy_m_s": "float",
    "vz_m_s": "float",
    "roll_rad": "float",
    "pitch_rad": "float",
    "yaw_rad": "float",
    "ref_x_m": "float",
    "ref_y_m": "float",
    "ref_z_m": "float",
    "ref_yaw_rad": "float",
    "cmd_thrust_m_s2": "float",
    "cmd_roll_rad": "float",
    "cmd_pitch_rad": "float",
    "solve_time_ms": "float",
    "iterations": "int",
    "status": "str",
    "solve_failed": "bool",
    "min_clearance_m": "float",
    "collision": "bool",
    "constraint_violation": "bool",
}

#: Flown column -> reference column for the tracking errors. Roll and pitch are measured
#: against the command (held over the next step): the attitude loop's tracking, about a
#: quarter of it its steady gain (0.75), not the reference trajectory's attitude
#: (``ref_roll_rad``, which older logs lack); the README says so beside the paper's.
TRACKED_AXES: dict[str, tuple[str, str]] = {
    "x": ("x_m", "ref_x_m"),
    "y": ("y_m", "ref_y_m"),
    "z": ("z_m", "ref_z_m"),
    "roll": ("roll_rad", "cmd_roll_rad"),
    "pitch": ("pitch_rad", "cmd_pitch_rad"),
    "yaw": ("yaw_rad", "ref_yaw_rad"),
}


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Angles (rad) wrapped to (-pi, pi]."""
    return np.pi - np.mod(np.pi - np.asarray(angle, dtype=np.float64), 2.0 * np.pi)


def tracking_errors(log: pd.DataFrame) -> pd.DataFrame:
    """Flown minus reference per step and axis (``err_x_m`` ... ``err_yaw_rad``)."""
    out = {}
    for axis, (flown, ref) in TRACKED_AXES.items():
        unit = "m" if flown.endswith("_m") else "rad"
        err = log[flown].to_numpy(np.float64) - log[ref].to_numpy(np.float64)
        out[f"err_{axis}_{unit}"] = wrap_angle(err) if axis == "yaw" else err
    return pd.DataFrame(out, index=log.index)


def check_control_log(log: pd.DataFrame, source: str = "<control log>") -> None:
    """Raise :class:`DataError` naming the source, column and row of the first problem."""
    missing = [c for c in CONTROL_LOG_COLUMNS if c not in log.columns]
    if missing:
        raise DataError(f"{source}: control log is missing column(s) {missing}")
    if log.empty:
        raise DataError(f"{source}: control log has no rows")
    for column, kind in CONTROL_LOG_COLUMNS.items():
        values = log[column]
        if kind == "float":
            arr = pd.to_numeric(values, errors="coerce").to_numpy(np.float64)
            finite = np.isfinite(arr)
            if column == "min_clearance_m":
                finite |= np.isposinf(arr)  # inf means "no obstacle"
            if not finite.all():
                row = int(np.flatnonzero(~finite)[0])
                raise DataError(
                    f"{source}: row {row}, column '{column}': non-finite value {values.iloc[row]!r}"
                )
        elif kind == "bool" and values.dtype != bool:
            raise DataError(f"{source}: column '{column}' must be boolean, got {values.dtype}")
        elif kind == "str" and values.isna().any():
            row = int(np.flatnonzero(values.isna().to_numpy())[0])
            raise DataError(f"{source}: row {row}, column '{column}': missing value")


#: What a control log is and where one comes from, for the errors of a file that is not one.
CONTROL_LOG_HINT = (
    "a control log is a table (.parquet or .csv) with one row per control step and the "
    "columns controller, scenario, t_s, x_m, ..., constraint_violation; a run in dynamics "
    "mode writes one per episode to RUN_DIR/control/<split>/<episode_id>.parquet, and "
    "`skyvln-eval reproduce` the paper's cases to OUT/control_runs/<case>_<controller>.parquet"
)


def read_control_log(path: str | Path) -> pd.DataFrame:
    """Read a control log from parquet or CSV and check it; a file that is not one (not a
    table, or a table of something else) is a :class:`DataError` naming it and saying what
    a control log is."""
    path = Path(path)
    if path.is_dir():
        raise DataError(f"{path}: a folder, not a control log; {CONTROL_LOG_HINT}")
    if not path.is_file():
        raise DataError(f"{path}: control log not found")
    if path.suffix not in (".parquet", ".csv"):
        raise DataError(f"{path}: unknown control log format; use .parquet or .csv")
    try:
        log = pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path)
    except (ValueError, UnicodeDecodeError) as error:
        # pandas' ParserError and EmptyDataError and pyarrow's ArrowInvalid are ValueErrors.
        reason = (str(error).strip().splitlines() or [type(error).__name__])[0]
        kind = "a parquet file" if path.suffix == ".parquet" else "CSV"
        raise DataError(
            f"{path}: not a control log (not {kind}: {reason}); {CONTROL_LOG_HINT}"
        ) from None
    if not {"controller", "t_s", "x_m"} & set(log.columns):  # some other table
        shown = ", ".join(str(c) for c in log.columns[:6]) + ("..." if len(log.columns) > 6 else "")
        raise DataError(f"{path}: not a control log (its columns: {shown}); {CONTROL_LOG_HINT}")
    check_control_log(log, str(path))
    if path.suffix == ".parquet":  # how it was flown, where the harness wrote it
        log.attrs["settings"] = _flight_settings(path)
    return log


def _flight_settings(path: Path) -> dict[str, Any]:
    """The settings the harness kept in a flight log's Parquet metadata (``{}`` where none)."""
    import pyarrow.parquet as pq

    # Here, not at the top: the control package imports CasADi (see summarise_control).
    from skyvln_eval.control.flight_log import stored_settings

    return stored_settings(pq.read_schema(path).metadata, path)


def _rmse(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(err))))


def _duration_s(t: NDArray[np.float64]) -> float | None:
    """From the first step's start to the last step's end: each row is a step from its
    ``t_s`` to the next row's, and the last lasts as long as the others (``None`` for one
    step, whose length the log does not hold)."""
    if len(t) < 2:
        return None
    return float(t.max() - t.min() + np.median(np.diff(np.sort(t))))


def summarise_control(
    log: pd.DataFrame, source: str = "<control log>", settings: dict[str, Any] | None = None
) -> ControlSummary:
    """The :class:`ControlSummary` of one controller on one scenario (one group);
    ``settings``: how it was flown (else the log's ``attrs["settings"]``, as
    :func:`read_control_log` and ``load_flight_log`` give them)."""
    settings = log.attrs.get("settings", {}) if settings is None else settings
    check_control_log(log, source)
    for column in ("controller", "scenario"):
        if log[column].nunique() != 1:
            raise DataError(f"{source}: one summary needs one {column}; use control_metrics()")
    err = tracking_errors(log)
    t = log["t_s"].to_numpy(np.float64)
    solve = log["solve_time_ms"].to_numpy(np.float64)
    clearance = log["min_clearance_m"].to_numpy(np.float64)
    controller = str(log["controller"].iloc[0])
    return ControlSummary(
        controller=controller,
        scenario=str(log["scenario"].iloc[0]),
        steps=len(log),
        duration_s=_duration_s(t),
        collision_steps=int(log["collision"].sum()),
        min_clearance_m=None if np.isposinf(clearance).all() else float(clearance.min()),
        constraint_violation_steps=int(log["constraint_violation"].sum()),
        solve_failures=int(log["solve_failed"].sum()),
        rmse_x_m=_rmse(err["err_x_m"].to_numpy()),
        rmse_y_m=_rmse(err["err_y_m"].to_numpy()),
        rmse_z_m=_rmse(err["err_z_m"].to_numpy()),
        rmse_roll_rad=_rmse(err["err_roll_rad"].to_numpy()),
        rmse_pitch_rad=_rmse(err["err_pitch_rad"].to_numpy()),
        rmse_yaw_rad=_rmse(err["err_yaw_rad"].to_numpy()),
        solve_time_mean_ms=float(solve.mean()),
        solve_time_p50_ms=float(np.percentile(solve, 50)),
        solve_time_p95_ms=float(np.percentile(solve, 95)),
        solve_time_max_ms=float(solve.max()),
        soft_steps=None
        if not _kept_out_by_a_constraint(controller, settings)
        else int((log["status"] == "solved_soft").sum()),
    )


def _kept_out_by_a_constraint(controller: str, settings: dict[str, Any]) -> bool:
    """Whether the controller's plan had an obstacle constraint to relax: not one without
    any (the PID), nor an MPC built with no obstacle slots (``max_obstacles: 0``, where
    the flight log's settings say so); an unknown controller is given the benefit."""
    # Here, not at the top: the control package imports CasADi, which scoring and
    # notebooks reading scores do not need.
    from skyvln_eval.control.registry import has_obstacle_constraint

    slots = settings.get("controller_settings", {}).get("max_obstacles")
    return has_obstacle_constraint(controller) is not False and slots != 0


def control_metrics(log: pd.DataFrame, source: str = "<control log>") -> pd.DataFrame:
    """One row of :class:`ControlSummary` fields per (controller, scenario[, episode_id]).

    Adds ``collided`` (any collision step). ``min_clearance_m`` is NaN-free: groups
    without obstacles get ``None`` (shown as "no obstacles" in reports).
    """
    check_control_log(log, source)
    keys = ["controller", "scenario"] + (["episode_id"] if "episode_id" in log.columns else [])
    rows = []
    for key, group in log.groupby(keys, sort=True):
        group = group.reset_index(drop=True)
        group.attrs = dict(log.attrs)  # the flight's settings, where the log has them
        summary = summarise_control(group, f"{source} {key}")
        row = summary.to_json_dict()
        if "episode_id" in keys:
            row["episode_id"] = key[2]
        row["collided"] = summary.collided
        rows.append(row)
    return pd.DataFrame(rows)
