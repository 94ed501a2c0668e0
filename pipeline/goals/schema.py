"""The typed, human-editable goals document: export to YAML/JSON, validated import.

Layout (YAML shown; JSON is the same structure)::

    format: zipon-goals
    format_version: 1
    scene: sim_00
    rooms:                      # room id -> type, owners ([] = shared), display name
      bedroom_1: {type: bedroom, owners: [Alice], name: Alice's bedroom}
    objects:                    # object key -> class, identity (its personalized name), room, position
      chair_0: {class: chair, identity: Alice's chair, room: bedroom_1, position_xy: [5.8, 3.5]}
    goals:
    - id: chair_0               # the representative object key
      name: Alice's chair       # unique in the scene
      type: ambiguous           # big | small | ambiguous
      room: Alice's bedroom
      room_id: bedroom_1
      objects: [chair_0]        # same_goal group: reaching any counts
      feedback:
        corrective: {chair_1: This is Bob's chair, not Alice's chair.}
        descriptive: It is a red chair made of wood. ...
        landmark: It is next to Alice's bed.
        procedural: turn left, go forward 5 meters, turn right

Positions are world metres (z-up world, see pipeline.geometry) and informational: geometry always
comes from the scene's objects. Import errors name the field path (``goals[2].feedback.corrective``)
and the reason.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Annotated, Literal

import yaml
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, create_model, model_validator

from pipeline.errors import InputDataError
from pipeline.goals.feedback import FEEDBACK_KINDS
from pipeline.goals.objects import XY, read_structured, strict_number, validation_error

DOC_FORMAT = "zipon-goals"
DOC_VERSION = 1


class _M(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True, allow_inf_nan=False)


#: a goal's feedback: one field per kind of the registry (each kind declares its field in its own module), in the
#: order of their names
Feedback = create_model("Feedback", __base__=_M, __module__=__name__,
                        **{name: kind.field for name, kind in sorted(FEEDBACK_KINDS.items())})


class GoalEntry(_M):
    id: str = Field(min_length=1)
    name: str = Field(min_length=1, description="personalized name, unique in the scene")
    type: Literal["big", "small", "ambiguous"]
    room: str | None = Field(None, description="room display name")
    room_id: str | None = None
    objects: list[str] = Field(min_length=1, description="object keys of the same_goal group")
    feedback: Feedback = Feedback()


class RoomEntry(_M):
    type: str
    owners: list[str] = Field(default_factory=list)
    name: str


class ObjectEntry(_M):
    cls: str = Field(alias="class")
    identity: str = Field(min_length=1)
    room: str | None = None
    position_xy: XY = Field(description="world x, y metres (finite)")


class GoalsDocument(_M):
    format: Literal["zipon-goals"] = DOC_FORMAT
    format_version: Annotated[Literal[1], BeforeValidator(strict_number)] = DOC_VERSION
    scene: str
    rooms: dict[str, RoomEntry] = Field(default_factory=dict)
    objects: dict[str, ObjectEntry]
    goals: list[GoalEntry]

    @model_validator(mode="after")
    def _consistent(self) -> "GoalsDocument":
        ids = [g.id for g in self.goals]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ValueError(f"goal ids are not unique: {dup}")
        names = [g.name.lower() for g in self.goals]
        dup = sorted({g.name for g in self.goals if names.count(g.name.lower()) > 1})
        if dup:
            raise ValueError(f"goal names are not unique in the scene: {dup}")
        for i, g in enumerate(self.goals):
            named = [(f"objects[{j}]", k) for j, k in enumerate(g.objects)]
            named += [(f"feedback.corrective.{k}", k) for k in g.feedback.corrective]
            for field, k in named:
                if k not in self.objects:
                    raise ValueError(f"goals[{i}].{field}: object {k!r} is not in 'objects' (goal {g.id})")
            if g.room_id is not None and self.rooms and g.room_id not in self.rooms:
                raise ValueError(f"goals[{i}].room_id: {g.room_id!r} is not in 'rooms' (goal {g.id})")
        together = {frozenset(g.objects) for g in self.goals}
        by_identity: dict[str, set[str]] = {}
        for k, o in self.objects.items():
            by_identity.setdefault(o.identity.lower(), set()).add(k)
        for ident, keys in sorted(by_identity.items()):
            # objects one name refers to must be found together: a goal naming one of them names the group
            # (objects of no goal may share a name: nobody is sent to them)
            if len(keys) > 1 and any(keys & t for t in together) and not any(keys <= t for t in together):
                raise ValueError(f"objects {sorted(keys)} share the identity {ident!r} but a goal names only some "
                                 f"of them")
        return self


def document_dict(doc: GoalsDocument) -> dict:
    return doc.model_dump(mode="json", by_alias=True)


def dump_document(doc: GoalsDocument, suffix: str) -> str:
    """Deterministic text of the document: YAML for .yaml/.yml, else JSON."""
    data = document_dict(doc)
    if suffix.lower() in (".yaml", ".yml"):
        return yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=100)
    return json.dumps(data, indent=2, ensure_ascii=False) + "\n"


def load_document(path: Path) -> GoalsDocument:
    """Parse and validate a goals document; :class:`InputDataError` names the file, field and reason."""
    return document_from_data(read_structured(path), path)


def document_from_data(raw: object, path: Path | str | None = None) -> GoalsDocument:
    """:func:`load_document`'s checks on data already read (``path`` names its origin in errors)."""
    if not isinstance(raw, dict):
        raise InputDataError("expected a mapping (format, scene, rooms, objects, goals)", path=path)
    try:
        return GoalsDocument.model_validate(raw)
    except ValidationError as err:
        raise validation_error(err, path) from None


def check_against_objects(doc: GoalsDocument, object_keys: set[str], room_ids: set[str], *, path=None) -> None:
    """Every object and room the document names exists in the scene."""
    for k in sorted(doc.objects):
        if k not in object_keys:
            raise InputDataError(f"object {k!r} does not exist in scene {doc.scene!r}", path=path,
                                 field=f"objects.{k}", expected=f"one of {len(object_keys)} scene objects")
    for i, g in enumerate(doc.goals):
        for j, k in enumerate(g.objects):
            if k not in object_keys:
                raise InputDataError(f"object {k!r} does not exist in scene {doc.scene!r}", path=path,
                                     field=f"goals[{i}].objects[{j}]")
        if g.room_id is not None and room_ids and g.room_id not in room_ids:
            raise InputDataError(f"room {g.room_id!r} does not exist in scene {doc.scene!r}", path=path,
                                 field=f"goals[{i}].room_id", expected=f"one of {sorted(room_ids)}")


def document_digest(doc: GoalsDocument) -> str:
    text = json.dumps(document_dict(doc), sort_keys=True, separators=(",", ":"))
    return hashlib.blake2b(text.encode(), digest_size=6).hexdigest()
