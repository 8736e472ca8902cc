"""TBMA: shortest paths, backtracking and notes on a small hand-built graph."""

from __future__ import annotations

import math

import pytest

from skyvln_eval.agent.memory import TrackBackMemory
from skyvln_eval.agent.perception import Sighting
from skyvln_eval.errors import SkyvlnError
from skyvln_eval.frames import ViewPose


def pose(x: float, y: float, z: float = 50.0) -> ViewPose:
    return ViewPose(x, y, z, math.pi / 2)


def seen(lid: str, label: str, x: float, y: float, at: ViewPose, caption: str = "") -> Sighting:
    east, north = x - at.x_m, y - at.y_m
    return Sighting(
        landmark_id=lid, label=label, caption=caption or f"a {label}", score=0.9, view_index=4,
        view_name="below", view_heading_deg=0.0, box_px=(100, 100, 120, 120),
        image_size_px=(224, 224),
        x_m=x, y_m=y, east_m=east, north_m=north, distance_m=math.hypot(east, north),
        bearing_deg=math.degrees(math.atan2(east, north)) % 360, size_m=20.0,
    )  # fmt: skip


def small_graph() -> TrackBackMemory:
    """Start P0 at (0, 0); flights north to P1 (0, 100) and east to P2 (100, 100).

    A gas station L1 is met at P1, a restaurant L2 at P2.
    """
    memory = TrackBackMemory(meet_radius_m=40.0)
    memory.reset(())
    p0, p1, p2 = pose(0, 0), pose(0, 100), pose(100, 100)
    memory.add_place(0, p0, "head north", None)
    memory.meet(0, p0, [seen("L9", "hotel", 300, 300, p0)])  # too far to be met
    memory.add_place(1, p1, "head north", {"type": "move_forward", "distance_m": 100})
    memory.meet(1, p1, [seen("L1", "gas station", 10, 110, p1)])
    memory.add_place(2, p2, "turn right", {"type": "move_right", "distance_m": 100})
    memory.meet(2, p2, [seen("L2", "restaurant", 100, 120, p2)])
    return memory


def test_nodes_are_places_and_landmarks_met_and_edges_keep_instructions_and_actions() -> None:
    memory = small_graph()
    assert set(memory.graph.nodes) == {"P0", "P1", "P2", "L1", "L2"}
    flight = memory.graph.edges["P1", "P2"]
    assert flight["instruction"] == "turn right"
    assert flight["action"] == {"type": "move_right", "distance_m": 100}
    assert flight["distance_m"] == pytest.approx(100.0)
    assert memory.travelled_m == pytest.approx(200.0)
    assert memory.snapshot()["current"] == "P2"


def test_the_shortest_path_goes_through_the_places_flown() -> None:
    memory = small_graph()
    assert memory.shortest_path("P2", "P0") == ["P2", "P1", "P0"]
    assert memory.shortest_path("L2", "L1") == ["L2", "P2", "P1", "L1"]
    # A later flight straight back to the start is a shortcut the memory then uses.
    memory.add_place(3, pose(50, 50), "go back", None)
    memory.graph.add_edge("P3", "P0", kind="flight", distance_m=70.7)
    assert memory.shortest_path("P3", "P0") == ["P3", "P0"]
    with pytest.raises(SkyvlnError, match="no way"):
        memory.shortest_path("P0", "L7")


def test_the_way_back_leads_to_the_place_where_the_agent_decided() -> None:
    memory = small_graph()
    back = memory.way_back("P1", pose(100, 100), reason="L2 was not there")
    assert back.path == ("P2", "P1")
    assert (back.east_m, back.north_m) == pytest.approx((-100.0, 0.0))
    assert back.to_dict()["distance_m"] == pytest.approx(100.0)


def test_notes_tell_what_the_memory_knows_about_candidates() -> None:
    memory = small_graph()
    memory.reject("L2", "not there when I arrived")
    memory.mark_goal("L1", "the gas station")
    notes = memory.notes(["L1", "L2", "L5"], phrase="a gas station with a white canopy")
    assert set(notes) == {"L1", "L2"}  # L5 was never met
    assert "already used as 'the gas station'" in notes["L1"]
    assert "rejected: not there when I arrived" in notes["L2"]
    assert "confirmed" in memory.notes(["L1"], phrase="the gas station")["L1"]


def test_landmarks_of_earlier_rounds_are_recognised_at_the_start() -> None:
    memory = TrackBackMemory()
    memory.reset(["the church"])
    start = pose(0, 0)
    memory.add_place(0, start, "go north", None)
    memory.meet(0, start, [seen("L4", "church", 5, 5, start, "a church with a red roof")])
    assert "from an earlier round" in memory.notes(["L4"])["L4"]


def test_the_clue_summarises_the_path_for_instructions_without_landmarks() -> None:
    clue = small_graph().clue(pose(100, 100))
    assert "flown 200 m through P0 -> P1 -> P2" in clue
    assert "Last landmark met: L2 restaurant, 20 m to the north" in clue
