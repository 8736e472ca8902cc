"""Baselines: random, ground-truth replay, and a NavGPT-style LLM-only agent.

* :class:`RandomAgent` draws a uniformly random action of the vocabulary each step
  (STOP included), seeded by the agent seed and the episode id.
* The ground-truth replay is not an agent: it reads the route, which no agent may. The
  harness builds it from the episode as a labelled oracle (:mod:`skyvln_eval.harness.oracle`).
* :class:`NavGPTAgent` is the LLM alone, as in NavGPT: one call per step with the whole
  instruction, view-level descriptions of what each view shows (label, caption, left /
  centre / right; no ids, distances or sectors), and the history of its own actions. No
  sub-goal module, no HSD, no memory graph, no fly-to (nothing to name).
"""

from __future__ import annotations

import json
import random
from typing import Any

from skyvln_eval.agent.actions import (
    action_from_dict,
    action_record,
    decision_json_schema,
)
from skyvln_eval.agent.base import (
    Agent,
    Decision,
    EpisodeBrief,
    Observation,
    episode_seed,
    llm_agent_settings,
)
from skyvln_eval.agent.hsd import coarse_position
from skyvln_eval.agent.images import panorama_images
from skyvln_eval.agent.motion import (
    SYSTEM_PROMPT,
    MotionGenerator,
    action_space,
    commander_prompt,
    feedback_prompt,
    pose_prompt,
)
from skyvln_eval.agent.odometry import Odometer, pose_summary, roads_text
from skyvln_eval.agent.perception import Panorama, Perception
from skyvln_eval.agent.subgoals import DialogText
from skyvln_eval.llm.client import LLMClient
from skyvln_eval.llm.config import LLMConfig
from skyvln_eval.llm.simple import random_action


class RandomAgent(Agent):
    name = "random"

    def __init__(self, seed: int = 0) -> None:
        self.seed = seed
        self._rng = random.Random(seed)

    def settings(self) -> dict[str, Any]:
        return {"name": self.name, "seed": self.seed}

    def reset(self, brief: EpisodeBrief) -> None:
        self._rng = random.Random(episode_seed(self.seed, brief.episode_key))

    def act(self, observation: Observation) -> Decision:
        action = action_from_dict(random_action(self._rng, {}), {})
        return Decision("random action", action, {"action": action_record(action)})


class NavGPTAgent(Agent):
    name = "navgpt"

    def __init__(
        self, client: LLMClient, perception: Perception, llm: LLMConfig, seed: int = 0
    ) -> None:
        self.client = client
        self.perception = perception
        self.llm = llm
        self.seed = seed
        self.motion = MotionGenerator(
            client,
            llm.generation("navgpt", json_schema=decision_json_schema(), schema_name="decision"),
            llm.repair_policy(),
            module="navgpt",
        )

    def llm_clients(self) -> tuple[LLMClient, ...]:
        return (self.client, *self.perception.detector.llm_clients())

    def settings(self) -> dict[str, Any]:
        return llm_agent_settings(self.name, self.seed, self.client, self.llm, self.perception)

    def reset(self, brief: EpisodeBrief) -> None:
        self._brief = brief
        self._dialog = DialogText.of(brief.dialog, brief.current_round)
        self._history: list[dict[str, Any]] = []
        self._odometer = Odometer()
        self.perception.reset(episode_seed(self.seed, brief.episode_key))

    def act(self, observation: Observation) -> Decision:
        if not hasattr(self, "_brief"):
            raise RuntimeError("NavGPTAgent.act called before reset(brief)")  # a harness bug
        pose = observation.pose
        if self._history:
            self._history[-1]["feedback"] = observation.feedback
        panorama = self.perception.observe(observation.sensors, pose)
        detected = self.perception.detector.take_calls()  # a VLM detector's calls, if any
        self._odometer.update(pose, panorama.road_bearings_deg)
        views = self._views(panorama)
        state = {
            "dialog": self._dialog.to_dict(),
            "observation": views,
            "history": self._history[-8:],
            "pose": pose_summary(pose),
            "odometry": self._odometer.to_dict(),
            "actions_left": observation.actions_left,
            "feedback": observation.feedback,
            "roads": {
                "here": list(panorama.road_bearings_deg),
                "at_start": list(self._odometer.start_roads or ()),
            },
        }
        seen = "\n".join(
            f"- {v['name']} (facing {v['heading_deg']:.0f} deg): "
            + (
                ", ".join(f"{o['caption'] or o['label']} ({o['position']})" for o in v["objects"])
                or "nothing notable"
            )
            for v in views
        )
        recent = self._history[-8:]
        # The last action's outcome is the Feedback block's: said there, not here again.
        history = "\n".join(
            f"- {json.dumps(h['action'])}: {h['thought']}"
            + (f" -> {h.get('feedback')}" if k < len(recent) - 1 else "")
            for k, h in enumerate(recent)
        )
        user = (
            action_space(fly_to=False)  # nothing to name: its schema has no fly_to either
            + commander_prompt(self._dialog)
            + pose_prompt(pose)
            + f"## What you see\n{seen}\n"
            + f"{roads_text(panorama.road_bearings_deg, self._odometer.start_roads)}\n"
            + f"{self._odometer.text()}\n"
            + f"## History\n{history or '(none)'}\n"
            + feedback_prompt(
                observation.feedback, observation.step_index, observation.actions_left
            )
        )
        images = []
        if self.client.backend.takes_images:
            images = panorama_images(panorama, self.llm.image_max_side_px)
        result = self.motion.decide(SYSTEM_PROMPT, user, state, {}, images)
        self._history.append({"action": action_record(result.action), "thought": result.thought})
        trace = {
            "observation": views,
            "views": panorama.view_records(),
            "fallback": result.fallback,
            "repaired": result.repaired,
            "exchanges": result.exchanges,
        }
        trace["exchanges"] = detected.exchanges + result.exchanges
        failures = (*detected.failures, *([result.failure] if result.failure else []))
        records = (*detected.records, *result.records)
        return Decision(result.thought, result.action, trace, records, failures)

    @staticmethod
    def _views(panorama: Panorama) -> list[dict[str, Any]]:
        """What each view shows, as a captioner would say it: no ids, distances or sectors."""
        return [
            {
                "name": v.name,
                "heading_deg": round(v.heading_deg, 1),
                "objects": [
                    {
                        "label": s.label,
                        "caption": s.caption,
                        "position": coarse_position(s.box_px, s.image_size_px),
                    }
                    for s in panorama.sightings
                    if s.view_index == v.index
                ],
            }
            for v in panorama.views
        ]
