"""The run log's control-step messages: the fast JSON text is the writer's encoding of the
reference dicts, byte for byte, and rows the text does not cover keep their dicts."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skyvln_eval.control.flight_log import LOG_COLUMNS, PREDICTED_PATH_COLUMN, log_frame
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.writer import encode_json
from skyvln_eval.harness import control_messages as cm

TRICKY = [0.0, -0.0, 1e-7, -1e-5, 1e-4, 1e16, 9999999999999998.0, 1e22, 5e-324, 0.1, 1 / 3, 2.5]


def _row(k: int, value: float, **changes: Any) -> dict[str, Any]:
    row: dict[str, Any] = dict.fromkeys(LOG_COLUMNS, value)
    row |= {
        "controller": "nmpc",
        "scenario": "crossing",
        "t_s": 0.05 * k,
        "iterations": 7 + k,
        "status": "solved",
        "solve_failed": k % 2 == 0,
        "collision": False,
        "constraint_violation": k % 3 == 0,
        PREDICTED_PATH_COLUMN: [value, -value, value / 3.0, 1.0, 2.0, 3.0],
    }
    return row | changes


def _reference(log: pd.DataFrame, rows: list[int] | None = None) -> list[tuple[int, str, bytes]]:
    """What the run log wrote before the fast text: the dicts, encoded by the writer."""
    columns = {name: log[name].to_numpy() for name in log.columns}
    return [
        (t_ns, topic, encode_json(message))
        for i in (range(len(log)) if rows is None else rows)
        for t_ns, topic, message in cm._row_dicts(columns, i)
    ]


def _written(log: pd.DataFrame) -> list[tuple[int, str, bytes]]:
    return [
        (t_ns, topic, message if isinstance(message, bytes) else encode_json(message))
        for t_ns, topic, message in cm.control_messages(log)
    ]


def _assert_fast_and_equal(log: pd.DataFrame) -> None:
    messages = cm.control_messages(log)
    assert all(isinstance(message, bytes) for _, _, message in messages)
    assert _written(log) == _reference(log)


def test_tricky_floats_ints_and_strings_give_the_writers_bytes() -> None:
    rows = [_row(k, v) for k, v in enumerate(TRICKY)]
    rows[0] |= {"min_clearance_m": math.nan, "controller": 'n"mpc\n é ✈', "status": "\x01"}
    rows[1] |= {"min_clearance_m": math.inf, PREDICTED_PATH_COLUMN: None}
    rows[2] |= {"min_clearance_m": -math.inf, PREDICTED_PATH_COLUMN: []}
    rows[3] |= {"iterations": 2**62, "t_s": -1.0}  # a negative time logs at 0
    rows[4] |= {PREDICTED_PATH_COLUMN: np.arange(9.0).reshape(3, 3)}
    _assert_fast_and_equal(log_frame(rows))


def test_a_log_without_predictions_writes_null() -> None:
    log = log_frame([_row(k, v) for k, v in enumerate(TRICKY)]).drop(
        columns=[PREDICTED_PATH_COLUMN]
    )
    _assert_fast_and_equal(log)
    assert all(b'"predicted_positions_m":null}' in m for _, topic, m in _written(log)[2::3])


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("where", ["vx_m_s", "solve_time_ms", "t_s", PREDICTED_PATH_COLUMN])
def test_a_non_finite_row_keeps_its_dicts_and_the_writer_refuses_it(bad: float, where: str) -> None:
    value = [1.0, bad, 3.0] if where == PREDICTED_PATH_COLUMN else bad
    log = log_frame([_row(0, 1.5), _row(1, 2.5, **{where: value}), _row(2, 3.5)])
    if where == "t_s":  # the time itself cannot be made: the same error as before
        with pytest.raises((ValueError, OverflowError)):
            cm.control_messages(log)
        return
    messages = cm.control_messages(log)
    kinds = [isinstance(message, bytes) for _, _, message in messages]
    assert kinds == [True] * 3 + [False] * 3 + [True] * 3
    assert messages[:3] + messages[6:] == _reference(log, [0, 2])
    with pytest.raises(ValueError, match="Out of range float"):
        encode_json(messages[5][2])


def test_a_log_of_other_column_types_keeps_the_dicts() -> None:
    log = log_frame([_row(k, v) for k, v in enumerate(TRICKY)])
    log["iterations"] = log["iterations"].astype(np.float64)  # not the flight log's int
    messages = cm.control_messages(log)
    assert not any(isinstance(message, bytes) for _, _, message in messages)
    assert _written(log) == _reference(log)


def test_messages_come_in_row_order_on_their_topics() -> None:
    log = log_frame([_row(k, v) for k, v in enumerate(TRICKY)])
    messages = cm.control_messages(log)
    topics = [t.TOPIC_TF, t.TOPIC_TF, t.TOPIC_CONTROL_STEP]
    assert [topic for _, topic, _ in messages] == topics * len(TRICKY)
    assert [t_ns for t_ns, _, _ in messages[::3]] == [cm.ns(0.05 * k) for k in range(len(TRICKY))]


def _rotation(axis: int, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    i, j = (axis + 1) % 3, (axis + 2) % 3  # the plane it turns, in right-hand order
    matrix = np.eye(3)
    matrix[i, i], matrix[i, j], matrix[j, i], matrix[j, j] = c, -s, s, c
    return matrix


def test_the_airframe_carries_the_models_roll_and_pitch_and_the_heading_frame_stays_level() -> None:
    # An audit: /tf's map->drone had only yaw while /control/step said 6 deg of roll.
    log = log_frame([_row(0, 0.5, roll_rad=0.106, pitch_rad=-0.2, yaw_rad=2.0)])
    heading, body, _ = (json.loads(m) for _, _, m in _written(log))
    assert heading["child_frame_id"] == t.DRONE_FRAME
    assert heading["rotation"]["x"] == heading["rotation"]["y"] == 0.0
    assert (body["parent_frame_id"], body["child_frame_id"]) == (t.MAP_FRAME, t.BODY_FRAME)
    assert body["translation"] == heading["translation"]
    x, y, z, w = (body["rotation"][k] for k in "xyzw")
    assert math.isclose(x * x + y * y + z * z + w * w, 1.0, rel_tol=1e-12)
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    # The model's R = Ry(pitch) Rx(roll) after the yaw: its thrust axis is R e_z.
    expected = _rotation(1, -0.2) @ _rotation(0, 0.106) @ _rotation(2, 2.0)
    np.testing.assert_allclose(rotation, expected, atol=1e-12)


finite = st.floats(allow_nan=False, allow_infinity=False)


@settings(max_examples=200, deadline=None)
@given(
    values=st.lists(finite, min_size=len(cm.FLOAT_COLUMNS) + 1, max_size=len(cm.FLOAT_COLUMNS) + 1),
    predicted=st.lists(finite, max_size=12).map(lambda v: v[: len(v) - len(v) % 3]),
    clearance=st.floats(),
)
def test_any_finite_row_gives_the_writers_bytes(
    values: list[float], predicted: list[float], clearance: float
) -> None:
    row = _row(0, 0.0, **dict(zip(cm.FLOAT_COLUMNS, values, strict=False)))
    row |= {"t_s": abs(values[0]) % 1e6, "min_clearance_m": clearance}
    row[PREDICTED_PATH_COLUMN] = predicted
    _assert_fast_and_equal(log_frame([row]))


@settings(max_examples=60, deadline=None)
@given(
    centres=st.lists(st.sampled_from(TRICKY) | finite, min_size=6, max_size=6),
    start_s=st.floats(0.0, 1e5),
)
def test_obstacle_messages_are_the_writers_bytes_of_their_dicts(
    centres: list[float], start_s: float
) -> None:
    """The /sim/obstacles texts filled in from a template are the encoded dicts."""
    from skyvln_eval.harness import run_log
    from skyvln_eval.sim.obstacles import ConstantVelocity, ObstacleScenario, SphereObstacle

    obstacles = tuple(
        SphereObstacle(ConstantVelocity(tuple(centres[3 * k : 3 * k + 3]), (0.5, -1e-5, 0.0)))
        for k in range(2)
    )
    scenario = ObstacleScenario("crossing ü", obstacles)
    out = run_log._Messages()
    run_log._obstacle_messages(out, [(start_s, start_s + 2.0, scenario)])
    times = np.arange(start_s, start_s + 2.0 + 1e-9, run_log.OBSTACLE_SAMPLE_S)
    assert len(out.items) == len(times)
    for (t_ns, _, topic, _, text), t_s in zip(out.items, times, strict=True):
        at = [ob.motion.position_m(np.array([t_s]))[0].tolist() for ob in obstacles]
        assert topic == t.TOPIC_OBSTACLES and t_ns == cm.ns(float(t_s))
        assert text == encode_json(run_log.obstacle_message(t_ns, scenario, at))


class _Odd:
    def __str__(self) -> str:
        return "odd ü"


@pytest.mark.parametrize(
    "trace",
    [
        {"subgoals": [{"kind": "turn", "deg": -0.0}], "exchanges": [{"x": 1}], "é": "ü\n"},
        {1: (1, 2.5e-7, None), "f32": np.float32(1.5), "f64": np.float64(1e16), "o": _Odd()},
        {"nested": {"a": [True, {"b": 1e22}]}, "empty": {}, "odd": [_Odd(), b"bytes"]},
    ],
)
def test_agent_step_text_is_the_writers_bytes_of_its_dict(trace: dict[Any, Any]) -> None:
    from skyvln_eval.agent.actions import Stop, action_record
    from skyvln_eval.harness import run_log

    step = run_log.Step(3.5, 2, np.zeros((4, 2)), "thinking ü", Stop(), "fine", trace)
    record = action_record(step.action)
    text = run_log.agent_step_json(3_500_000_000, "ep_1", step, record)
    reference = run_log.agent_step_message(3_500_000_000, "ep_1", step, record)
    assert text == encode_json(reference)
    assert b"exchanges" not in text  # they have a topic of their own


def test_an_agent_step_whose_thought_spells_a_slot_marker_is_written_as_its_dict() -> None:
    from skyvln_eval.agent.actions import Stop, action_record
    from skyvln_eval.converters.json_template import slot
    from skyvln_eval.harness import run_log

    for thought in (slot(0), slot(1), f"{slot(1)} and {slot(0)}"):
        step = run_log.Step(1.0, 0, np.zeros((4, 2)), thought, Stop(), None, {"k": 1})
        record = action_record(step.action)
        message = run_log.agent_step_json(10, "ep", step, record)
        text = message if isinstance(message, bytes) else encode_json(message)
        assert text == encode_json(run_log.agent_step_message(10, "ep", step, record))
        assert json.loads(text)["thought"] == thought


def test_an_agent_step_the_writer_refuses_stays_a_dict() -> None:
    from skyvln_eval.agent.actions import Stop, action_record
    from skyvln_eval.harness import run_log

    for trace in ({"score": math.nan}, {"name": "lone \udc80"}):
        step = run_log.Step(1.0, 0, np.zeros((4, 2)), "", Stop(), None, trace)
        message = run_log.agent_step_json(10, "ep", step, action_record(step.action))
        assert isinstance(message, dict)
        with pytest.raises(ValueError):
            encode_json(message)
