"""The annotation workflow: export a goals store for people to edit, validate and register their edit.

- :func:`export_goals` writes the goals document (YAML or JSON by extension).
- :func:`import_goals` validates an edited document (typed schema: field path + reason; unique
  names; objects and rooms exist in the scene's goals store) and stores it content-addressed as
  ``<edits_dir>/<scene>-<digest>.yaml``; the returned path goes into ``goals.edits[scene]`` (see
  :func:`record_goals_edit`), so the goals stage applies it deterministically and a new edit changes
  the stage's params digest. Rerunning upstream stages keeps the edit as long as its objects exist.
- :func:`save_goals_edit` is the whole transaction ``zipon goals import`` and ``zipon annotate`` run: store the
  validated edit, rebuild goals and routes with it, then record it in the params file; when the rebuild fails,
  everything it wrote is undone and :class:`EditNotSaved` says why.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pipeline.errors import InputDataError, StageError
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
    return check_document(load_document(edit_file), goals_path, origin=edit_file)


def check_document(doc: GoalsDocument, goals_path: Path, *, origin: Path | str | None = None) -> GoalsDocument:
    """``doc`` checked against the scene in ``goals_path``: same scene, every object and room it names exists
    there, and each goal's objects lie on one floor (a building's; :class:`InputDataError` naming ``origin``, the
    field path and the reason)."""
    goals = Goals(goals_path)
    if doc.scene != goals.scene:
        raise InputDataError(f"document is for scene {doc.scene!r}, the goals store is scene {goals.scene!r}",
                             path=origin, field="scene")
    check_against_objects(doc, set(goals.objects), set(goals.document.rooms), path=origin)
    for i, g in enumerate(doc.goals):
        if len({goals.objects[k].floor for k in g.objects}) > 1:
            named = ", ".join(f"{k} (floor {goals.objects[k].floor})" for k in g.objects)
            raise InputDataError(f"{named} lie on different floors; a goal's objects lie on one floor",
                                 path=origin, field=f"goals[{i}].objects")
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


# ----------------------------------------------------------------------------- the import transaction

REBUILT = ("goals", "routes")


@dataclass(frozen=True)
class SavedEdit:
    """A goals edit stored, rebuilt into goals and routes, and recorded in the params file."""

    scene: str
    path: str  # the stored edit, relative to the params file's folder (the value of goals.edits.<scene>)
    digest: str  # the document's digest (part of the stored file's name)
    outcomes: tuple  # the rebuild's pipeline.engine.runner.Outcome of goals and routes
    dvc_note: str  # what happened to dvc.lock ("" when nothing needed saying)


class EditNotSaved(StageError):
    """The save failed at ``step`` (``"rebuild"``, ``"params"`` or ``"dvc.lock"``) and was undone: the params file,
    ``dvc.yaml``, ``dvc.lock``, the stored edits and the built goals and routes are as they were. ``outcomes`` are
    the failed rebuild's, ``restored`` the stages rebuilt without the edit."""

    def __init__(self, message: str, outcomes: tuple = (), restored: tuple[str, ...] = (), step: str = "rebuild"):
        super().__init__(message)
        self.outcomes, self.restored, self.step = outcomes, restored, step


def save_goals_edit(ws, scene: str, doc: GoalsDocument, stages: dict, *, overrides: tuple[str, ...] = (),
                    show_progress: bool = False, record_dvc: bool = True) -> SavedEdit:
    """Store the validated ``doc`` content-addressed beside ``ws``'s params file, rebuild ``scene``'s goals and
    routes with it (``stages``: the stage registry; each stage under its lock), then set ``goals.edits.<scene>`` in
    the params file (comments kept) and record both stages in dvc.lock. ``overrides`` are the caller's ``--set``
    values. All or nothing: when any step fails, the stored file is removed, the params file, ``dvc.yaml`` and
    ``dvc.lock`` get their bytes back, a stage already republished with the edit is rebuilt without it (same
    inputs and params, so the same content), and :class:`EditNotSaved` says which step failed (an error that
    stopped the rebuild itself, such as a held lock, is raised as it is, after the same undoing)."""
    from pipeline.paramsfile import load_params
    from pipeline.engine.runner import run_many
    from pipeline.engine.stagegraph import plan

    rel = edit_relpath(doc)
    stored = ws.root / rel
    created = [p for p in (stored.parent, stored) if not p.exists()]  # removed again if the import fails
    kept = {p: _bytes(p) for p in (ws.params_path, ws.root / "dvc.yaml", ws.root / "dvc.lock")}
    write_text_atomic(stored, dump_document(doc, ".yaml"))
    manifests = {stage: ws.manifest(scene, stage) for stage in REBUILT}
    published = {stage: _bytes(path) for stage, path in manifests.items()}

    def rebuild(extra: tuple[str, ...]) -> list:
        params = load_params(ws.params_path, (*overrides, *extra))
        pairs = plan(stages, params, [scene], list(REBUILT))
        return run_many(ws, params, stages, pairs, scheduler="sync", show_progress=show_progress)

    outcomes: list = []
    step, note = "rebuild", ""
    try:  # the rebuild sees the edit through an override; the params file is written once it succeeded
        outcomes = rebuild((f"goals.edits.{scene}={rel}",))
        failed = [o for o in outcomes if o.status == "failed"]
        if failed:
            raise EditNotSaved(f"{failed[0].scene}/{failed[0].stage}: {failed[0].error.splitlines()[0]}")
        step = "params"
        record_goals_edit(ws.params_path, scene, rel)
        if record_dvc:
            from pipeline.engine.dvcfile import sync_dvc_lock

            step = "dvc.lock"
            note = sync_dvc_lock(ws, load_params(ws.params_path, overrides), stages,
                                 [(scene, stage) for stage in REBUILT], overrides)
    except Exception as err:  # noqa: BLE001 - re-raised below, after undoing what this transaction wrote
        restored = _undo(created, kept, manifests, published, rebuild)
        if isinstance(err, EditNotSaved) or step != "rebuild":
            what = "" if step == "rebuild" else f"{step} could not be recorded, so the whole save was undone: "
            raise EditNotSaved(f"{what}{err}; {ws.params_path.name} unchanged", tuple(outcomes), restored,
                               step) from None
        raise
    return SavedEdit(scene, rel, document_digest(doc), tuple(outcomes), note)


def _undo(created: list[Path], kept: dict[Path, bytes | None], manifests: dict, published: dict, rebuild) -> tuple:
    """Put back what a failed save wrote: files it created removed, files it changed given their bytes back, and
    the stages republished with the edit rebuilt without it. Returns those stages."""
    from pipeline.store import remove

    for path in reversed(created):
        remove(path)
    for path, data in kept.items():
        if data is None:
            path.unlink(missing_ok=True)
        elif _bytes(path) != data:
            write_text_atomic(path, data.decode("utf-8"))  # the files it changes are UTF-8 text
    restored = tuple(stage for stage, path in manifests.items() if _bytes(path) != published[stage])
    if restored:
        rebuild(())
    return restored


def _bytes(path: Path) -> bytes | None:
    return path.read_bytes() if path.is_file() else None
