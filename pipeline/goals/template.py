"""Starting points for a user's own goals: a commented objects file and JSON Schemas of the editable files.

- :func:`objects_template`: YAML in the :class:`~pipeline.goals.objects.ObjectSet` layout that
  ``goals.objects: file`` reads (``goals.objects_files[scene]``), every field explained in a comment,
  filled with the scene's objects when goals were built (else one example object placed in the middle
  of the reconstruction, else at the origin). It validates as it is.
- :func:`json_schema`: JSON Schema (draft 2020-12, from the pydantic models) of the goals document
  (``zipon goals export``/``import``) or of the objects file, for editors that check YAML/JSON.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from pipeline.errors import ConfigError
from pipeline.goals.objects import ObjectRecord, ObjectSet, RoomRecord

SCHEMAS = ("goals", "objects")


def _field_comments(model, indent: str) -> list[str]:
    lines = []
    for name, f in model.model_fields.items():
        req = "required" if f.is_required() else f"default {f.default!r}" if f.default_factory is None else "optional"
        lines.append(f"{indent}#   {name}: {f.description or ''} ({req})".rstrip())
    return lines


def _example_object(recon_path: Path | None) -> dict:
    """A 0.6 m x 0.6 m chair in the middle of the reconstruction's occupied cells (or at the origin)."""
    cx, cy = 0.0, 0.0
    if recon_path is not None and Path(recon_path).exists():
        from pipeline.recon import Recon
        from pipeline.recon.store import OCCUPIED

        recon = Recon(recon_path)
        rc = np.argwhere(recon.occupancy == OCCUPIED)
        if len(rc):
            mid = rc[np.argmin(((rc - rc.mean(axis=0)) ** 2).sum(axis=1))]  # an occupied cell near their middle
            cx, cy = (round(float(v), 2) for v in recon.grid.cell_to_world(mid))
    h = 0.3
    return ObjectRecord(key="chair_0", cls="chair", instance_id=0, room=None,
                        footprint=[(cx - h, cy - h), (cx + h, cy - h), (cx + h, cy + h), (cx - h, cy + h)],
                        mass_center=(cx, cy), z_range=(0.0, 0.9), size="big", color_name="brown", material="wood",
                        description=["a wooden chair with armrests"]).model_dump(mode="json")


def objects_template(scene: str, *, goals_path: Path | None = None, recon_path: Path | None = None) -> str:
    """The commented YAML text (see the module docstring)."""
    if goals_path is not None and Path(goals_path).exists():
        from pipeline.goals.store import Goals

        goals = Goals(goals_path)
        objects = [o.model_dump(mode="json") for o in goals.objects.values()]
        rooms = [RoomRecord(id=rid, type=r.type).model_dump(mode="json") for rid, r in goals.document.rooms.items()]
        origin = f"the {len(objects)} objects of the built goals.zarr ({goals.meta.source})"
    else:
        objects, rooms = [_example_object(recon_path)], []
        origin = "one example object; replace it with yours"
    head = [
        f"# zipon objects file for scene {scene!r}: the objects personalized goals are made of.",
        f"# Filled with {origin}.",
        "# Use it: params.yaml -> goals: {objects: file, objects_files: {" + scene + ": THIS_FILE}}, then",
        f"#   zipon run -s {scene} --stage goals   (errors name the field, e.g. objects[2].footprint)",
        "# JSON Schema for editors: zipon goals schema --what objects",
        "# Units: world metres (right-handed, z up, the frames' world frame); heights are metres above the floor.",
        "#",
        "# rooms (optional): one entry per room",
        *_field_comments(RoomRecord, ""),
        "# objects: one entry per object",
        *_field_comments(ObjectRecord, ""),
    ]
    body = yaml.safe_dump({"rooms": rooms, "objects": objects}, sort_keys=False, default_flow_style=None,
                          allow_unicode=True, width=110)
    return "\n".join(head) + "\n" + body


def json_schema(what: str) -> dict:
    """JSON Schema of ``what`` = 'goals' (the goals document) or 'objects' (an objects file)."""
    if what not in SCHEMAS:
        raise ConfigError(f"--what {what!r}: choose one of {list(SCHEMAS)}")
    if what == "goals":
        from pipeline.goals.schema import GoalsDocument

        schema = GoalsDocument.model_json_schema(by_alias=True)
        title = "zipon goals document (zipon goals export / import)"
    else:
        schema = ObjectSet.model_json_schema(by_alias=True)
        # the file leaves out what the goals stage fills in: the scene name and the source
        schema["required"] = [k for k in schema.get("required", []) if k not in ("scene", "source")]
        title = "zipon objects file (goals.objects: file)"
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema, "title": title}
