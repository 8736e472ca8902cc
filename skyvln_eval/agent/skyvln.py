"""The SkyVLN agent: perception, sub-goals, HSD, TrackBack memory and the motion generator.

Per step: record the place in memory, look around (panorama + straight down), note the
landmarks met, check whether the last fly-to found what it was after (:mod:`.pursuit`),
rank candidates for the pending landmark phrases (HSD, with memory's notes), then let the
motion generator choose one action. HSD off gives the coarse descriptor. TBMA off gives
no memory at all: no landmark notes, no way back, and no knowledge of the path flown
(where the start is, how far the drone has come) - that is the memory's to keep.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

from skyvln_eval.agent.actions import Action, FlyTo, action_record, decision_json_schema
from skyvln_eval.agent.base import (
    Agent,
    Decision,
    EpisodeBrief,
    Observation,
    episode_seed,
    llm_agent_settings,
)
from skyvln_eval.agent.calls import call_json
from skyvln_eval.agent.clarify import Clarification, ask_commander
from skyvln_eval.agent.hsd import HsdResult, PhraseMatch, SpatialDescriptor, matches_text
from skyvln_eval.agent.images import panorama_images
from skyvln_eval.agent.memory import TrackBackMemory
from skyvln_eval.agent.motion import (
    SYSTEM_PROMPT,
    MotionGenerator,
    action_space,
    commander_prompt,
    feedback_prompt,
    navigation_prompt,
    pose_prompt,
)
from skyvln_eval.agent.odometry import Odometer, pose_summary, roads_text
from skyvln_eval.agent.perception import Panorama, Perception
from skyvln_eval.agent.pursuit import Pursuit, Verdict, check_pursuit
from skyvln_eval.agent.subgoals import (
    DialogText,
    SubGoalPlan,
    parse_subgoals,
    subgoal_messages,
    subgoals_json_schema,
)
from skyvln_eval.avdn.records import DialogTurn
from skyvln_eval.frames import ViewPose
from skyvln_eval.llm.client import LLMClient
from skyvln_eval.llm.config import LLMConfig
from skyvln_eval.llm_records import LlmCall, ModuleFailure
from skyvln_eval.vocabulary import COMPASS

STOP_KINDS = ("destination", "stop_at")


@dataclass
class _EpisodeState:
    """Everything the agent carries from step to step of one episode."""

    brief: EpisodeBrief
    dialog: DialogText
    dialog_turns: tuple[DialogTurn, ...] = ()
    plan: SubGoalPlan | None = None
    odometer: Odometer = field(default_factory=Odometer)
    last_action: dict[str, Any] | None = None
    pursuit: Pursuit | None = None
    done: set[int] = field(default_factory=set)
    asked_about: set[str] = field(default_factory=set)  # phrases already asked about


class SkyVLNAgent(Agent):
    """See the module docstring; build it from an :class:`~skyvln_eval.agent.config.AgentConfig`."""

    name = "skyvln"

    def __init__(
        self,
        client: LLMClient,
        perception: Perception,
        llm: LLMConfig,
        hsd: bool = True,
        tbma: bool = True,
        top_k: int = 3,
        seed: int = 0,
        meet_radius_m: float = 40.0,
    ) -> None:
        self.client = client
        self.perception = perception
        self.llm = llm
        self.hsd = hsd
        self.tbma = tbma
        self.seed = seed
        self.descriptor = SpatialDescriptor(client, llm, enabled=hsd, top_k=top_k)
        decision = llm.generation(
            "motion", json_schema=decision_json_schema(), schema_name="decision"
        )
        self.motion = MotionGenerator(client, decision, llm.repair_policy())
        self.memory = TrackBackMemory(meet_radius_m) if tbma else None
        self._state: _EpisodeState | None = None

    def llm_clients(self) -> tuple[LLMClient, ...]:
        return (self.client, *self.perception.detector.llm_clients())

    def settings(self) -> dict[str, Any]:
        return llm_agent_settings(
            self.name,
            self.seed,
            self.client,
            self.llm,
            self.perception,
            hsd=self.hsd,
            tbma=self.tbma,
            top_k=self.descriptor.top_k,
        )

    def reset(self, brief: EpisodeBrief) -> None:
        self._state = _EpisodeState(
            brief, DialogText.of(brief.dialog, brief.current_round), brief.dialog
        )
        self.perception.reset(episode_seed(self.seed, brief.episode_key))
        if self.memory is not None:
            self.memory.reset(())

    def act(self, observation: Observation) -> Decision:
        st = self._state
        if st is None:
            raise RuntimeError("SkyVLNAgent.act called before reset(brief)")  # a harness bug
        records: list[LlmCall] = []
        exchanges: list[dict[str, Any]] = []
        failures: list[ModuleFailure] = []
        first_plan = st.plan is None
        if observation.new_dialog:  # the commander answered: plan again from the new words
            turns = (*st.dialog_turns, *observation.new_dialog)
            st.dialog_turns = turns
            st.dialog = DialogText.of(turns, max(t.round_index for t in turns))
            st.plan, st.done = None, set()
            # The answer's way and distance are said from here, not from the episode's start.
            st.odometer = Odometer()
        if st.plan is None:
            # The way it faces now, from its own pose: the words are said relative to it.
            heading = observation.pose.heading_deg
            st.plan = self._extract_subgoals(st.dialog, heading, records, exchanges, failures)
            if self.memory is not None and first_plan:
                self.memory.reset(st.plan.context_landmarks)
        pose = observation.pose
        place = None
        if self.memory is not None:
            # The words being followed now: the commander's answer, once there is one.
            instruction = st.dialog.instruction or st.brief.instruction
            place = self.memory.add_place(observation.step_index, pose, instruction, st.last_action)
        panorama = self.perception.observe(observation.sensors, pose, st.plan.landmark_phrases)
        detected = self.perception.detector.take_calls()  # a VLM detector's calls, if any
        records += detected.records
        exchanges += detected.exchanges
        failures += detected.failures
        st.odometer.update(pose, panorama.road_bearings_deg)
        met = []
        if self.memory is not None:
            met = self.memory.meet(observation.step_index, pose, panorama.sightings)
        verdict = Verdict()
        if st.pursuit is not None:
            verdict = check_pursuit(st.pursuit, panorama, pose, self.memory, self.client, self.llm)
            st.pursuit = None
        hsd = self._match(st, panorama, observation)
        self._update_done(st, hsd.matches, met)
        records += verdict.records + hsd.records
        exchanges += verdict.exchanges + hsd.exchanges
        failures += verdict.failures + hsd.failures
        question = verdict.question
        # The paper's clarification prompt is TrackBack memory's: without it (w/o TBMA)
        # the agent does not ask, so the ablation takes the commander's help away too.
        if question is None and self.memory is not None:  # which one of HSD's tied matches
            asked = self._ask_about_ambiguity(st, hsd.matches, pose)
            question = asked.question
            records += asked.records
            exchanges += asked.exchanges
            failures += asked.failures
        entries = self.descriptor.entries(panorama, pose.heading_deg)
        state = self._navigation_state(st, observation, entries, hsd, verdict, panorama)
        # What is seen now is where it is now; memory adds only what is out of sight.
        offsets = self.memory.offsets(pose) if self.memory is not None else {}
        offsets.update({s.landmark_id: (s.east_m, s.north_m) for s in panorama.sightings})
        images = []
        if self.client.backend.takes_images:
            images = panorama_images(panorama, self.llm.image_max_side_px)
        result = self.motion.decide(
            SYSTEM_PROMPT,
            self._prompt(st, observation, entries, panorama, verdict, hsd),
            state,
            offsets,
            images,
        )
        records += result.records
        exchanges += result.exchanges
        failures += [result.failure] if result.failure is not None else []
        st.pursuit = self._pursuit_of(st, result.action, hsd.matches, place, panorama)
        st.last_action = action_record(result.action)
        trace = {
            "subgoals": [g.to_dict() for g in st.plan.subgoals],
            "done_subgoals": sorted(st.done),
            # What the descriptor said, plus where in which image (for the viewer's boxes).
            "sightings": [
                {**entry, "box_px": list(s.box_px), "image_size_px": list(s.image_size_px)}
                for entry, s in zip(entries, panorama.sightings, strict=True)
            ],
            "roads_deg": list(panorama.road_bearings_deg),
            "views": panorama.view_records(),
            "hsd_matches": state["matches"],
            "memory": None if self.memory is None else self.memory.snapshot(),
            "way_back": None if verdict.way_back is None else verdict.way_back.to_dict(),
            "clarification_question": question,
            "repaired": result.repaired,
            "fallback": result.fallback,
            "failures": [f.to_json_dict() for f in failures],
            "exchanges": exchanges,
        }
        return Decision(
            result.thought, result.action, trace, tuple(records), tuple(failures), question
        )

    def _ask_about_ambiguity(
        self, st: _EpisodeState, matches: list[PhraseMatch], pose: ViewPose
    ) -> Clarification:
        """A question when HSD ranks two candidates for a stop landmark equally (once per
        phrase): which of them the commander means."""
        stops = {g.landmark for g in (st.plan.subgoals if st.plan else ()) if g.kind in STOP_KINDS}
        for m in matches:
            if not m.ambiguous or m.phrase not in stops or m.phrase in st.asked_about:
                continue
            st.asked_about.add(m.phrase)
            tied = [c for c in m.candidates if c.match == m.candidates[0].match][:3]
            where = "; ".join(
                f"{c.entry['id']} {c.entry['caption']}, {c.entry['distance_m']:.0f} m at bearing "
                f"{c.entry['bearing_deg']:.0f} deg"
                for c in tied
            )
            reason = f"{len(tied)} places look equally like {m.phrase!r} ({where})"
            clue = None if self.memory is None else self.memory.clue(pose)
            return ask_commander(self.client, self.llm, reason, m.phrase, clue)
        return Clarification()

    # -- parts ---------------------------------------------------------------------------
    def _extract_subgoals(
        self,
        dialog: DialogText,
        heading_deg: float,
        records: list[LlmCall],
        exchanges: list[dict[str, Any]],
        failures: list[ModuleFailure],
    ) -> SubGoalPlan:
        """The sub-goals of the dialog, for a drone facing ``heading_deg`` (compass
        degrees); when none could be extracted, the failure is recorded and the agent goes
        on from the commander's words alone (they are in every motion prompt)."""
        # Phrases may be made only of the dialog's words, so the schema is this dialog's.
        schema = subgoals_json_schema(dialog)
        config = self.llm.generation("subgoals", json_schema=schema, schema_name="subgoals")
        call = call_json(
            self.client,
            "subgoals",
            subgoal_messages(dialog, heading_deg),
            config,
            functools.partial(parse_subgoals, dialog=dialog),
            self.llm.repair_policy(),
        )
        records += call.records
        exchanges += call.exchanges
        failure = call.failure("subgoals", "no sub-goals (the instruction alone)")
        if failure is not None or call.value is None:
            failures += [failure] if failure is not None else []
            return SubGoalPlan(())
        return call.value

    def _match(self, st: _EpisodeState, panorama: Panorama, observation: Observation) -> HsdResult:
        """HSD on the pending landmark phrases, with the commander's direction and distance."""
        goals = st.plan.subgoals if st.plan is not None else ()
        pending = [g for i, g in enumerate(goals) if i not in st.done and g.landmark]
        direction = next(
            (COMPASS[g.direction] for g in goals if g.kind == "head" and g.direction in COMPASS),
            None,
        )
        distance = next((g.distance_m for g in goals if g.distance_m), None)
        # Without memory the agent does not know how far it has come, so it cannot say how
        # far is left (the instruction's whole distance would be a false "left to fly").
        remaining = None
        if distance is not None and self.memory is not None:
            # Whole metres, as the prompt's prose says it.
            remaining = round(max(0.0, distance - st.odometer.travelled_m))
        hint = {"direction_deg": direction, "remaining_m": remaining}
        notes = None if self.memory is None else self.memory.notes
        heading = observation.pose.heading_deg
        return self.descriptor.match(pending, panorama, heading, notes, hint)

    @staticmethod
    def _update_done(st: _EpisodeState, matches: list[PhraseMatch], met: list[str]) -> None:
        """A landmark to pass is done once memory has met the landmark HSD matched to it."""
        best = {m.phrase: m.best for m in matches}
        for i, goal in enumerate(st.plan.subgoals if st.plan is not None else ()):
            if goal.kind == "pass" and goal.landmark in best and best[goal.landmark] in met:
                st.done.add(i)

    def _pursuit_of(
        self,
        st: _EpisodeState,
        action: Action,
        matches: list[PhraseMatch],
        place: str | None,
        panorama: Panorama,
    ) -> Pursuit | None:
        """The fly-to to check next step, if it goes to a landmark taken for a stop goal."""
        by_id = panorama.by_id()
        if not isinstance(action, FlyTo) or action.landmark not in by_id or st.plan is None:
            return None
        stops = sorted(g.landmark for g in st.plan.subgoals if g.kind in STOP_KINDS and g.landmark)
        target = by_id[action.landmark]
        for m in matches:
            if m.phrase in stops and m.best == action.landmark:
                return Pursuit(target, m.phrase, place)
        if not self.hsd and stops:  # coarse: no ranking says which phrase it is for
            return Pursuit(target, stops[0], place)
        return None

    def _prompt(
        self,
        st: _EpisodeState,
        observation: Observation,
        entries: list[dict[str, Any]],
        panorama: Panorama,
        verdict: Verdict,
        hsd: HsdResult,
    ) -> str:
        """Action space, dialog, feedback, pose and navigation prompt (descriptor, HSD's
        matches, memory, sub-goal progress): everything of the task data, said once, what
        stays the same through the episode first (see :mod:`.motion`)."""
        pose = observation.pose
        remembered = st.odometer.start_roads if self.memory is not None else None
        landmarks = self.descriptor.text(entries)
        if hsd.matches:
            landmarks += "\n" + matches_text(hsd.matches)
        landmarks += "\n" + roads_text(panorama.road_bearings_deg, remembered)
        memory = None
        if self.memory is not None:
            memory = self.memory.prompt_text(pose, verdict.way_back)
        goals = st.plan.subgoals if st.plan is not None else ()
        lines = [
            f"{i + 1}. {g.kind} "
            + ", ".join(f"{k}={v}" for k, v in g.to_dict().items() if k != "kind")
            + (" [done]" if i in st.done else "")
            for i, g in enumerate(goals)
        ] or ["(no sub-goals: follow the commander's instruction above)"]
        if self.memory is not None:  # the path flown is the memory's to tell
            lines.append(st.odometer.text())
        return (
            action_space(memory=self.memory is not None)
            + commander_prompt(st.dialog)
            + feedback_prompt(
                observation.feedback, observation.step_index, observation.actions_left
            )
            + pose_prompt(pose)
            + navigation_prompt(landmarks, memory, "\n".join(lines))
        )

    def _navigation_state(
        self,
        st: _EpisodeState,
        observation: Observation,
        entries: list[dict[str, Any]],
        hsd: HsdResult,
        verdict: Verdict,
        panorama: Panorama,
    ) -> dict[str, Any]:
        """The task data of the motion request: what the prompt text says, as data."""
        pose = observation.pose
        memory = None
        if self.memory is not None:
            memory = {
                "notes": self.memory.notes([e["id"] for e in entries]),
                "way_back": None if verdict.way_back is None else verdict.way_back.to_dict(),
                "clue": self.memory.clue(pose),
            }
        goals = st.plan.subgoals if st.plan is not None else ()
        return {
            "dialog": st.dialog.to_dict(),
            "step": observation.step_index,
            "actions_left": observation.actions_left,
            "pose": pose_summary(pose),
            # The path flown is TrackBack memory's: without it the agent knows none of it.
            "odometry": None if self.memory is None else st.odometer.to_dict(),
            "feedback": observation.feedback,
            "last_action": st.last_action,
            "subgoals": [
                {**g.to_dict(), "status": "done" if i in st.done else "pending"}
                for i, g in enumerate(goals)
            ],
            "descriptor": "fine" if self.hsd else "coarse",
            "landmarks": entries,
            "matches": {m.phrase: m.to_dict() for m in hsd.matches},
            "memory": memory,
            "roads": {
                "here": list(panorama.road_bearings_deg),
                "at_start": None if self.memory is None else list(st.odometer.start_roads or ()),
            },
        }
