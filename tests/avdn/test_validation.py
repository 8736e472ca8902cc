"""Bad input gets a specific error naming the file, record index, episode id and field."""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from skyvln_eval.avdn import check_split, load_split, parse_record
from skyvln_eval.avdn.validation import MAX_EPISODE_ID_CHARS, is_episode_id
from skyvln_eval.errors import AvdnFileError, AvdnValidationError, ValidationIssue
from tests.conftest import make_record


def only_issue(dataset_factory: Callable[..., Path], records: list[Any]) -> ValidationIssue:
    root = dataset_factory({"val_seen": records})
    _, issues = check_split(root, "val_seen")
    assert len(issues) == 1, [str(i) for i in issues]
    issue = issues[0]
    assert issue.file.endswith("annotations/val_seen_data.json")
    return issue


def test_valid_records_have_no_issues(dataset_factory: Callable[..., Path]) -> None:
    root = dataset_factory(
        {"val_seen": [make_record(route_index="0_1"), make_record(route_index="1_1")]}
    )
    records, issues = check_split(root, "val_seen")
    assert issues == []
    assert [r.episode_id for r in records] == ["1913__0_1", "1913__1_1"]


def test_missing_key(dataset_factory: Callable[..., Path]) -> None:
    bad = make_record(route_index="3_1")
    del bad["angle"]
    issue = only_issue(dataset_factory, [make_record(), bad])
    assert (issue.record_index, issue.episode_id, issue.field) == (1, "1913__3_1", "angle")
    assert "missing required key" in issue.message
    assert (
        "record 1" in str(issue) and "episode 1913__3_1" in str(issue) and "'angle'" in str(issue)
    )


def test_optional_keys_may_be_absent(dataset_factory: Callable[..., Path]) -> None:
    record = make_record()
    del record["destination"], record["last_round_idx"]
    root = dataset_factory({"val_seen": [record]})
    records, issues = check_split(root, "val_seen")
    assert issues == [] and records[0].destination is None and records[0].last_round_idx is None


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("map_name", 1913, "expected a string, got integer"),
        ("angle", "north", "expected a number, got string"),
        ("pre_dialogs", "hello", "expected a list of strings"),
        ("lat_ratio", True, "expected a number, got true"),
        ("last_round_idx", 1.5, "expected an integer >= 1"),
        ("route_index", "7", "expected '<trajectory>_<round>'"),
    ],
)
def test_wrong_type(
    dataset_factory: Callable[..., Path], field: str, value: Any, message: str
) -> None:
    issue = only_issue(dataset_factory, [make_record(**{field: value})])
    assert issue.field == field
    assert message in issue.message


def test_corner_with_wrong_type_is_located(dataset_factory: Callable[..., Path]) -> None:
    record = make_record()
    record["gt_path_corners"][1][2][0] = "30.1"
    issue = only_issue(dataset_factory, [record])
    assert issue.field == "gt_path_corners[1][2][0]"
    assert "expected a number, got string" in issue.message


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_nan_or_infinite_coordinate(dataset_factory: Callable[..., Path], value: float) -> None:
    record = make_record()
    record["gt_path_corners"][2][3][1] = value
    issue = only_issue(dataset_factory, [record])
    assert issue.field == "gt_path_corners[2][3][1]"
    assert "NaN or infinite" in issue.message


def _with(record: dict[str, Any], path: tuple[Any, ...], value: Any) -> dict[str, Any]:
    target: Any = record
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    return record


@pytest.mark.parametrize(
    ("path", "field"),
    [
        (("angle",), "angle"),
        (("lat_ratio",), "lat_ratio"),
        (("gps_botm_left", 1), "gps_botm_left[1]"),
        (("gt_path_corners", 1, 2, 0), "gt_path_corners[1][2][0]"),
        (("destination", 3, 1), "destination[3][1]"),
        (("attention_list", 0, 1), "attention_list[0][1]"),
    ],
)
def test_an_integer_too_large_for_a_float_is_a_problem_not_a_crash(
    dataset_factory: Callable[..., Path], path: tuple[Any, ...], field: str
) -> None:
    # 1 followed by 400 zeros is a JSON number, and OverflowError in math.isfinite.
    issue = only_issue(dataset_factory, [_with(make_record(), path, 10**400)])
    assert issue.field == field
    assert "an integer of 401 digits is too large for a 64-bit float" in issue.message


@pytest.mark.parametrize("literal", ["1e-400", "-2.5E-0400", "0." + "0" * 400 + "3"])
@pytest.mark.parametrize(
    ("path", "field"),
    [
        (("angle",), "angle"),
        (("gt_path_corners", 0, 1, 0), "gt_path_corners[0][1][0]"),
        (("note",), "note"),  # a field the format does not define is kept: not as 0.0
    ],
)
def test_a_number_too_small_for_a_float_is_a_problem_not_a_silent_zero(
    dataset_factory: Callable[..., Path], literal: str, path: tuple[Any, ...], field: str
) -> None:
    # 1e400 was refused (infinite) while 1e-400 silently read as 0.0.
    good = make_record(route_index="1_1")
    good["angle"] = 0.0  # a zero, and a tiny number a float holds, are numbers
    good["scale"] = 1e-310  # below the normal range, still not zero
    root = dataset_factory({"val_seen": [_with(make_record(), path, "TINY"), good]})
    annotations = root / "annotations" / "val_seen_data.json"
    annotations.write_text(annotations.read_text().replace('"TINY"', literal))
    _, issues = check_split(root, "val_seen")
    [issue] = issues
    assert (issue.record_index, issue.field) == (0, field)
    assert issue.message == f"{literal} is too small for a 64-bit float (it would read as 0)"


def test_an_integer_beyond_int64_that_a_float_holds_is_a_number(
    dataset_factory: Callable[..., Path],
) -> None:
    record = make_record(n_views=1)  # test_unseen: the start view alone is allowed there
    record["gt_path_corners"][0][0][0] = 10**20  # numpy keeps it as an object
    _, issues = check_split(dataset_factory({"test_unseen": [record]}), "test_unseen")
    # Its geometry is judged (it was 'expected views of shape 4x2 ..., got 1x4x2').
    assert [(i.field, i.message.split(" (")[0]) for i in issues] == [
        ("gt_path_corners[0]", "view is not square"),
        ("gt_path_corners[0]", "view lies outside the map bounds gps_botm_left..gps_top_right"),
    ]


def test_an_integer_longer_than_python_reads_is_a_file_error(
    dataset_factory: Callable[..., Path],
) -> None:
    root = dataset_factory({"val_seen": [make_record()]})
    path = root / "annotations" / "val_seen_data.json"
    path.write_text(path.read_text().replace('"angle": 30.0', '"angle": 1' + "0" * 5000))
    with pytest.raises(AvdnFileError, match=r"cannot be read: Exceeds the limit \(4300 digits\)"):
        check_split(root, "val_seen")


@pytest.mark.parametrize(
    ("path", "field"),
    [
        (("instructions",), "instructions"),
        (("pre_dialogs",), "pre_dialogs[1]"),
        (("note",), "note['text'][0]"),
        (("\udc00",), "'\\udc00'"),
    ],
)
def test_a_lone_surrogate_is_a_problem_of_its_field(
    dataset_factory: Callable[..., Path], path: tuple[str, ...], field: str
) -> None:
    # "\ud83d" is half an emoji: JSON decodes it, UTF-8 cannot encode it, and the converter
    # crashed on it (the whole batch, nothing written).
    values = {
        "instructions": "[INS] \ud83d fly north",
        "pre_dialogs": ["[INS] go", "[QUE] \ud83d?"],
        "note": {"text": ["\ud83d"]},
        "\udc00": 1,
    }
    record = make_record(route_index="2_2", **{path[0]: values[path[0]]})
    issue = only_issue(dataset_factory, [record])
    assert (issue.field, issue.episode_id) == (field, "1913__2_2")
    assert "not valid Unicode text" in issue.message
    str(issue).encode("utf-8")  # the issue itself can be printed


def test_nan_in_an_unknown_key_is_a_problem(
    tmp_path: Path, dataset_factory: Callable[..., Path]
) -> None:
    # It was kept and written as a bare NaN into every log's metadata: not JSON.
    root = dataset_factory({"val_seen": [make_record(extra=1.5)]})
    path = root / "annotations" / "val_seen_data.json"
    path.write_text(path.read_text().replace('"extra": 1.5', '"extra": NaN'))
    _, issues = check_split(root, "val_seen")
    assert [(i.field, i.message) for i in issues] == [
        ("extra", "NaN or infinite value (nan): strict JSON has none")
    ]


def test_a_key_repeated_inside_an_unknown_field_is_a_problem(
    dataset_factory: Callable[..., Path],
) -> None:
    # An audit: '"notes": {"who": "alice", "who": "bob"}' passed, and the log kept only bob.
    root = dataset_factory({"val_seen": [make_record(notes={"who": "alice"})]})
    path = root / "annotations" / "val_seen_data.json"
    path.write_text(path.read_text().replace('"who": "alice"', '"who": "alice", "who": "bob"'))
    _, issues = check_split(root, "val_seen")
    assert [(i.field, i.message) for i in issues] == [
        ("notes['who']", "key given more than once (JSON keeps the last value)")
    ]


def test_nan_in_json_text_is_caught(tmp_path: Path, dataset_factory: Callable[..., Path]) -> None:
    root = dataset_factory({"val_seen": [make_record()]})
    path = root / "annotations" / "val_seen_data.json"
    text = path.read_text()
    path.write_text(text.replace('"angle": 30.0', '"angle": NaN'))
    _, issues = check_split(root, "val_seen")
    assert [(i.field, "NaN" in i.message) for i in issues] == [("angle", True)]


def test_empty_gt_path(dataset_factory: Callable[..., Path]) -> None:
    issue = only_issue(dataset_factory, [make_record(gt_path_corners=[])])
    assert issue.field == "gt_path_corners"
    assert "empty gt_path_corners" in issue.message


def test_wrong_view_shape(dataset_factory: Callable[..., Path]) -> None:
    record = make_record()
    record["gt_path_corners"][1] = record["gt_path_corners"][1][:3]
    issue = only_issue(dataset_factory, [record])
    assert issue.field == "gt_path_corners[1]"  # which view (it said "got ragged")
    assert issue.message == "expected a view of 4 [lat, lng] corners, got a list of 3"
    record = make_record()
    record["gt_path_corners"][2][3] = [24.0]
    issue = only_issue(dataset_factory, [record])
    assert issue.field == "gt_path_corners[2][3]"
    assert issue.message == "expected a corner [lat, lng], got a list of 1"
    record = make_record(route_index="1_1")
    record["destination"] = record["destination"][:2]
    issue = only_issue(dataset_factory, [record])
    assert (issue.field, issue.message) == (
        "destination",
        "expected a view of 4 [lat, lng] corners, got a list of 2",
    )


def test_degenerate_view(dataset_factory: Callable[..., Path]) -> None:
    record = make_record()
    point = record["gt_path_corners"][1][0]
    record["gt_path_corners"][1] = [point, point, point, point]
    issue = only_issue(dataset_factory, [record])
    assert issue.field == "gt_path_corners[1]"
    assert "degenerate view" in issue.message


def test_non_square_view(dataset_factory: Callable[..., Path]) -> None:
    record = make_record()
    view = record["gt_path_corners"][0]
    view[1] = [view[1][0] + 0.0002, view[1][1]]  # stretch the front-right corner by ~22 m
    issue = only_issue(dataset_factory, [record])
    assert issue.field == "gt_path_corners[0]"
    assert "not square" in issue.message


def test_mirrored_corner_order(dataset_factory: Callable[..., Path]) -> None:
    record = make_record()
    fl, fr, br, bl = record["gt_path_corners"][0]
    record["gt_path_corners"][0] = [fr, fl, bl, br]
    issue = only_issue(dataset_factory, [record])
    assert "front-left, front-right" in issue.message


@pytest.mark.parametrize("shift", [1, 2, 3])
def test_corners_listed_from_another_corner_are_refused(
    dataset_factory: Callable[..., Path], shift: int
) -> None:
    # An audit shifted every view's corners round by one (FR, BR, BL, FL): the order still
    # runs clockwise, so the record loaded and the official step flew 90 degrees off.
    record = make_record()
    record["gt_path_corners"] = [view[shift:] + view[:shift] for view in record["gt_path_corners"]]
    issue = only_issue(dataset_factory, [record])
    assert issue.field == "gt_path_corners[0]"
    assert "do not start at the front-left corner" in issue.message


@pytest.mark.parametrize("route", ["6_02", "06_1", "\u0666_1", "\uff16_1"])
def test_a_route_index_in_another_spelling_of_its_numbers_is_refused(
    dataset_factory: Callable[..., Path], route: str
) -> None:
    # "6_2" and "6_02" are one round: both would have joined trajectory 6, round 2 twice.
    issue = only_issue(dataset_factory, [make_record(route_index=route)])
    assert issue.field == "route_index" and "without leading zeros" in issue.message


def test_an_episode_id_too_long_for_a_file_name_is_refused(
    dataset_factory: Callable[..., Path],
) -> None:
    # Logs are named after the id: 300 digits made convert fail with "File name too long".
    issue = only_issue(dataset_factory, [make_record(route_index="1" * 300 + "_1")])
    assert issue.field == "route_index" and "files are named after it" in issue.message
    longest = "1" * (MAX_EPISODE_ID_CHARS - len("1913__") - 2) + "_1"
    assert is_episode_id(f"1913__{longest}") and not is_episode_id(f"1913__1{longest}")
    _, issues = check_split(
        dataset_factory({"val_seen": [make_record(route_index=longest)]}), "val_seen"
    )
    assert issues == []


def test_an_attention_centre_off_the_map_is_refused(dataset_factory: Callable[..., Path]) -> None:
    # Swapped [lng, lat] that still reads as a valid [lat, lng]: drawn far off the map.
    record = make_record()
    lat, lng = record["gt_path_corners"][0][0]
    record["attention_list"] = [[[lat, lng], 20.0], [[lng, lat], 20.0]]
    issue = only_issue(dataset_factory, [record])
    assert issue.field == "attention_list[1][0]" and "outside the map bounds" in issue.message


def test_a_key_given_twice_is_refused_not_silently_the_last(
    dataset_factory: Callable[..., Path],
) -> None:
    root = dataset_factory({"val_seen": [make_record()]})
    path = root / "annotations" / "val_seen_data.json"
    text = path.read_text()
    assert text.count('"angle": 30.0') == 1
    path.write_text(text.replace('"angle": 30.0', '"angle": 30.0, "angle": 120.0'))
    _, issues = check_split(root, "val_seen")
    assert [(i.field, "more than once" in i.message) for i in issues] == [("angle", True)]
    # Every problem of the record is reported, not the repeated key alone (an audit).
    path.write_text(text.replace('"angle": 30.0', '"angle": 30.0, "angle": 30.0, "lat_ratio": -1'))
    _, issues = check_split(root, "val_seen")
    said = [(i.field, "more than once" in i.message) for i in issues]
    assert said == [("angle", True), ("lat_ratio", True), ("lat_ratio", False)]


@pytest.mark.parametrize(
    ("key", "path", "field"),
    [
        ("gt_path_corners", (1, 2, 0), "gt_path_corners[1][2][0]"),
        ("destination", (0, 1), "destination[0][1]"),
    ],
)
def test_a_boolean_among_coordinates_is_a_wrong_type(
    dataset_factory: Callable[..., Path], key: str, path: tuple[int, ...], field: str
) -> None:
    # numpy read `true` as 1.0: a destination took it as a coordinate, a view was 'not
    # square'.
    record = make_record()
    target = record[key]
    for k in path[:-1]:
        target = target[k]
    target[path[-1]] = True
    issue = only_issue(dataset_factory, [record])
    assert (issue.field, issue.message) == (field, "expected a number, got true")


def test_coordinates_of_exactly_0_or_1_are_numbers(dataset_factory: Callable[..., Path]) -> None:
    # The record of make_record moved to lat, lng about 1: an integer 1 is a coordinate.
    def moved(value: Any) -> Any:
        if isinstance(value, list) and len(value) == 2 and all(type(v) is float for v in value):
            return [value[0] - 29.005, value[1] - 39.005]
        return [moved(v) for v in value] if isinstance(value, list) else value

    record = {k: moved(v) if k != "attention_list" else v for k, v in make_record().items()}
    record["attention_list"] = [[[1, 1], 20]]
    record["destination"] = [[1, 1], [1, 1.0001], [0.9999, 1.0001], [0.9999, 1]]
    records, issues = check_split(dataset_factory({"val_seen": [record]}), "val_seen")
    assert issues == [] and records[0].destination is not None
    assert records[0].destination[0].tolist() == [1.0, 1.0]


def test_a_destination_is_checked_as_the_views_are(dataset_factory: Callable[..., Path]) -> None:
    # Swapped to [lng, lat], it passed: not checked at all beyond its shape.
    record = make_record()
    record["destination"] = [[lng, lat] for lat, lng in record["destination"]]
    issue = only_issue(dataset_factory, [record])  # [40.005, 30.005]: on the globe, off the map
    assert issue.field == "destination"
    assert issue.message.startswith("destination centre [40.005")
    assert "lies outside the map bounds gps_botm_left..gps_top_right" in issue.message
    # A landmark's footprint may reach past the map's edge: its centre is on the map.
    record["destination"] = [[lat - 0.0052, lng] for lat, lng in make_record()["destination"]]
    assert check_split(dataset_factory({"val_seen": [record]}), "val_seen")[1] == []
    record["destination"] = [[lat + 100.0, lng] for lat, lng in make_record()["destination"]]
    issue = only_issue(dataset_factory, [record])
    assert issue.field == "destination[0]"
    assert issue.message.startswith("not a valid [lat, lng]: [130.0")
    # Optional means absent: a null is refused with the fix (null is no AVDN value).
    record["destination"] = None
    issue = only_issue(dataset_factory, [record])
    assert issue.field == "destination" and "got null (leave the key out)" in issue.message


def test_view_outside_the_map(dataset_factory: Callable[..., Path]) -> None:
    record = make_record()
    record["gt_path_corners"] = [
        [[lat + 0.0049, lng] for lat, lng in view] for view in record["gt_path_corners"]
    ]
    root = dataset_factory({"val_seen": [record]})
    _, issues = check_split(root, "val_seen")
    assert issues and all("outside the map bounds" in i.message for i in issues)
    assert issues[-1].field == "gt_path_corners[2]"


def test_duplicate_episode_id(dataset_factory: Callable[..., Path]) -> None:
    issue = only_issue(
        dataset_factory, [make_record(), make_record(), make_record(route_index="1_1")]
    )
    assert (issue.record_index, issue.episode_id, issue.field) == (1, "1913__0_1", "route_index")
    assert "duplicate episode id (first seen in record 0)" in issue.message


def test_a_duplicate_of_an_invalid_record_is_reported_too(
    dataset_factory: Callable[..., Path],
) -> None:
    # An audit: only the first copy's problem was reported, the second was converted under
    # the id the list of what was left out named, and the duplicate never mentioned.
    root = dataset_factory({"val_seen": [make_record(angle="x"), make_record()]})
    _, issues = check_split(root, "val_seen")
    assert [(i.record_index, i.field) for i in issues] == [(0, "angle"), (1, "route_index")]
    assert "duplicate episode id (first seen in record 0)" in issues[1].message


def test_inconsistent_georeference_on_one_map(dataset_factory: Callable[..., Path]) -> None:
    issue = only_issue(
        dataset_factory, [make_record(), make_record(route_index="1_1", lat_ratio=2e-5)]
    )
    assert issue.record_index == 1 and "geo-reference differs" in issue.message
    # The field that differs is named, and the record it differs from.
    assert issue.field == "lat_ratio" and "from record 0's" in issue.message


def test_missing_map_image(dataset_factory: Callable[..., Path]) -> None:
    root = dataset_factory(
        {"val_seen": [make_record(), make_record(map_name="77")]}, maps=("1913",)
    )
    _, issues = check_split(root, "val_seen")
    assert len(issues) == 1
    assert (issues[0].record_index, issues[0].episode_id, issues[0].field) == (
        1,
        "77__0_1",
        "map_name",
    )
    assert "77.tif not found" in issues[0].message
    records, issues = check_split(root, "val_seen", check_map_images=False)
    assert len(records) == 2 and issues == []


def test_record_that_is_not_an_object(dataset_factory: Callable[..., Path]) -> None:
    issue = only_issue(dataset_factory, [make_record(), ["not", "a", "record"]])
    assert issue.record_index == 1 and "expected a JSON object, got list" in issue.message


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ('{"a": 1}', "expected a JSON list of records, got a JSON object"),
        ("[1, 2", "not valid JSON"),
    ],
)
def test_file_that_is_not_a_json_list(
    dataset_factory: Callable[..., Path], content: str, message: str
) -> None:
    root = dataset_factory({"val_seen": []})
    (root / "annotations" / "val_seen_data.json").write_text(content)
    with pytest.raises(AvdnFileError, match=message) as info:
        load_split(root, "val_seen")
    assert "val_seen_data.json" in str(info.value)


def test_a_file_that_is_not_utf8_names_the_byte_record_and_field(
    dataset_factory: Callable[..., Path],
) -> None:
    # AVDN files are one line: "not UTF-8 text (invalid start byte)" left a user searching.
    root = dataset_factory({"val_seen": []})
    text = json.dumps([make_record(), make_record(route_index="1_1", instructions="[INS] go @")])
    raw = text.encode().replace(b"go @", b"go \xff")
    (root / "annotations" / "val_seen_data.json").write_bytes(raw)
    offset = raw.index(b"\xff")
    with pytest.raises(AvdnFileError) as info:
        load_split(root, "val_seen")
    assert str(info.value).endswith(
        f"not UTF-8 text (invalid start byte): byte 0xff on line 1, byte offset {offset} "
        "in record 1, field 'instructions'"
    )


def test_missing_annotation_file(tmp_path: Path) -> None:
    with pytest.raises(AvdnFileError, match="annotation file not found"):
        load_split(tmp_path, "val_unseen")


def test_load_raises_with_every_problem_or_skips_and_reports(
    dataset_factory: Callable[..., Path],
) -> None:
    bad_angle = make_record(route_index="1_1", angle=None)
    bad_corner = make_record(route_index="2_1")
    bad_corner["gt_path_corners"][0][0][0] = math.nan
    root = dataset_factory(
        {"val_unseen": [make_record(), bad_angle, bad_corner, make_record(route_index="3_1")]}
    )
    with pytest.raises(AvdnValidationError) as info:
        load_split(root, "val_unseen")
    assert len(info.value.issues) == 2
    assert "record 1" in str(info.value) and "record 2" in str(info.value)
    loaded = load_split(root, "val_unseen", skip_invalid=True)
    assert [r.route_index for r in loaded.records] == ["0_1", "3_1"]
    assert loaded.skipped_record_indices == [1, 2]
    assert {i.field for i in loaded.skipped} == {"angle", "gt_path_corners[0][0][0]"}


def test_every_problem_of_a_record_is_reported(dataset_factory: Callable[..., Path]) -> None:
    record = make_record(angle="x", lng_ratio=-1.0)
    del record["instructions"]
    root = dataset_factory({"val_seen": [record]})
    _, issues = check_split(root, "val_seen")
    assert [i.field for i in issues] == ["instructions"]  # missing keys stop the record early
    record["instructions"] = "[INS] go"
    root = dataset_factory({"val_seen": [record]})
    _, issues = check_split(root, "val_seen")
    assert sorted(i.field for i in issues) == ["angle", "lng_ratio"]


def test_parse_record_round_trips_the_source() -> None:
    raw = make_record(extra_key={"kept": True})
    record = parse_record(copy.deepcopy(raw))
    assert record.to_json_dict() == raw
    assert record.extra == {"extra_key": {"kept": True}}
    rebuilt = json.loads(json.dumps(record.to_json_dict()))
    assert parse_record(rebuilt) == record
    with pytest.raises(AvdnValidationError, match="angle"):
        parse_record(make_record(angle=math.inf))


def test_the_error_counts_records_not_problems() -> None:
    from skyvln_eval.errors import AvdnValidationError, ValidationIssue

    issues = [
        ValidationIssue("a.json", "bad angle", record_index=1, field="angle"),
        ValidationIssue("a.json", "bad lat", record_index=1, field="gps_botm_left"),
        ValidationIssue("a.json", "trajectory 7 misses round 3"),
    ]
    message = str(AvdnValidationError(issues))
    assert message.startswith("1 invalid record(s), 1 other problem(s) (")


def test_views_given_as_lng_lat_are_one_issue_that_says_so(
    dataset_factory: Callable[..., Path],
) -> None:
    # Each view was refused twice (mirrored corners, off the map) with no word of the swap.
    record = make_record(route_index="0_1")
    record["gt_path_corners"] = [[c[::-1] for c in view] for view in record["gt_path_corners"]]
    issue = only_issue(dataset_factory, [record])
    assert issue.field == "gt_path_corners"
    assert "would lie on it read as [lng, lat]: corners are [lat, lng] (swapped?)" in issue.message


def test_a_last_round_before_a_round_the_file_holds_is_refused(
    dataset_factory: Callable[..., Path],
) -> None:
    # Round 1 says the trajectory ended there while round 3 is in the file: ANDH-Full took
    # round 3's declaration and nobody heard of round 1's.
    rounds = [make_record(route_index=f"0_{k}", last_round_idx=3) for k in (1, 2, 3)]
    rounds[0]["last_round_idx"] = 1
    issue = only_issue(dataset_factory, rounds)
    assert (issue.record_index, issue.field) == (0, "last_round_idx")
    assert issue.message == "1, but record 2 holds round 3 of this trajectory"


@pytest.mark.parametrize(
    ("changes", "field", "message"),
    [
        (  # 0 px high: the resize to a 0 px wide map was an OpenCV traceback
            {"lat_ratio": 1e300},
            "lat_ratio",
            "1e+300 degrees per pixel makes the map's image height (latitude span / "
            "lat_ratio) 1e-302 px, not 1 to 20000: ratios are degrees per image pixel",
        ),
        (  # 10^10 px high: a resize of gigabytes
            {"lat_ratio": 1e-12},
            "lat_ratio",
            "1e-12 degrees per pixel makes the map's image height (latitude span / "
            "lat_ratio) 1e+10 px, not 1 to 20000: ratios are degrees per image pixel",
        ),
        (
            {"lng_ratio": 1e300},
            "lng_ratio",
            "1e+300 degrees per pixel makes the map's image width (longitude span / "
            "lng_ratio) 1e-302 px, not 1 to 20000: ratios are degrees per image pixel",
        ),
        (  # each ratio fits its own span, but the resize makes 1,000 x 100,000 px
            {"lng_ratio": 1e-3, "gps_top_right": [30.01, 41.0]},
            "lat_ratio",
            "1e-05 degrees per pixel makes the map's resized map width (longitude span / "
            "lat_ratio) 1e+05 px, not 1 to 20000: ratios are degrees per image pixel",
        ),
    ],
)
def test_ratios_must_make_a_map_of_a_usable_size(
    dataset_factory: Callable[..., Path], changes: dict[str, Any], field: str, message: str
) -> None:
    # Only '> 0' was checked: validate said ok, then crashed on the map's resize.
    root = dataset_factory({"val_seen": [make_record(), make_record(route_index="1_1", **changes)]})
    records, issues = check_split(root, "val_seen")
    assert [r.route_index for r in records] == ["0_1"]
    assert [(i.record_index, i.episode_id, i.field, i.message) for i in issues] == [
        (1, "1913__1_1", field, message)
    ]


def test_a_record_with_its_start_view_alone_is_refused_outside_test_unseen(
    dataset_factory: Callable[..., Path],
) -> None:
    # AVDN.md: "In test_unseen, N = 1 (start only)": its ground truth is withheld. A
    # val_seen record with no end view passed validate, and was scored against its start.
    start_only = [make_record(), make_record(route_index="1_1", n_views=1)]
    root = dataset_factory({"val_seen": start_only, "test_unseen": start_only})
    records, issues = check_split(root, "val_seen")
    assert [r.route_index for r in records] == ["0_1"]
    assert [(i.record_index, i.episode_id, i.field, i.message) for i in issues] == [
        (
            1,
            "1913__1_1",
            "gt_path_corners",
            "only the start view: a val_seen record's ground truth needs its end view too "
            "(the start view alone is the withheld ground truth of test_unseen)",
        )
    ]
    records, issues = check_split(root, "test_unseen")
    assert len(records) == 2 and issues == []
