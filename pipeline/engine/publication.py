"""Publishing a stage's whole output set and its manifest as one unit: all of it or none of it.

A stage writes its outputs in a private temporary folder (:func:`pipeline.store.new_tmp_dir`). The
runner then publishes them with :func:`publish_outputs`, holding the (scene, stage) lock
(:mod:`pipeline.engine.locks`), by this protocol:

1. **Intent**: the journal ``artifacts/<scene>/.<stage>.publish.json`` is written atomically
   (temporary file, fsync, rename, fsync of the folder). It lists every move ``tmp -> final``, the
   name the previous version will be set aside under (``.<name>.old-<token>``, same folder) and
   whether there is one, and the exact text of the new manifest.
2. **Moves**: for each output the previous version is renamed aside, then the new one renamed in
   (each a single rename on one filesystem).
3. **Manifest**: ``manifests/<scene>/<stage>.json`` is written atomically from the journal's text.
4. **Commit**: the journal is rewritten with ``committed: true``.
5. **Cleanup**: the set-aside previous versions are deleted, then the journal.

A kill at any instant leaves a journal (steps 1-5) or nothing to undo (before 1, after 5).
:func:`recover`, run by the next ``run_stage`` of that (scene, stage) under its lock before it
looks at anything else, brings the set back to one consistent version:

- a **committed** journal: the new outputs and manifest are in place; finish the cleanup;
- an **uncommitted** journal whose new outputs all still exist (in the temporary folder or
  already renamed in): **roll forward**, i.e. finish the moves, write the manifest, commit, clean up;
- otherwise (a temporary output was lost): **roll back**, i.e. put every previous version back
  (deleting the new one in its place) and delete the journal. The manifest was not touched: step 3
  is reached only once every move is done, and then nothing new is missing.

Every recovery step is idempotent, so a kill during recovery is repaired by the next one. Recovery
also deletes what single-file publication (:func:`pipeline.store.publish`) or an atomic write may
have left for this stage's outputs: ``.<name>.old-*`` and ``.<name>.tmp-*`` siblings.

A kill -9 (an OOM kill, a lost dask worker) loses nothing the kernel has accepted, so the protocol
holds against it as is. Against a power loss, the journal, the manifest and the renamed folder
entries are fsynced in this order; the outputs' own files are not (an fsync costs ~16 ms per file on
this project's VM disk, seconds for a store of hundreds of chunks), so a torn chunk after a power loss
is possible, and ``zipon verify`` reports it.
"""

from __future__ import annotations

import os
import socket
import uuid
from pathlib import Path

from pydantic import BaseModel, ConfigDict

from pipeline.errors import ArtifactError, StageError
from pipeline.engine.manifest import Manifest
from pipeline.paths import Workspace
from pipeline.store import fsync_dir, remove, write_text_atomic

JOURNAL_FORMAT_VERSION = 1


class Move(BaseModel):
    """One output of the set: where it was built, where it goes, and where the old one is set aside."""

    model_config = ConfigDict(extra="forbid")
    tmp: str
    final: str
    aside: str
    had_old: bool


class Journal(BaseModel):
    """The intent record of one publication (``artifacts/<scene>/.<stage>.publish.json``)."""

    model_config = ConfigDict(extra="forbid")
    format_version: int = JOURNAL_FORMAT_VERSION
    host: str
    pid: int
    moves: list[Move]
    manifest_path: str
    manifest_text: str
    committed: bool = False


# Every change publication makes on disk goes through these three functions (tests interpose on
# them to kill the process between any two changes).

def _replace(src: Path, dst: Path) -> None:
    os.replace(src, dst)


def _write(path: Path, text: str) -> None:
    write_text_atomic(path, text)


def _remove(path: Path) -> None:
    remove(path)


# ----------------------------------------------------------------------------- publishing

def publish_outputs(journal_path: Path, outputs: dict[Path, Path], manifest_path: Path, manifest: Manifest) -> None:
    """Publish ``outputs`` (final path -> finished temporary path) and ``manifest`` as one set.

    On an error (a full disk, a read-only folder) the previous set is restored before the error
    propagates; on a kill, :func:`recover` finishes or undoes the publication later.
    """
    journal_path = Path(journal_path)
    if journal_path.exists():
        raise StageError(f"{journal_path}: an unfinished publication is pending; recover it first")
    token = uuid.uuid4().hex[:8]
    moves = []
    for final, tmp in outputs.items():
        final, tmp = Path(final), Path(tmp)
        if not tmp.exists():
            raise StageError(f"{tmp}: output to publish as {final} does not exist")
        final.parent.mkdir(parents=True, exist_ok=True)
        moves.append(Move(tmp=str(tmp), final=str(final), aside=str(final.with_name(f".{final.name}.old-{token}")),
                          had_old=final.exists() or final.is_symlink()))
    journal = Journal(host=socket.gethostname(), pid=os.getpid(), moves=moves,
                      manifest_path=str(manifest_path), manifest_text=manifest.text())
    _write(journal_path, journal.model_dump_json(indent=1))
    try:
        _roll_forward(journal_path, journal)
    except BaseException:
        # a live error (not a kill): leave the previous set as it was, if the disk lets us
        try:
            recover(journal_path, [Path(m.final) for m in moves], manifest_path, prefer_rollback=True)
        except OSError:
            pass  # the journal stays; the next run's recover() repairs the set
        raise


def _roll_forward(journal_path: Path, journal: Journal) -> None:
    if not journal.committed:
        for m in journal.moves:
            tmp, final, aside = Path(m.tmp), Path(m.final), Path(m.aside)
            if not tmp.exists():
                continue  # already renamed in
            if final.exists() or final.is_symlink():
                if aside.exists():
                    raise ArtifactError(f"{journal_path}: both {final} and {aside} exist while {tmp} is unpublished; "
                                        "inspect them and delete the journal by hand")
                _replace(final, aside)
            _replace(tmp, final)
        for folder in sorted({Path(m.final).parent for m in journal.moves}):
            fsync_dir(folder)
        _write(Path(journal.manifest_path), journal.manifest_text)
        journal = journal.model_copy(update={"committed": True})
        _write(journal_path, journal.model_dump_json(indent=1))
    for m in journal.moves:
        _remove(Path(m.aside))
    _remove(journal_path)


def _roll_back(journal_path: Path, journal: Journal) -> None:
    for m in reversed(journal.moves):
        tmp, final, aside = Path(m.tmp), Path(m.final), Path(m.aside)
        moved_in = not tmp.exists() and (final.exists() or final.is_symlink())
        if aside.exists() or aside.is_symlink():
            if moved_in:
                _remove(final)
            _replace(aside, final)
        elif not m.had_old and moved_in:
            _remove(final)
    # The journal goes before the temporary outputs: a half-deleted one must never be rolled forward.
    _remove(journal_path)
    for m in journal.moves:
        _remove(Path(m.tmp))


def _new_available(m: Move) -> bool:
    """Whether the new version of ``m`` still exists: unpublished in its temporary folder, or renamed in
    (then the old one, if any, sits aside, since asides are deleted only after the commit)."""
    final, aside = Path(m.final), Path(m.aside)
    if Path(m.tmp).exists():
        return True
    return (final.exists() or final.is_symlink()) and (not m.had_old or aside.exists() or aside.is_symlink())


# ----------------------------------------------------------------------------- recovery

def read_journal(journal_path: Path) -> Journal | None:
    journal_path = Path(journal_path)
    if not journal_path.is_file():
        return None
    try:
        return Journal.model_validate_json(journal_path.read_text(encoding="utf-8"))
    except ValueError as err:  # written atomically by us, so this is damage from outside
        raise ArtifactError(f"{journal_path}: not a readable publication journal ({err}); "
                            "restore the stage's outputs by hand or delete them with their manifest and rerun") from None


def recover(journal_path: Path, finals: list[Path], manifest_path: Path, *, prefer_rollback: bool = False) -> str:
    """Finish or undo a publication interrupted at any instant; delete this set's leftovers.

    ``finals``, ``manifest_path``: the set's output paths and manifest (their stray ``.<name>.old-*``
    and ``.<name>.tmp-*`` siblings are deleted). Call it holding the set's lock. Returns what was done: ``"rolled forward"``,
    ``"rolled back"``, ``"cleaned up"`` (a committed journal) or ``""`` (nothing pending).
    ``prefer_rollback``: undo even when the new set is complete (a live error inside publication).
    """
    journal_path = Path(journal_path)
    journal = read_journal(journal_path)
    done = ""
    if journal is not None:
        if journal.committed:
            _roll_forward(journal_path, journal)
            done = "cleaned up"
        elif not prefer_rollback and all(_new_available(m) for m in journal.moves):
            _roll_forward(journal_path, journal)
            done = "rolled forward"
        else:
            _roll_back(journal_path, journal)
            done = "rolled back"
    for path in [Path(f) for f in finals] + [journal_path, Path(manifest_path)]:
        if path.parent.is_dir():
            for stray in path.parent.glob(f".{path.name}.old-*"):
                _remove(stray)
            for stray in path.parent.glob(f".{path.name}.tmp-*"):
                _remove(stray)
    return done


# ----------------------------------------------------------------------------- readers of inputs

def check_inputs_unchanged(ws: Workspace, scene: str, stage: str, upstream: list[str],
                           expected: dict[str, str] | None = None) -> None:
    """Refuse to use inputs another run is republishing, or republished since ``expected`` was read.

    ``upstream``: the stages producing this stage's inputs; ``expected``: artifact name -> digest as
    read from their manifests when the stage started (``None``: only check nothing is in flight).
    Checked at start and again just before publishing: a publication of an input that overlapped the
    stage either is still in flight (its journal exists) or has changed that input's manifest.
    """
    for up in upstream:
        journal = ws.journal(scene, up)
        if journal.exists():
            raise StageError(
                f"scene {scene}: input stage {up} has a publication in flight ({journal}); stage {stage} "
                f"{'read its outputs meanwhile and is not published' if expected else 'cannot start'}. "
                f"Run again once that run ends (zipon run finishes or undoes a killed one)")
    if expected is None:
        return
    for up in upstream:
        man = Manifest.read(ws.manifest(scene, up))
        current = {name: rec.digest for name, rec in man.outputs.items()} if man else {}
        changed = sorted(name for name in expected if name in current and current[name] != expected[name])
        if man is None or changed:
            raise StageError(
                f"scene {scene}: input(s) {changed or f'of stage {up}'} changed while stage {stage} ran (another run "
                f"published stage {up}); its outputs are not published. Run again")
