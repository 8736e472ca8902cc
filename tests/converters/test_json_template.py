"""A filled JSON template is the writer's encoding of the message with those values."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from skyvln_eval.converters import messages as fx
from skyvln_eval.converters.float_text import float_texts
from skyvln_eval.converters.json_template import JsonTemplate, slot
from skyvln_eval.converters.writer import encode_json


def _message(a: object, b: object, name: object) -> dict[str, object]:
    return {"t": {"sec": a, "{braces}": [1, "}{"]}, "v": [b, 0.5], "name": name, "ü": "ä"}


@given(
    a=st.integers(0, 2**62),
    b=st.floats(allow_nan=False, allow_infinity=False),
    name=st.text(),
)
def test_filled_template_equals_the_encoded_message(a: int, b: float, name: str) -> None:
    template = JsonTemplate(_message(slot(0), slot(2), slot(1)))
    texts = (str(a), json.dumps(name, ensure_ascii=False), float_texts(np.array([b]))[0])
    assert template.slots == 3
    assert template.fill(*texts) == encode_json(_message(a, b, name))


def test_every_slot_once() -> None:
    with pytest.raises(ValueError, match="exactly once"):
        JsonTemplate({"a": slot(0), "b": slot(0)})
    with pytest.raises(ValueError, match="exactly once"):
        JsonTemplate({"a": slot(1)})


@given(
    t_ns=st.integers(0, 2**62),
    frame_id=st.text(),
    data=st.binary(max_size=300),
    image_format=st.sampled_from(["jpeg", "png", "wébp"]),
)
def test_compressed_image_json_is_the_encoded_message(
    t_ns: int, frame_id: str, data: bytes, image_format: str
) -> None:
    expected = encode_json(fx.compressed_image(t_ns, frame_id, data, image_format))
    assert fx.compressed_image_json(t_ns, frame_id, data, image_format) == expected
