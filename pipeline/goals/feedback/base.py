"""The feedback family: one interface, one registry, one file per kind.

A :class:`FeedbackKind` is everything zipon knows of one kind of feedback, in its one file:

- :meth:`~FeedbackKind.generate`: a goal and its scene (:class:`FeedbackContext`) -> the plain value stored in the
  goal's ``feedback`` mapping under the kind's ``name`` (the paper's FB dictionary), typed by the kind's
  :attr:`~FeedbackKind.field` (the goals document's :class:`~pipeline.goals.schema.Feedback` is made of them);
- :meth:`~FeedbackKind.say`: what the evaluator's simulated user says of it to an agent at a pose;
- :meth:`~FeedbackKind.parse`: what an agent reads back from a reply (the attributes of
  ``orion_eval.agents.ParsedFeedback`` the kind declares in :attr:`~FeedbackKind.parsed`);
- :attr:`~FeedbackKind.form`: how the annotation page edits the value.

The kinds:

- ``corrective``  dict object key -> what the user says when the agent reaches that (wrong) object
- ``descriptive`` str, appearance, state and function of the goal
- ``landmark``    str, salient objects near the goal in line of sight, with spatial relation words
- ``procedural``  str | None, the route in words from the recording's start pose (None: unreachable)
"""

from __future__ import annotations

import re

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Literal, Protocol

import numpy as np
from pydantic.fields import FieldInfo

from pipeline.config import GoalsParams
from pipeline.errors import ConfigError
from pipeline.geometry import GridSpec
from pipeline.goals.naming import Identity, RoomInfo
from pipeline.goals.objects import ObjectRecord


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
    # a building: its planner over every floor (pipeline.nav.building.BuildingPlanner), the floor the recording
    # starts on and the floor this context's goals lie on; None: one floor (``planner`` plans everything)
    building: Any = None
    start_floor: int = 0
    floor: int = 0

    def footprint_mask(self, keys: tuple[str, ...]) -> np.ndarray:
        idx = [self.object_keys.index(k) + 1 for k in keys]
        return np.isin(self.object_index, idx)


class Speaker(Protocol):
    """What the evaluator's simulated user (``orion_eval.user.SimulatedUser``) lends a kind's :meth:`FeedbackKind.say`:
    its goal (a ``GoalView``: ``name``, ``feedback``, ``mass_center``, ``room_id``) and what a person asked at
    ``pose`` perceives and how they say it."""

    goal: Any

    def looked_at(self, pose, keys) -> str | None:
        """The key among ``keys`` of the object the agent at ``pose`` is looking at (None: none of them)."""

    def route_from(self, pose) -> Any:
        """The route into the goal's region from ``pose`` (a ``Route``; None: the goal cannot be reached)."""

    def room_at(self, pose) -> str | None:
        """The room id at ``pose`` (None: outside every room)."""

    def place_key(self, pose) -> tuple[int, ...]:
        """The place asked from, as non-negative integers (the misjudgements' seed words)."""

    def say_metres(self, metres: float, where: tuple[int, ...]) -> str:
        """A distance as a person says it ("4 meters"), misjudged the same for the same ``where``."""

    def floor_words(self, pose) -> str | None:
        """Where the goal's floor is from the agent's at ``pose`` (:func:`floor_words`); None on the goal's floor or
        in a single-floor scene."""


def floor_words(floors_up: int) -> str | None:
    """How a person says where a floor ``floors_up`` floors above (negative: below) is: "upstairs", "downstairs",
    "2 floors up"; None for the same floor. :func:`read_floor_words` reads it back."""
    n = int(floors_up)
    if n == 0:
        return None
    if abs(n) == 1:
        return "upstairs" if n > 0 else "downstairs"
    return f"{abs(n)} floors {'up' if n > 0 else 'down'}"


def read_floor_words(words: str) -> int:
    """The floors up (negative: down) :func:`floor_words` said in ``words``; 0 when they say none."""
    words = words.strip().lower()
    if words in ("upstairs", "downstairs"):
        return 1 if words == "upstairs" else -1
    m = re.fullmatch(r"(\d+) floors (up|down)", words)
    return (int(m.group(1)) if m.group(2) == "up" else -int(m.group(1))) if m else 0


#: the floor words :func:`floor_words` says, as a regular expression (one group)
FLOOR_WORDS = r"(upstairs|downstairs|\d+ floors (?:up|down))"


#: how the annotation page edits a kind's value: free text, free text where empty means none (null), or one line
#: per ``key: text`` entry of a mapping
Form = Literal["text", "optional_text", "key_lines"]


class FeedbackKind(ABC):
    """One kind of user feedback (see the module docstring)."""

    name: ClassVar[str]
    #: the value's type and its field in the goals document (default, description): ``(type, Field(...))``
    field: ClassVar[tuple[Any, FieldInfo]]
    #: how the annotation page edits the value (served with the kinds by ``zipon annotate``)
    form: ClassVar[Form] = "text"
    #: what a new goal made on the annotation page starts with: a template of the goal's ``{class}`` ("" = the
    #: field's default)
    new_goal: ClassVar[str] = ""
    #: the attributes of ``ParsedFeedback`` :meth:`parse` fills, each with the factory of its value when the reply
    #: says nothing of the kind
    parsed: ClassVar[dict[str, Callable[[], Any]]]

    @abstractmethod
    def generate(self, goal: GoalDraft, ctx: FeedbackContext) -> Any:
        """The value stored under ``feedback[name]`` (JSON-able)."""

    def say(self, value: Any, user: Speaker, pose) -> str | None:
        """What the simulated user says of this kind to an agent at ``pose`` (``x, y, yaw``), from the goal's stored
        ``value``; None when the kind has nothing to say there. By default the stored text itself."""
        return value or None

    @abstractmethod
    def parse(self, reply: str) -> dict[str, Any]:
        """The :attr:`parsed` attributes ``reply`` gives (only those it says something of)."""


#: kind name -> implementation: the one list of feedback kinds (the goals document's fields, the evaluator's feedback
#: settings, what its user says and its agents read, the annotation page's form all derive from it)
FEEDBACK_KINDS: dict[str, type[FeedbackKind]] = {}


def register(cls: type[FeedbackKind]) -> type[FeedbackKind]:
    """Add ``cls`` under its ``name``; its :attr:`~FeedbackKind.parsed` attributes must be its own."""
    taken = {attr: other.name for other in FEEDBACK_KINDS.values() for attr in other.parsed if other is not cls}
    clash = sorted(set(cls.parsed) & (set(taken) | {"yes"}))
    if clash:
        raise TypeError(f"feedback kind {cls.name!r} ({cls.__qualname__}): parsed attribute(s) {clash} already "
                        f"filled by {sorted({taken.get(a, 'the yes/no reply') for a in clash})}")
    FEEDBACK_KINDS[cls.name] = cls
    return cls


def feedback_kind(name: str) -> FeedbackKind:
    """The kind registered as ``name``; a name the registry lacks is a ConfigError naming the registered kinds."""
    if name not in FEEDBACK_KINDS:
        raise ConfigError(f"feedback kind {name!r}: unknown; the registered kinds are {sorted(FEEDBACK_KINDS)} "
                          "(pipeline.goals.feedback: one module each)")
    return FEEDBACK_KINDS[name]()


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
