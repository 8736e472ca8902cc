"""The sensor boundary: agents see only their sensors, never the world, the goal or the route."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from skyvln_eval.agent import AgentConfig, Decision, Stop, build_agent
from skyvln_eval.agent.actions import Move
from skyvln_eval.agent.base import Agent, EpisodeBrief, Observation
from skyvln_eval.avdn.records import AvdnRecord, Episode
from skyvln_eval.harness import run_official_episode
from skyvln_eval.sensing import SensorConfig
from skyvln_eval.worlds.tile import Landmark, WorldTile
from tests.conftest import REPO
from tests.toy_worlds import town_episode, town_world

AGENT_PACKAGE = REPO / "skyvln_eval" / "agent"
#: What agent modules may never import: the world's rasters, the simulator, and what
#: reads a dataset's annotations or logs (the route and the goal).
FORBIDDEN = (
    "skyvln_eval.worlds",
    "skyvln_eval.sim",
    "skyvln_eval.harness",
    "skyvln_eval.avdn.loader",
    "skyvln_eval.avdn.validation",
    "skyvln_eval.converters",
    "skyvln_eval.metrics",
)


def _imports(path: Path) -> Iterator[str]:
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            yield node.module


def test_no_agent_module_imports_the_world_or_the_simulator() -> None:
    offending = [
        f"{path.relative_to(REPO)} imports {name}"
        for path in sorted(AGENT_PACKAGE.rglob("*.py"))
        for name in _imports(path)
        if name.startswith(FORBIDDEN) or name == "skyvln_eval.avdn"  # it exports load_split
    ]
    assert not offending, offending


#: Modules that look behind objects (frames, referents, raw memory, other modules).
INTROSPECTION = ("gc", "inspect", "ctypes", "sys")
#: Dunders that open an object up (its fields, a bound method's owner, a closure's cells).
OPENING_DUNDERS = ("__dict__", "__self__", "__closure__", "__globals__", "__func__")


def _label(path: Path) -> str:
    """How a finding names its file: from the repository, or a test's own file by name."""
    return str(path.relative_to(REPO)) if path.is_relative_to(REPO) else path.name


def _sneaky(tmp_path: Path, source: str) -> Path:
    """An agent module of a test's own, written to show what a check finds."""
    sneaky = tmp_path / "sneaky_agent.py"
    sneaky.write_text(source, encoding="utf-8")
    return sneaky


def _private_reaches(path: Path) -> Iterator[str]:
    """Where agent code reads a private name of something other than itself: the sensor
    handle keeps its simulator behind a private method, which agent code must not call."""
    label = _label(path)
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        dunder = node.attr.startswith("__") if isinstance(node, ast.Attribute) else False
        if isinstance(node, ast.Attribute) and dunder and node.attr in OPENING_DUNDERS:
            yield f"{label}:{node.lineno} {ast.unparse(node)}"
        elif isinstance(node, ast.Attribute) and node.attr.startswith("_") and not dunder:
            owner = node.value
            if not (isinstance(owner, ast.Name) and owner.id in ("self", "cls")):
                yield f"{label}:{node.lineno} {ast.unparse(node)}"
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            on_itself = bool(node.args) and isinstance(node.args[0], ast.Name)
            on_itself = on_itself and node.args[0].id in ("self", "cls")  # type: ignore[attr-defined]
            if (
                node.func.id in ("getattr", "hasattr")
                and not on_itself
                and any(
                    isinstance(a, ast.Constant) and str(a.value).startswith("_") for a in node.args
                )
            ):
                yield f"{label}:{node.lineno} {ast.unparse(node)}"
            if node.func.id in ("vars", "globals", "__import__"):
                yield f"{label}:{node.lineno} {ast.unparse(node)}"


def test_no_agent_module_reads_private_names_or_looks_behind_objects() -> None:
    offending = [
        reach for path in sorted(AGENT_PACKAGE.rglob("*.py")) for reach in _private_reaches(path)
    ]
    offending += [
        f"{path.relative_to(REPO)} imports {name}"
        for path in sorted(AGENT_PACKAGE.rglob("*.py"))
        for name in _imports(path)
        if name.split(".")[0] in INTROSPECTION
    ]
    assert not offending, offending


#: Modules that import by a name made at run time, past the import check above (an
#: audit's agent loaded the dataset loader so, found its record by its start view and
#: flew the route). Only the detector registry may, and only modules of this package.
DYNAMIC_IMPORTS = ("importlib", "runpy", "pkgutil")
REGISTRY = AGENT_PACKAGE / "detectors.py"


def _dynamic_imports(path: Path) -> Iterator[str]:
    label = _label(path)
    for name in _imports(path):
        if name.split(".")[0] in DYNAMIC_IMPORTS:
            yield f"{label} imports {name}"
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Attribute) and node.attr == "import_module":
            yield f"{label}:{node.lineno} {ast.unparse(node)}"


def test_no_agent_module_imports_by_a_name_made_at_run_time() -> None:
    offending = [
        reach
        for path in sorted(AGENT_PACKAGE.rglob("*.py"))
        if path != REGISTRY
        for reach in _dynamic_imports(path)
    ]
    assert not offending, offending
    from skyvln_eval.agent.detectors import _DETECTORS  # the one that may: what it imports

    outside = [t for t in _DETECTORS.values() if not t.startswith("skyvln_eval.agent.")]
    assert not outside, outside


def test_the_dynamic_import_check_finds_what_it_forbids(tmp_path: Path) -> None:
    sneaky = _sneaky(
        tmp_path,
        "import importlib\n"
        "def route(brief):\n"
        "    return importlib.import_module('skyvln_eval.avdn.loader').load_split\n",
    )
    found = list(_dynamic_imports(sneaky))
    assert found == [
        "sneaky_agent.py imports importlib",
        "sneaky_agent.py:3 importlib.import_module",
    ]


def test_the_private_reach_check_finds_what_it_forbids(tmp_path: Path) -> None:
    sneaky = _sneaky(
        tmp_path,
        "def peek(observation):\n"
        "    world = observation.sensors._sensors()\n"
        "    return getattr(world, '_world'), vars(world), world.capture.__self__\n",
    )
    found = list(_private_reaches(sneaky))
    assert len(found) == 4 and "observation.sensors._sensors" in found[0]


def _reachable(root: Any, depth: int = 8) -> Iterator[Any]:
    """Everything reachable from ``root`` through attributes, fields and containers."""
    seen: set[int] = set()
    stack = [(root, 0)]
    while stack:
        item, level = stack.pop()
        if id(item) in seen or level > depth:
            continue
        seen.add(id(item))
        yield item
        children: list[Any] = []
        if isinstance(item, list | tuple | set | frozenset):
            children += list(item)
        if isinstance(item, dict):
            children += list(item.keys()) + list(item.values())
        if hasattr(item, "__dict__") and not isinstance(item, type):
            children += list(vars(item).values())
        for slot in getattr(type(item), "__slots__", ()):
            if hasattr(item, slot):
                children.append(getattr(item, slot))
        for cell in getattr(item, "__closure__", None) or ():
            children.append(cell.cell_contents)
        if isinstance(item, np.ndarray) and item.base is not None:
            children.append(item.base)  # a slice keeps its whole array there
        if isinstance(item, memoryview):
            children.append(item.obj)
        stack += [(child, level + 1) for child in children]


class Inspector(Agent):
    """Keeps what it is given, stops at the second step."""

    def __init__(self) -> None:
        self.given: list[Any] = []

    def reset(self, brief: EpisodeBrief) -> None:
        self.given.append(brief)

    def act(self, observation: Observation) -> Decision:
        self.given.append(observation)
        images = observation.sensors.capture_many([(0.0, 60.0), (0.0, 90.0)])
        self.given += images
        return Decision("look", Stop())


def test_nothing_an_agent_is_given_leads_to_the_world_the_goal_or_the_route() -> None:
    episode = town_episode("Go north. The destination is a small restaurant with a red roof.")
    world = town_world()
    inspector = Inspector()
    run_official_episode(inspector, episode, world)
    route = episode.gt_path_corners[1:]  # the start view is given; the rest is the answer
    descriptions = {landmark.description for landmark in world.landmarks}
    found = list(_reachable(inspector.given))
    forbidden_types = (WorldTile, Episode, AvdnRecord, Landmark)
    assert not [type(x).__name__ for x in found if isinstance(x, forbidden_types)]
    for item in found:
        if isinstance(item, np.ndarray) and item.dtype.kind == "f" and item.size % 8 == 0:
            # No copy of a ground-truth view beyond the start, alone or in a larger array.
            blocks = item.reshape(-1, 4, 2)
            for view in route:
                assert not np.isclose(blocks, view).all(axis=(1, 2)).any(), "a GT view"
        if isinstance(item, str):
            assert item not in descriptions, f"a landmark description reached the agent: {item}"
            # The episode's id and map name are the keys of its annotations (the route).
            assert episode.episode_id not in item and episode.map_name not in item, item
    brief = inspector.given[0]
    assert isinstance(brief, EpisodeBrief) and brief.instruction.startswith("Go north")


def test_captures_hold_only_the_carried_sensors() -> None:
    episode = town_episode("Go north.")
    for sensors, channels in (
        ({"depth": False, "semantic": False}, {"rgb"}),
        ({"depth": True, "semantic": False}, {"rgb", "depth_m"}),
        ({"depth": True, "semantic": True}, {"rgb", "depth_m", "semantic", "instance"}),
    ):
        inspector = Inspector()
        run_official_episode(inspector, episode, town_world(), sensors=SensorConfig(**sensors))
        capture = inspector.given[2]
        present = {
            name
            for name in ("rgb", "depth_m", "semantic", "instance")
            if getattr(capture, name) is not None
        }
        assert present == channels, sensors
        assert bool(capture.instance_categories) == ("instance" in channels)
        assert all(
            isinstance(c, str) and " " not in c for c in capture.instance_categories.values()
        )


def test_the_full_agent_runs_behind_the_boundary() -> None:
    episode = town_episode("Go north. The destination is a small restaurant with a red roof.")
    config = AgentConfig.model_validate(
        {"detector": {"miss_rate": 0.0, "false_positive_rate": 0.0}}
    )
    rollout = run_official_episode(build_agent(config), episode, town_world())
    assert rollout.error is None and rollout.actions


class Painter(Agent):
    """Writes on the view it is given, as a careless agent might."""

    def __init__(self) -> None:
        self.refusals = 0

    def reset(self, brief: EpisodeBrief) -> None:
        assert brief.start_view.base is None  # not a row of the route
        self._try(brief.start_view)

    def act(self, observation: Observation) -> Decision:
        self._try(observation.view_corners)
        return Decision("paint", Stop() if observation.step_index else Move("forward", 40.0))

    def _try(self, view: np.ndarray) -> None:
        try:
            view += 500.0
        except ValueError:
            self.refusals += 1


def test_what_an_agent_does_to_its_views_does_not_change_what_is_recorded() -> None:
    episode = town_episode("Go north.")
    painter = Painter()
    rollout = run_official_episode(painter, episode, town_world())
    clean = run_official_episode(Inspector(), episode, town_world())
    assert painter.refusals == 3  # the brief's start view and two observations
    np.testing.assert_array_equal(rollout.views[0], episode.start_view)
    np.testing.assert_array_equal(rollout.views[0], clean.views[0])
    assert len(rollout.views) == 2 and not np.allclose(rollout.views[1], rollout.views[0])
    np.testing.assert_array_equal(episode.gt_path_corners[0], clean.views[0])
