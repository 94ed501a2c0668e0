"""The feedback family: one interface, one registry, one file per kind.

A :class:`FeedbackKind` turns a goal and its scene (:class:`FeedbackContext`) into the plain value
stored in the goal's ``feedback`` mapping under the kind's ``name`` (the paper's FB dictionary):

- ``corrective``  dict object key -> what the user says when the agent reaches that (wrong) object
- ``descriptive`` str, appearance, state and function of the goal
- ``landmark``    str, salient objects near the goal in line of sight, with spatial relation words
- ``procedural``  str | None, the route in words from the recording's start pose (None: unreachable)
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar

import numpy as np

from pipeline.config import GoalsParams
from pipeline.geometry import GridSpec
from pipeline.goals.naming import Identity, RoomInfo
from pipeline.goals.objects import ObjectRecord
from pipeline.goals.schema import Feedback


@dataclass
class GoalDraft:
    """A goal before its feedback is attached."""

    id: str  # the representative object key
    name: str
    type: str  # big | small | ambiguous
    cls: str
    room_id: str | None
    room_name: str | None
    members: tuple[str, ...]  # object keys; reaching any counts (same_goal)


@dataclass
class FeedbackContext:
    """Everything a feedback kind may read about the scene."""

    objects: dict[str, ObjectRecord]
    identities: dict[str, Identity]  # object key -> identity of its same_goal group
    rooms: dict[str, RoomInfo]
    goals: list[GoalDraft]
    grid: GridSpec
    walls: np.ndarray  # (rows, cols) bool: cells that block line of sight
    object_index: np.ndarray  # (rows, cols) int32: 1 + index into ``object_keys``, 0 none
    object_keys: list[str]
    planner: Any = None  # pipeline.nav.actions.RoutePlanner, or None (no navigable grid)
    start_pose: tuple[float, float, float] | None = None  # x, y, yaw of the recording's start
    # members -> (rows, cols) bool goal region (pipeline.goals.build.GoalRegions, stored in goals.zarr and
    # read by the routes stage); None = no reconstruction mesh: routes end within the planner's stop radius
    goal_region: Callable[[tuple[str, ...]], np.ndarray] | None = None
    settings: GoalsParams = field(default_factory=GoalsParams)  # the goals params (landmark radius, ...)

    def footprint_mask(self, keys: tuple[str, ...]) -> np.ndarray:
        idx = [self.object_keys.index(k) + 1 for k in keys]
        return np.isin(self.object_index, idx)


class FeedbackKind(ABC):
    """One kind of user feedback."""

    name: ClassVar[str]

    @abstractmethod
    def generate(self, goal: GoalDraft, ctx: FeedbackContext) -> Any:
        """The value stored under ``feedback[name]`` (JSON-able)."""


#: kind name -> implementation: the one list of feedback kinds (the evaluator's feedback settings derive from it)
FEEDBACK_KINDS: dict[str, type[FeedbackKind]] = {}


def register(cls: type[FeedbackKind]) -> type[FeedbackKind]:
    """Add ``cls`` under its ``name``, which must be a field of the goals document's
    :class:`~pipeline.goals.schema.Feedback` (where its values are stored and edited)."""
    if cls.name not in Feedback.model_fields:
        raise TypeError(f"feedback kind {cls.name!r} ({cls.__qualname__}) has no field in "
                        f"pipeline.goals.schema.Feedback {sorted(Feedback.model_fields)}")
    FEEDBACK_KINDS[cls.name] = cls
    return cls


def class_is_unique(key: str, ctx: FeedbackContext) -> bool:
    """Whether the object is the scene's one instance of its class (one identity: a pair counts once), so that
    its class name alone finds it: "the fridge"."""
    cls = ctx.objects[key].cls
    return len({ctx.identities[k].members for k, o in ctx.objects.items() if o.cls == cls}) == 1


def object_phrase(key: str, ctx: FeedbackContext) -> str:
    """How the user names another object: 'the bed', or its identity when its class repeats."""
    return f"the {ctx.objects[key].cls}" if class_is_unique(key, ctx) else ctx.identities[key].name


def appearance(obj: ObjectRecord) -> str:
    """What an object looks like, as the user says it: "white nightstand made of wood" (the colour and material
    when known). The descriptive feedback says it of the goal, the landmark feedback of a landmark."""
    words = " ".join(w for w in (obj.color_name, obj.cls) if w)
    return words + (f" made of {obj.material}" if obj.material else "")
