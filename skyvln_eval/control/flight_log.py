"""The closed-loop log: one row per control step, saved as versioned Parquet.

Columns (:data:`LOG_COLUMNS`; other columns may follow):

- ``controller``, ``scenario`` (str): controller name and obstacle scenario name;
- ``t_s``: time on the flight clock at the start of the step;
- ``x_m`` ... ``yaw_rad``: the true state (ENU metres, m/s, rad) at ``t_s``;
- ``ref_x_m``, ``ref_y_m``, ``ref_z_m``, ``ref_yaw_rad``: the reference at ``t_s``;
- ``cmd_thrust_m_s2``, ``cmd_roll_rad``, ``cmd_pitch_rad``: the command held over the step
  (thrust and the roll / pitch *references* sent to the attitude loop);
- ``solve_time_ms``, ``iterations`` (QP solver iterations; 0 for PID), ``status`` and
  ``solve_failed`` (a fallback command was used);
- ``min_clearance_m``: over all obstacles and over the step (from ``t_s`` to the next
  step, drone and obstacles moving in straight lines in between), the least distance from
  the drone to an obstacle centre minus ``r_obs + r_s`` (negative = inside a keep-out
  sphere); ``inf`` without obstacles. Not only at ``t_s``: a controller that keeps its
  samples outside a sphere can cut through it between them;
- ``collision``: inside some obstacle's own sphere (distance < ``r_obs``) during the step;
- ``constraint_violation``: ``min_clearance_m < 0`` or a command outside the input bounds or
  beyond the per-step rate limit of roll_ref / pitch_ref.

Flights add ``ref_roll_rad``, ``ref_pitch_rad`` and ``predicted_path_m`` (the controller's
predicted positions over its horizon, a flat ``[x0, y0, z0, x1, ...]`` list in ENU metres,
or null for controllers without a prediction and for fallback steps).
"""

from __future__ import annotations

import io
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from skyvln_eval.errors import DataError, FormatVersionError
from skyvln_eval.fileio import atomic_write_bytes

LOG_FORMAT = "skyvln-flight-log"
#: The Parquet metadata key under which a flight log keeps its settings (JSON).
SETTINGS_KEY = b"skyvln_settings"
LOG_FORMAT_VERSION = 1
LOG_COLUMNS: tuple[str, ...] = (
    "controller",
    "scenario",
    "t_s",
    "x_m",
    "y_m",
    "z_m",
    "vx_m_s",
    "vy_m_s",
    "vz_m_s",
    "roll_rad",
    "pitch_rad",
    "yaw_rad",
    "ref_x_m",
    "ref_y_m",
    "ref_z_m",
    "ref_yaw_rad",
    "cmd_thrust_m_s2",
    "cmd_roll_rad",
    "cmd_pitch_rad",
    "solve_time_ms",
    "iterations",
    "status",
    "solve_failed",
    "min_clearance_m",
    "collision",
    "constraint_violation",
)
#: Extra column: the controller's predicted positions over its horizon, flattened
#: ``[x0, y0, z0, x1, ...]`` ENU metres (``None`` without a prediction).
PREDICTED_PATH_COLUMN = "predicted_path_m"
_STRING = ("controller", "scenario", "status")
_BOOL = ("solve_failed", "collision", "constraint_violation")
_INT = ("iterations",)


def log_frame(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """A log DataFrame from row dicts, with the columns in order and their dtypes fixed."""
    frame = pd.DataFrame(rows, columns=list(LOG_COLUMNS) if not rows else None)
    missing = [c for c in LOG_COLUMNS if c not in frame.columns]
    if missing:
        raise DataError(f"flight log rows lack the column(s) {', '.join(missing)}")
    extra = [c for c in frame.columns if c not in LOG_COLUMNS]
    frame = frame[[*LOG_COLUMNS, *extra]]
    types: dict[str, str] = {c: "float64" for c in LOG_COLUMNS if c not in _STRING + _BOOL + _INT}
    types.update(dict.fromkeys(_STRING, "str"))
    types.update(dict.fromkeys(_BOOL, "bool"))
    types.update(dict.fromkeys(_INT, "int64"))
    # Only the columns not inferred as their type are converted (astype copies every
    # column it is given, the same values for those already of the type).
    convert = {c: t for c, t in types.items() if str(frame[c].dtype) != t}
    return frame.astype(convert) if convert else frame


def save_flight_log(
    frame: pd.DataFrame, path: str | Path, settings: dict[str, Any] | None = None
) -> Path:
    """Write ``frame`` as Parquet (atomically), with the format version and ``settings``
    (e.g. the controller's and scenario's, JSON) in the file's metadata."""
    missing = [c for c in LOG_COLUMNS if c not in frame.columns]
    if missing:
        raise DataError(f"not a flight log: column(s) {', '.join(missing)} missing")
    table = pa.Table.from_pandas(frame, preserve_index=False)
    metadata = dict(table.schema.metadata or {})
    metadata[b"skyvln_format"] = LOG_FORMAT.encode()
    metadata[b"skyvln_format_version"] = str(LOG_FORMAT_VERSION).encode()
    metadata[SETTINGS_KEY] = json.dumps(settings or {}, default=str).encode()
    table = table.replace_schema_metadata(metadata)
    buffer = io.BytesIO()
    # Dictionary pages only for the text columns: on the floats they cost most of the
    # writing time and made the file larger (they are a storage detail: read back, the
    # columns are the same).
    pq.write_table(table, buffer, use_dictionary=[c for c in _STRING if c in frame.columns])
    atomic_write_bytes(path, buffer.getvalue())
    return Path(path)


def load_flight_log(path: str | Path) -> pd.DataFrame:
    """Read a flight log written by :func:`save_flight_log`, checking its format version.

    The settings stored with it are in ``frame.attrs["settings"]``.
    """
    path = Path(path)
    try:
        table = pq.read_table(path)
    except (OSError, pa.ArrowInvalid) as error:
        raise DataError(f"{path}: cannot read a flight log: {error}") from error
    metadata = table.schema.metadata or {}
    if metadata.get(b"skyvln_format") != LOG_FORMAT.encode():
        raise DataError(f"{path}: not a flight log (no '{LOG_FORMAT}' format marker)")
    version = metadata.get(b"skyvln_format_version", b"?").decode()
    if version != str(LOG_FORMAT_VERSION):
        raise FormatVersionError(
            str(path), version, LOG_FORMAT_VERSION, "Record the run again with this version."
        )
    frame = table.to_pandas()
    frame.attrs["settings"] = stored_settings(metadata, path)
    return frame


def stored_settings(metadata: Mapping[bytes, bytes] | None, path: Path) -> dict[str, Any]:
    """The settings :func:`save_flight_log` kept in a Parquet file's metadata (``{}``
    where none), for every reader of flight logs."""
    stored = (metadata or {}).get(SETTINGS_KEY)
    try:
        settings = json.loads(stored) if stored else {}
    except ValueError:
        raise DataError(f"{path}: its stored settings are not JSON") from None
    if not isinstance(settings, dict):  # another writer's metadata: not ours to read as {}
        raise DataError(f"{path}: its stored settings are not a JSON object")
    return settings
