"""The evaluation's sections of ``params.yaml``: ``task`` (the agent's action space and success rule, shared
by the routes stage and the evaluator), ``routes``, and ``eval`` with its ``llm`` endpoint: a leaf of the
params schema (:mod:`pipeline.config` imports it)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_serializer, model_validator

from pipeline.encoder_params.perception import DetectorParams
from pipeline.section import Section


class TaskParams(Section):
    """The ZIPON task's facts, one home: the action space, the success rule, and how a walk to a goal is planned.

    Read by the goals stage (goal regions, procedural feedback), the routes stage (episodes, replay) and the
    evaluator (``orion_eval``), which takes the action space and success radius from ``routes.zarr`` and refuses
    params that disagree with it. Not here: ``simulate.hfov_deg`` is the field of view of the camera that
    RECORDS a simulated scene (a real log brings its own intrinsics); ``hfov_deg`` here is the agent's ego view,
    a fact of the task that holds for real and simulated scenes alike. ``eval.goto_stop_radius_m`` is how close
    the evaluator's agents approach an object they found, a choice of the agents, not of the task.
    """

    step_m: float = Field(0.25, gt=0, description="forward action, metres (paper: 0.25)")
    turn_deg: float = Field(15.0, gt=0, le=180, description="turn action (left / right), degrees (paper: 15)")
    success_m: float = Field(
        1.5, gt=0, description="success radius: an episode succeeds within this distance of the goal's footprint "
        "(paper: 1.5); a goal's region is the navigable cells this close that see its mass centre, metres"
    )
    hfov_deg: float = Field(
        90.0, gt=0, lt=180, description="horizontal field of view of the agent's ego view: success needs the goal's "
        "mass centre inside it (paper: 90); the reference routes are replayed with it, degrees"
    )
    stop_radius_m: float = Field(
        1.0, gt=0, description="a walk to a goal (the reference routes, the procedural feedback of goals.zarr and of "
        "the simulated user) aims for goal-region cells within this distance of the footprint "
        "(pipeline.nav.region.route_target), metres"
    )
    clearance_m: float = Field(
        0.1, ge=0, description="planned paths keep this far from non-navigable cells, beyond recon's robot radius: "
        "the same for the reference routes and the agents, so SPL compares paths planned alike, metres"
    )

    @model_validator(mode="after")
    def _radii(self) -> "TaskParams":
        if self.stop_radius_m + self.step_m / 2 > self.success_m:
            raise ValueError("stop_radius_m + step_m / 2 must not exceed success_m (routes must end in success)")
        return self


class RoutesParams(Section):
    """Goals + navigable grid -> episodes, geodesic routes and procedural text (``routes.zarr``).

    The action space, success rule and planning margins are the task's (``task``)."""

    seed: int = Field(0, description="seed of the start poses")
    episodes_per_goal: int = Field(3, gt=0, description="episodes (start poses) per goal")
    min_geodesic_m: float = Field(2.0, ge=0, description="start poses are at least this geodesic distance away")
    cross_floor_per_goal: int = Field(
        1, ge=0, le=20, description="a building's episodes per goal from each other floor the stairs join to it (0: "
        "none); a single-floor scene has none")

    @model_serializer(mode="wrap")
    def _unset_building_keys(self, handler) -> dict:
        # a building's key at its default is not written, so a single-floor scene's routes digest is as before it
        data = handler(self)
        if data.get("cross_floor_per_goal") == 1:
            data.pop("cross_floor_per_goal")
        return data


class LLMParams(Section):
    """Optional LLM-backed user / agent through an OpenAI-compatible HTTP endpoint (off unless base_url is set)."""

    base_url: str | None = Field(
        None, description="e.g. http://127.0.0.1:8000/v1 (POST {base_url}/chat/completions); None = off, nothing "
        "is contacted"
    )
    model: str = Field("gpt-4o-mini", description="model name sent in each request")
    api_key_env: str | None = Field("OPENAI_API_KEY", description="environment variable holding the bearer key "
                                    "(unset variable = no Authorization header)")
    roles: Literal["user", "agent", "both"] = Field("both", description="which side the LLM plays")
    timeout_s: float = Field(30.0, gt=0, description="total deadline of one call (a streamed reply and every retry "
                             "included), seconds")
    max_requests: int = Field(200, gt=0, description="requests per evaluation run at most (then a StageError)")
    temperature: float = Field(0.0, ge=0, description="sampling temperature sent with each request")


class EvalParams(Section):
    """The light online evaluator (``zipon eval``, package ``orion_eval``): agents, simulated user, metrics.

    Actions: TurnLeft / TurnRight ``task.turn_deg`` (15 deg), MoveForward ``task.step_m`` (0.25 m), Talk, as
    ``routes.zarr`` records them. An episode ends on success or after ``max_talk_turns`` Talk turns (or
    ``max_steps`` actions). Method and feedback names are checked against their registries when the evaluator
    runs (:data:`orion_eval.agents.AGENTS`, :data:`orion_eval.user.FEEDBACK_SETTINGS`, which are derived from
    :data:`pipeline.goals.feedback.FEEDBACK_KINDS`), so a name is spelled once, in its registry.
    """

    scenes: tuple[str, ...] | None = Field(None, description="scenes to evaluate; None = every scene in 'scenes'")
    methods: tuple[str, ...] | None = Field(
        None, description="agents by name: the built-in ones (orion_eval.agents.AGENTS), plugins (zipon.agents "
        "entry points), llm (with eval.llm); None = every built-in agent, in the registry's order"
    )
    feedback: tuple[str, ...] | None = Field(
        None, description="simulated user's settings (orion_eval.user.FEEDBACK_SETTINGS: no interaction, yes/no, "
        "one per feedback kind of the goals, mixed); None = all of them"
    )
    seeds: tuple[int, ...] = Field((0, 1, 2, 3, 4), description="seeds (start pose choice, user draws); "
                                   "results are means over seeds")
    max_talk_turns: int = Field(5, gt=0, description="I_max: Talk turns per episode at most (paper: 5)")
    max_steps: int = Field(600, gt=0, description="movement actions per episode at most")
    success_rule: Literal["paper", "navchat"] = Field(
        "paper", description="'paper': within task.success_m of the goal, its mass centre in the ego view's "
        "field of view (task.hfov_deg) and in line of sight; 'navchat': navchat's tighter distance/angle bands"
    )
    camera_height_m: float | None = Field(
        None, gt=0, description="ego camera height above the floor; None = median height of the recording's poses"
    )
    orion_map: Literal["vlmap", "cfmap"] = Field("vlmap", description="the semantic map ORION retrieves from")
    detect_encoder: str | None = Field(
        None, description="encoder of detect_object ('vlmap' / 'cfmap' / an encoder name); None = the encoder the "
        "VLMap was built with"
    )
    detect_size: tuple[int, int] = Field((24, 32), description="ego view (height, width) ray-cast for detection")
    detect_max_range_m: float = Field(3.5, gt=0, description="detections farther than this are ignored, metres")
    detect_min_pixels: int = Field(4, gt=0, description="a detection needs this many winning ego-view pixels")
    explore_radius_m: float = Field(2.5, gt=0, description="a spin marks cells this close (in sight) as explored")
    explore_max_targets: int = Field(12, gt=0, description="frontier targets visited per search at most")
    reject_radius_m: float = Field(0.75, ge=0, description="candidates this close to a rejected place are skipped")
    goto_stop_radius_m: float = Field(
        1.25, gt=0, description="the agents' goto_object stops at the nearest place this close to a found object's "
        "cells from which its centre is in sight (an agent's choice; walks to a ground-truth goal use "
        "task.stop_radius_m), metres")
    workers: int = Field(2, gt=0, description="processes evaluating scenes in parallel (1 = serial)")
    detector: DetectorParams = Field(
        DetectorParams(), description="simulated open-vocabulary detector of the cow and orion agents (simulated scenes)"
    )
    llm: LLMParams = LLMParams()

    @field_validator("methods", "feedback", "seeds")
    @classmethod
    def _nonempty(cls, v):
        if v is None:
            return v
        if not v:
            raise ValueError("at least one value is needed")
        if len(set(v)) != len(v):
            raise ValueError("values must be distinct")
        return v
