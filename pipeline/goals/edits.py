"""The annotation workflow: export a goals store for people to edit, validate and register their edit.

- :func:`export_goals` writes the goals document (YAML or JSON by extension).
- :func:`import_goals` validates an edited document (typed schema: field path + reason; unique
  names; objects and rooms exist in the scene's goals store) and stores it content-addressed as
  ``<edits_dir>/<scene>-<digest>.yaml``; the returned path goes into ``goals.edits[scene]`` (see
  :func:`record_goals_edit`), so the goals stage applies it deterministically and a new edit changes
  the stage's params digest. Rerunning upstream stages keeps the edit as long as its objects exist.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.errors import InputDataError
from pipeline.goals.schema import (GoalsDocument, check_against_objects, document_digest, dump_document,
                                   load_document)
from pipeline.goals.store import Goals
from pipeline.store import write_text_atomic
from pipeline.userfiles import parse_yaml, read_user_text

EDITS_DIR = "goals_edits"


def export_goals(goals_path: Path, out_file: Path) -> Path:
    """Write the goals document of ``goals_path`` to ``out_file`` (.yaml/.yml -> YAML, else JSON)."""
    goals = Goals(goals_path)
    out_file = Path(out_file)
    write_text_atomic(out_file, dump_document(goals.document, out_file.suffix))
    return out_file


def validate_edit(edit_file: Path, goals_path: Path) -> GoalsDocument:
    """Parse ``edit_file`` and check it against the scene in ``goals_path`` (its objects and rooms).

    Raises :class:`InputDataError` naming the file, the field path and the reason.
    """
    edit_file = Path(edit_file)
    doc = load_document(edit_file)
    goals = Goals(goals_path)
    if doc.scene != goals.scene:
        raise InputDataError(f"document is for scene {doc.scene!r}, the goals store is scene {goals.scene!r}",
                             path=edit_file, field="scene")
    check_against_objects(doc, set(goals.objects), set(goals.document.rooms), path=edit_file)
    return doc


def edit_relpath(doc: GoalsDocument, edits_dir: str = EDITS_DIR) -> str:
    """Where a validated edit is stored, relative to the params file's folder (content-addressed)."""
    return f"{edits_dir}/{doc.scene}-{document_digest(doc)}.yaml"


def import_goals(edit_file: Path, goals_path: Path, root: Path, edits_dir: str = EDITS_DIR) -> str:
    """Validate ``edit_file`` against the scene in ``goals_path``; store it; return its path relative to ``root``."""
    doc = validate_edit(edit_file, goals_path)
    rel = edit_relpath(doc, edits_dir)
    write_text_atomic(Path(root) / rel, dump_document(doc, ".yaml"))
    return rel


def record_goals_edit(params_path: Path, scene: str, rel_path: str) -> None:
    """Set ``goals.edits.<scene>: <rel_path>`` in the params file, changing nothing else: comments, order,
    formatting and every other key stay as the user wrote them (a YAML round trip with ruamel.yaml, the
    library DVC itself edits params files with). The result is validated before it replaces the file."""
    import io

    from ruamel.yaml import YAML
    from ruamel.yaml.comments import CommentedMap

    from pipeline.paramsfile import parse_params

    params_path = Path(params_path)
    rt = YAML()  # round-trip: keeps comments and layout
    rt.width = 4096
    doc = rt.load(read_user_text(params_path, what="params YAML")) or CommentedMap()
    goals = doc.get("goals")
    if goals is None:
        goals = doc["goals"] = CommentedMap()
    edits = goals.get("edits")
    if edits is None or not hasattr(edits, "keys"):
        edits = goals["edits"] = CommentedMap()
    if hasattr(edits, "fa"):
        edits.fa.set_block_style()
    edits[scene] = rel_path
    buf = io.StringIO()
    rt.dump(doc, buf)
    text = buf.getvalue()
    parse_params(parse_yaml(text, origin=params_path), origin=str(params_path))
    write_text_atomic(params_path, text)
