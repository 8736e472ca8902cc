"""TBMA, the TrackBack memory array: a graph of where the drone has been and what it met.

Nodes are the landmarks met (``L3``: id, label, caption, position) and the places the
drone decided at (``P0`` start, ``P1``, ...: position, step); edges between consecutive
places hold the instruction being followed and the action taken, edges from a place to a
landmark say it was met there; every edge is weighted by its length in metres. The
shortest path between two nodes is therefore a flyable way back.

The memory answers three kinds of question:

* *notes* on landmark ids (HSD asks about ambiguous candidates): met when, already
  used for which sub-goal, recognised as a landmark of an earlier dialog round, rejected;
* *way back* to a node after the agent found it went wrong (path and displacement);
* a *clue* for instructions without a landmark to hold on to: path so far, last
  landmark met, distance flown.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import networkx as nx

from skyvln_eval.agent.perception import Sighting
from skyvln_eval.errors import SkyvlnError
from skyvln_eval.frames import ViewPose, enu_yaw_to_compass_deg
from skyvln_eval.vocabulary import compass_word, text_similarity


@dataclass(frozen=True)
class WayBack:
    """A route back to ``target``: node ids from here, and the target's displacement (m)."""

    target: str
    path: tuple[str, ...]
    east_m: float
    north_m: float
    reason: str

    def to_dict(self) -> dict[str, Any]:
        return {
            "target": self.target,
            "path": list(self.path),
            "east_m": round(self.east_m, 1),
            "north_m": round(self.north_m, 1),
            "distance_m": round(math.hypot(self.east_m, self.north_m), 1),
            "reason": self.reason,
        }


class TrackBackMemory:
    """The memory graph of one episode (see the module docstring)."""

    def __init__(self, meet_radius_m: float = 40.0, context_similarity: float = 0.6) -> None:
        self.meet_radius_m = meet_radius_m
        self.context_similarity = context_similarity
        self.reset(())

    def reset(self, context_phrases: Sequence[str]) -> None:
        """Forget everything; ``context_phrases`` are landmarks of earlier dialog rounds."""
        self.graph = nx.Graph()
        self.current: str | None = None
        self.context_phrases = tuple(context_phrases)
        self.travelled_m = 0.0

    def _position(self, node: str) -> tuple[float, float]:
        data = self.graph.nodes[node]
        return float(data["x_m"]), float(data["y_m"])

    def add_place(
        self, step: int, pose: ViewPose, instruction: str, action: dict[str, Any] | None
    ) -> str:
        """Record that the drone is at ``pose`` at ``step``, having taken ``action``."""
        node = f"P{step}"
        self.graph.add_node(node, kind="place", step=step, x_m=pose.x_m, y_m=pose.y_m)
        if self.current is not None:
            x0, y0 = self._position(self.current)
            length = math.hypot(pose.x_m - x0, pose.y_m - y0)
            self.travelled_m += length
            self.graph.add_edge(
                self.current,
                node,
                kind="flight",
                instruction=instruction,
                action=action,
                distance_m=length,
            )
        self.current = node
        return node

    def meet(self, step: int, pose: ViewPose, sightings: Sequence[Sighting]) -> list[str]:
        """Landmarks within the meeting radius of the current place become nodes; returns ids."""
        if self.current is None:
            raise SkyvlnError("TrackBackMemory.meet before add_place")
        radius = max(self.meet_radius_m, pose.edge_m / 2.0)
        met = []
        for s in sightings:
            if s.distance_m > radius:
                continue
            if s.landmark_id not in self.graph:
                context = next(
                    (
                        p
                        for p in self.context_phrases
                        if step == 0
                        and text_similarity(p, s.label, s.caption) >= self.context_similarity
                    ),
                    None,
                )
                self.graph.add_node(
                    s.landmark_id, kind="landmark", label=s.label, caption=s.caption, step=step,
                    x_m=s.x_m, y_m=s.y_m, context=context, goal=None, rejected=None,
                )  # fmt: skip
            else:  # the latest estimate of where it is
                self.graph.nodes[s.landmark_id].update(x_m=s.x_m, y_m=s.y_m)
            self.graph.add_edge(self.current, s.landmark_id, kind="met", distance_m=s.distance_m)
            met.append(s.landmark_id)
        return met

    def mark_goal(self, landmark_id: str, phrase: str) -> None:
        """A landmark was reached as the landmark of sub-goal ``phrase``."""
        if landmark_id in self.graph:
            self.graph.nodes[landmark_id]["goal"] = phrase

    def reject(self, landmark_id: str, reason: str) -> None:
        """The agent found that ``landmark_id`` is not what it took it for."""
        if landmark_id not in self.graph:
            self.graph.add_node(
                landmark_id,
                kind="landmark",
                label="?",
                caption="",
                step=-1,
                x_m=math.nan,
                y_m=math.nan,
                context=None,
                goal=None,
            )
        self.graph.nodes[landmark_id]["rejected"] = reason

    def notes(self, landmark_ids: Sequence[str], phrase: str | None = None) -> dict[str, str]:
        """What the memory knows about each id it has met (ids it never met are left out).

        With ``phrase`` (HSD asking about candidates for it), a landmark already reached as
        that same phrase is *confirmed*, one reached as another sub-goal's is *used*.
        """
        out = {}
        for lid in landmark_ids:
            if lid not in self.graph:
                continue
            data = self.graph.nodes[lid]
            parts = [f"met at step {data['step']}"] if data["step"] >= 0 else []
            if data.get("context"):
                parts.append(
                    f"recognised at the start as {data['context']!r} from an earlier round, "
                    "so already reached"
                )
            if data.get("goal") and data["goal"] == phrase:
                parts.append("confirmed earlier as this landmark")
            elif data.get("goal"):
                parts.append(f"already used as {data['goal']!r}")
            if data.get("rejected"):
                parts.append(f"rejected: {data['rejected']}")
            out[lid] = "; ".join(parts)
        return out

    def shortest_path(self, source: str, target: str) -> list[str]:
        """Node ids of the shortest way (by metres) between two nodes."""
        try:
            return list(nx.shortest_path(self.graph, source, target, weight="distance_m"))
        except (nx.NetworkXNoPath, nx.NodeNotFound) as error:
            raise SkyvlnError(f"no way from {source} to {target} in the memory: {error}") from None

    def way_back(self, target: str, pose: ViewPose, reason: str) -> WayBack:
        """The way from the current place back to ``target`` and where that is from ``pose``."""
        if self.current is None:
            raise SkyvlnError("the memory is empty: no way back")
        path = self.shortest_path(self.current, target)
        x, y = self._position(target)
        return WayBack(target, tuple(path), x - pose.x_m, y - pose.y_m, reason)

    def clue(self, pose: ViewPose, with_distance: bool = True) -> str:
        """A summary for instructions without a landmark to hold on to (``with_distance``:
        the metres flown too, which the motion prompt's odometry line already says)."""
        places = sorted(
            (n for n, d in self.graph.nodes(data=True) if d["kind"] == "place"),
            key=lambda n: self.graph.nodes[n]["step"],
        )
        landmarks = [
            n for n, d in self.graph.nodes(data=True) if d["kind"] == "landmark" and d["step"] >= 0
        ]
        path = " -> ".join(places) or "nowhere yet"
        text = (
            f"You have flown {self.travelled_m:.0f} m through {path}."
            if with_distance
            else f"Your path so far: {path}."
        )
        if landmarks:
            last = max(landmarks, key=lambda n: self.graph.nodes[n]["step"])
            x, y = self._position(last)
            east, north = x - pose.x_m, y - pose.y_m
            bearing = float(enu_yaw_to_compass_deg(math.atan2(north, east)))
            text += (
                f" Last landmark met: {last} {self.graph.nodes[last]['label']}, "
                f"{math.hypot(east, north):.0f} m "
                f"to the {compass_word(bearing)}."
            )
        return text

    def offsets(self, pose: ViewPose) -> dict[str, tuple[float, float]]:
        """Displacement (east, north) from ``pose`` of every node with a known position."""
        out = {}
        for node, data in self.graph.nodes(data=True):
            if math.isfinite(data["x_m"]):
                out[node] = (data["x_m"] - pose.x_m, data["y_m"] - pose.y_m)
        return out

    def prompt_text(self, pose: ViewPose, way_back: WayBack | None) -> str:
        """The memory's part of the navigation prompt: clue, notes, way back (the metres
        flown are the odometry's line of the same prompt)."""
        text = self.clue(pose, with_distance=False)
        notes = self.notes([n for n in self.graph.nodes if n.startswith("L")])
        if notes:
            text += "\n" + "\n".join(f"- {k}: {v}" for k, v in notes.items())
        if way_back is not None:
            text += f"\nWay back ({way_back.reason}): {' -> '.join(way_back.path)}"
        return text

    def snapshot(self) -> dict[str, Any]:
        """The graph as JSON-able nodes and edges, for logs and prompts."""

        def clean(value: Any) -> Any:
            return None if isinstance(value, float) and math.isnan(value) else value

        return {
            "nodes": [
                {"id": n, **{k: clean(v) for k, v in d.items()}}
                for n, d in self.graph.nodes(data=True)
            ],
            "edges": [
                {"from": a, "to": b, **{k: clean(v) for k, v in d.items()}}
                for a, b, d in self.graph.edges(data=True)
            ],
            "current": self.current,
            "travelled_m": round(self.travelled_m, 1),
        }
