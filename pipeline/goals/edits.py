"""The annotation workflow: export a goals store for people to edit, validate and register their edit.

- :func:`export_goals` writes the goals document (YAML or JSON by extension).
- :func:`import_goals` validates an edited document (typed schema: field path + reason; unique
  names; objects and rooms exist in the scene's goals store) and stores it content-addressed as
  ``<edits_dir>/<scene>-<digest>.yaml``; the returned path goes into ``goals.edits[scene]`` (see
  :func:`record_goals_edit`), so the goals stage applies it deterministically and a new edit changes
  the stage's params digest. Rerunning upstream stages keeps the edit as long as its objects exist.
"""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from pipeline.errors import InputDataError
from pipeline.goals.schema import check_against_objects, document_digest, dump_document, load_document
from pipeline.goals.store import Goals
from pipeline.store import write_text_atomic

EDITS_DIR = "goals_edits"


def export_goals(goals_path: Path, out_file: Path) -> Path:
    """Write the goals document of ``goals_path`` to ``out_file`` (.yaml/.yml -> YAML, else JSON)."""
    goals = Goals(goals_path)
    out_file = Path(out_file)
    write_text_atomic(out_file, dump_document(goals.document, out_file.suffix))
    return out_file


def import_goals(edit_file: Path, goals_path: Path, root: Path, edits_dir: str = EDITS_DIR) -> str:
    """Validate ``edit_file`` against the scene in ``goals_path``; store it; return its path relative to ``root``.

    Raises :class:`InputDataError` naming the file, the field path and the reason.
    """
    edit_file = Path(edit_file)
    doc = load_document(edit_file)
    goals = Goals(goals_path)
    if doc.scene != goals.scene:
        raise InputDataError(f"document is for scene {doc.scene!r}, the goals store is scene {goals.scene!r}",
                             path=edit_file, field="scene")
    rooms = set(goals.document.rooms)
    check_against_objects(doc, set(goals.objects), rooms, path=edit_file)
    rel = f"{edits_dir}/{doc.scene}-{document_digest(doc)}.yaml"
    write_text_atomic(Path(root) / rel, dump_document(doc, ".yaml"))
    return rel


def record_goals_edit(params_path: Path, scene: str, rel_path: str) -> None:
    """Set ``goals.edits.<scene>: <rel_path>`` in ``params.yaml``.

    The file is rewritten by :func:`pipeline.config.params_yaml` (validated, every tunable with its
    documentation comment), so the result is a complete, checked params file.
    """
    from pipeline.config import parse_params, params_yaml

    params_path = Path(params_path)
    raw = yaml.safe_load(params_path.read_text()) or {}
    raw.setdefault("goals", {}).setdefault("edits", {})[scene] = rel_path
    write_text_atomic(params_path, params_yaml(parse_params(raw, origin=str(params_path))))


def edit_digest_from_name(path: str) -> str | None:
    m = re.search(r"-([0-9a-f]{12})\.ya?ml$", path)
    return m.group(1) if m else None
