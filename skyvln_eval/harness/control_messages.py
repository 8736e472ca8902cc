"""The run log's per-control-step messages (``/tf`` and ``/control/step``), written fast.

A dynamics episode has hundreds of control steps, each with three messages: the drone's
level heading frame and the airframe with its roll and pitch (``/tf``), and the step. Building a
dict per message and handing it to the writer's JSON encoder cost most of a run log's
time, so rows are turned into the writer's JSON text here, column by column.

The text must be byte for byte what :func:`~skyvln_eval.converters.writer.encode_json`
writes for the dicts :func:`control_step_message`, :func:`drone_tf` and :func:`body_tf`
build (the
reference; the tests compare the two). That holds because the JSON encoder writes a
float as ``float.__repr__``, an int as ``int.__repr__``, a bool as ``true``/``false``
and a string by ``json.dumps`` rules, and the templates are the reference dicts with
slots, encoded once (:class:`~skyvln_eval.converters.json_template.JsonTemplate`). A
row the encoder would refuse or treat differently (a NaN or infinite value, an odd
column type) keeps its dicts, so the writer fails on it exactly as before.
"""

from __future__ import annotations

import functools
import json
import math
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from skyvln_eval.control.flight_log import PREDICTED_PATH_COLUMN
from skyvln_eval.converters import messages as fx
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.float_text import float_texts, point_list_texts
from skyvln_eval.converters.json_template import JsonTemplate, slot
from skyvln_eval.frames import ViewPose

NS = fx.NS_PER_S

_POSITION = ("x_m", "y_m", "z_m")
_VELOCITY = ("vx_m_s", "vy_m_s", "vz_m_s")
_ATTITUDE = ("roll_rad", "pitch_rad", "yaw_rad")
_REFERENCE = ("ref_x_m", "ref_y_m", "ref_z_m")
_COMMAND = ("cmd_thrust_m_s2", "cmd_roll_rad", "cmd_pitch_rad")
#: The flight log's columns the messages write as floats (all must be finite).
FLOAT_COLUMNS = (
    "t_s",
    *_POSITION,
    *_VELOCITY,
    *_ATTITUDE,
    *_REFERENCE,
    "ref_yaw_rad",
    *_COMMAND,
    "solve_time_ms",
)
_STRING_COLUMNS = ("controller", "status")
_BOOL_COLUMNS = ("solve_failed", "collision", "constraint_violation")

#: One (log time, topic, message) per message; a message is a dict or its JSON bytes.
Message = tuple[int, str, Any]


def ns(t_s: float) -> int:
    return max(0, round(t_s * NS))


def drone_tf(t_ns: int, pose: ViewPose) -> Any:
    return fx.frame_transform(
        t_ns,
        t.MAP_FRAME,
        t.DRONE_FRAME,
        fx.vector3(pose.x_m, pose.y_m, pose.z_m),
        fx.yaw_quaternion(pose.yaw_rad),
    )


def body_tf(t_ns: int, pose: ViewPose, roll_rad: float, pitch_rad: float) -> Any:
    """The airframe at ``pose`` tilted by the model's world-frame roll and pitch."""
    return fx.frame_transform(
        t_ns,
        t.MAP_FRAME,
        t.BODY_FRAME,
        fx.vector3(pose.x_m, pose.y_m, pose.z_m),
        fx.attitude_quaternion(roll_rad, pitch_rad, pose.yaw_rad),
    )


def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _predicted_positions(flat: Any) -> list[list[float]] | None:
    if flat is None or len(flat) == 0:
        return None
    return np.asarray(flat, dtype=np.float64).reshape(-1, 3).tolist()


def control_step_message(columns: dict[str, Any], i: int, t_ns: int, pose: ViewPose) -> Any:
    """Row ``i``'s ``/control/step`` message as a dict (the reference for the fast text)."""
    predicted = columns.get(PREDICTED_PATH_COLUMN)
    return {
        "timestamp": fx.timestamp(t_ns),
        "controller": str(columns["controller"][i]),
        "position_m": [pose.x_m, pose.y_m, pose.z_m],
        "velocity_m_s": [float(columns[c][i]) for c in _VELOCITY],
        "attitude_rad": [float(columns[c][i]) for c in _ATTITUDE],
        "reference_position_m": [float(columns[c][i]) for c in _REFERENCE],
        "reference_yaw_rad": float(columns["ref_yaw_rad"][i]),
        "command": {
            "thrust_m_s2": float(columns["cmd_thrust_m_s2"][i]),
            "roll_rad": float(columns["cmd_roll_rad"][i]),
            "pitch_rad": float(columns["cmd_pitch_rad"][i]),
        },
        "solve_time_ms": float(columns["solve_time_ms"][i]),
        "iterations": int(columns["iterations"][i]),
        "status": str(columns["status"][i]),
        "solve_failed": bool(columns["solve_failed"][i]),
        "min_clearance_m": _finite_or_none(float(columns["min_clearance_m"][i])),
        "collision": bool(columns["collision"][i]),
        "constraint_violation": bool(columns["constraint_violation"][i]),
        "predicted_positions_m": _predicted_positions(None if predicted is None else predicted[i]),
    }


def _row_dicts(columns: dict[str, Any], i: int) -> list[Message]:
    """Row ``i``'s messages as dicts: the path for rows the fast text does not cover."""
    t_ns = ns(float(columns["t_s"][i]))
    pose = ViewPose(*(float(columns[c][i]) for c in (*_POSITION, "yaw_rad")))
    roll, pitch = (float(columns[c][i]) for c in ("roll_rad", "pitch_rad"))
    return [
        (t_ns, t.TOPIC_TF, drone_tf(t_ns, pose)),
        (t_ns, t.TOPIC_TF, body_tf(t_ns, pose, roll, pitch)),
        (t_ns, t.TOPIC_CONTROL_STEP, control_step_message(columns, i, t_ns, pose)),
    ]


@functools.cache
def _tf_template() -> JsonTemplate:
    """:func:`drone_tf` with slots: seconds, nanoseconds, x, y, z, then the quaternion's z
    and w."""
    message = drone_tf(0, ViewPose(0.0, 0.0, 0.0, 0.0))
    message["timestamp"] = fx.timestamp_slots()
    message["translation"] = {"x": slot(2), "y": slot(3), "z": slot(4)}
    message["rotation"] = message["rotation"] | {"z": slot(5), "w": slot(6)}
    return JsonTemplate(message)


@functools.cache
def _body_tf_template() -> JsonTemplate:
    """:func:`body_tf` with slots: seconds, nanoseconds, x, y, z, then the quaternion's x,
    y, z and w."""
    message = body_tf(0, ViewPose(0.0, 0.0, 0.0, 0.0), 0.0, 0.0)
    message["timestamp"] = fx.timestamp_slots()
    message["translation"] = {"x": slot(2), "y": slot(3), "z": slot(4)}
    message["rotation"] = {k: slot(5 + n) for n, k in enumerate(("x", "y", "z", "w"))}
    return JsonTemplate(message)


@functools.cache
def _control_step_template() -> JsonTemplate:
    """:func:`control_step_message` with a slot for every field: seconds, nanoseconds,
    controller, the 17 floats of :data:`FLOAT_COLUMNS` after the time (in that order),
    iterations, status, solve_failed, min_clearance_m, collision, constraint_violation,
    predicted_positions_m. Every field is replaced in the reference's own dict, so its
    order is the reference's (a field left out would keep a dummy value: the tests
    compare the two)."""
    columns: dict[str, Any] = {c: np.zeros(1) for c in (*FLOAT_COLUMNS, "min_clearance_m")}
    columns |= {c: np.array(["-"]) for c in _STRING_COLUMNS}
    columns |= {c: np.zeros(1, dtype=bool) for c in _BOOL_COLUMNS} | {"iterations": [0]}
    message = control_step_message(columns, 0, 0, ViewPose(0.0, 0.0, 0.0, 0.0))
    floats = [slot(3 + k) for k in range(len(FLOAT_COLUMNS) - 1)]
    message.update(
        timestamp=fx.timestamp_slots(),
        controller=slot(2),
        position_m=floats[0:3],
        velocity_m_s=floats[3:6],
        attitude_rad=floats[6:9],
        reference_position_m=floats[9:12],
        reference_yaw_rad=floats[12],
        command=dict(zip(("thrust_m_s2", "roll_rad", "pitch_rad"), floats[13:16], strict=True)),
        solve_time_ms=floats[16],
        iterations=slot(20),
        status=slot(21),
        solve_failed=slot(22),
        min_clearance_m=slot(23),
        collision=slot(24),
        constraint_violation=slot(25),
        predicted_positions_m=slot(26),
    )
    return JsonTemplate(message)


def _json_string(value: Any) -> str:
    # As the writer encodes a str (non-ASCII kept, control characters escaped).
    return json.dumps(str(value), ensure_ascii=False)


def _json_strings(values: list[Any]) -> list[str]:
    """:func:`_json_string` of each value, encoded once per distinct value (a log's
    controller and status columns hold a few values over hundreds of rows)."""
    texts: dict[Any, str] = {}
    return [texts[v] if v in texts else texts.setdefault(v, _json_string(v)) for v in values]


def _json_bool(value: Any) -> str:
    return "true" if bool(value) else "false"


def _fast_columns_fit(log: pd.DataFrame) -> bool:
    """Whether every column has the type the flight log gives it (then the text's
    conversions are the dicts' ones); any other log keeps the dicts."""
    kinds = {name: log[name].dtype.kind for name in log.columns}
    needed = (*FLOAT_COLUMNS, "min_clearance_m", "iterations", *_STRING_COLUMNS, *_BOOL_COLUMNS)
    if any(name not in kinds for name in needed):
        return False
    return (
        all(kinds[c] == "f" for c in (*FLOAT_COLUMNS, "min_clearance_m"))
        and kinds["iterations"] in "iu"
        and all(kinds[c] == "b" for c in _BOOL_COLUMNS)
    )


def _predicted_texts(predicted: Any, n_rows: int) -> tuple[list[str], NDArray[np.bool_]]:
    """Each row's ``predicted_positions_m`` JSON text and whether the row has only finite
    values there: the rows with the same number of points formatted in one pass."""
    texts = ["null"] * n_rows
    finite = np.ones(n_rows, dtype=bool)
    if predicted is None:
        return texts, finite
    by_count: dict[int, tuple[list[int], list[NDArray[np.float64]]]] = {}
    for i in range(n_rows):
        flat = predicted[i]
        if flat is None or len(flat) == 0:
            continue
        points = np.asarray(flat, dtype=np.float64).reshape(-1, 3)
        rows, arrays = by_count.setdefault(len(points), ([], []))
        rows.append(i)
        arrays.append(points)
    for rows, arrays in by_count.values():
        stacked = np.stack(arrays)
        good = np.isfinite(stacked).all(axis=(1, 2))
        indices = np.asarray(rows)
        finite[indices[~good]] = False
        for i, text in zip(indices[good].tolist(), point_list_texts(stacked[good]), strict=True):
            texts[i] = text
    return texts, finite


def control_messages(log: pd.DataFrame) -> list[Message]:
    """Each control step's ``/tf`` and ``/control/step`` messages, in row order."""
    columns = {name: log[name].to_numpy() for name in log.columns}
    n_rows = len(log)
    if not _fast_columns_fit(log):
        return [m for i in range(n_rows) for m in _row_dicts(columns, i)]
    floats = np.column_stack([columns[c].astype(np.float64) for c in FLOAT_COLUMNS])
    predicted_texts, predicted_finite = _predicted_texts(columns.get(PREDICTED_PATH_COLUMN), n_rows)
    fast_rows = np.isfinite(floats).all(axis=1) & predicted_finite
    times = floats[:, 0].tolist()
    yaws = floats[:, FLOAT_COLUMNS.index("yaw_rad")].tolist()
    clearance = columns["min_clearance_m"].astype(np.float64)
    clearance_finite = np.isfinite(clearance).tolist()
    # The floats' texts in one pass: every column but the time, the clearance, and the
    # quaternion of each yaw (math.sin / math.cos, as the dicts compute them). Rows the
    # fast text does not cover get zeros here; their texts are not used.
    half_turns = [0.5 * yaw if math.isfinite(yaw) else 0.0 for yaw in yaws]
    quaternion = np.array([(math.sin(h), math.cos(h)) for h in half_turns]).reshape(n_rows, 2)
    angles = floats[:, [FLOAT_COLUMNS.index(c) for c in _ATTITUDE]]
    angles[~np.isfinite(angles)] = 0.0
    attitude = np.array(
        [tuple(fx.attitude_quaternion(*row).values()) for row in angles.tolist()]
    ).reshape(n_rows, 4)
    table = np.column_stack([floats[:, 1:], clearance, quaternion, attitude])
    table[~np.isfinite(table)] = 0.0
    width, named = table.shape[1], len(FLOAT_COLUMNS) - 1
    flat = float_texts(table.ravel())
    iterations = columns["iterations"].tolist()
    strings = {c: _json_strings(columns[c].tolist()) for c in _STRING_COLUMNS}
    bools = {c: [_json_bool(v) for v in columns[c].tolist()] for c in _BOOL_COLUMNS}
    tf, body, step = _tf_template(), _body_tf_template(), _control_step_template()
    messages: list[Message] = []
    for i in range(n_rows):
        if not fast_rows[i]:
            messages += _row_dicts(columns, i)
            continue
        t_ns = ns(times[i])
        sec, nsec = fx.timestamp_texts(t_ns)
        row = flat[i * width : (i + 1) * width]
        clearance_text, qz, qw, *tilted = row[named:]
        messages.append((t_ns, t.TOPIC_TF, tf.fill(sec, nsec, row[0], row[1], row[2], qz, qw)))
        messages.append((t_ns, t.TOPIC_TF, body.fill(sec, nsec, *row[:3], *tilted)))
        text = step.fill(
            sec,
            nsec,
            strings["controller"][i],
            *row[:named],
            str(int(iterations[i])),
            strings["status"][i],
            bools["solve_failed"][i],
            clearance_text if clearance_finite[i] else "null",
            bools["collision"][i],
            bools["constraint_violation"][i],
            predicted_texts[i],
        )
        messages.append((t_ns, t.TOPIC_CONTROL_STEP, text))
    return messages
