"""Where the workbench may write an objects file: the one folder it declares, and the files the params name.

The page sends the objects file's path, so the path is client input. It is accepted only when, resolved (links
followed), it is

- a ``.yaml``, ``.yml`` or ``.json`` file inside :data:`OBJECTS_DIR` beside the params file, or
- exactly a file that the params name as a scene's objects file (``goals.objects_files``),

and in either case none of what the pipeline owns: the params file, ``dvc.yaml``, ``dvc.lock``, anything under
the data root (artifacts, stores, episodes), the manifests folder, the stored goal edits, or ``.dvc``/``.git``.
Everything else is refused with a 403 naming the path, the rule and the folder that is allowed.

Those are the workbench's only writes at a path the page names. Its other two writes have fixed places and their
own owners: a goals save is :func:`pipeline.goals.edits.save_goals_edit`'s transaction (the stored edit, the
rebuilt goals and routes, ``goals.edits`` in the params file, dvc.lock), and a played episode is appended to
``DATA/eval/human/<scene>.episodes.jsonl`` (:mod:`zipon.annotate.play`), the one file under the data root it writes.
"""

from __future__ import annotations

from pathlib import Path

from zipon.annotate.http import HTTPError

OBJECTS_DIR = "objects"  # beside the params file: where the workbench writes objects files
SUFFIXES = (".yaml", ".yml", ".json")
PIPELINE_FILES = ("dvc.yaml", "dvc.lock", ".dvcignore")
PIPELINE_DIRS = (".dvc", ".git")


class WritePolicy:
    """The objects files one workspace's workbench may write (see the module docstring)."""

    def __init__(self, workspace, named: dict[str, str]):
        from pipeline.goals.edits import EDITS_DIR

        self.root = workspace.root.resolve()
        self.folder = self.root / OBJECTS_DIR
        self.named = {(self.root / rel).resolve() for rel in named.values() if isinstance(rel, str) and rel}
        self.owned = [(workspace.params_path.resolve(), "the params file"),
                      *((self.root / name, "a DVC file") for name in PIPELINE_FILES)]
        self.owned_dirs = [(Path(workspace.data_dir).resolve(), "the data root (artifacts, stores, episodes)"),
                           (Path(workspace.manifests_dir).resolve(), "the manifests folder"),
                           (self.root / EDITS_DIR, "the stored goal edits"),
                           *((self.root / name, "a version-control folder") for name in PIPELINE_DIRS)]

    def objects_file(self, rel, field: str = "path") -> Path:
        """``rel`` (relative to the params file's folder) as the absolute path to write, or an :class:`HTTPError`."""
        if not isinstance(rel, str) or not rel or rel.startswith(("/", "\\")) or "\x00" in rel or len(rel) > 1024:
            raise HTTPError(400, f"{str(rel)[:80]!r} is not a relative path", field)
        try:
            path = (self.root / rel).resolve()
        except (OSError, RuntimeError, ValueError) as err:  # a link loop, a name the OS refuses
            raise HTTPError(400, f"{rel!r} cannot be resolved ({err})", field) from None
        if not path.is_relative_to(self.root):
            raise HTTPError(400, f"{rel!r} leaves the workspace {self.root}", field)
        if path.suffix.lower() not in SUFFIXES:
            raise HTTPError(400, f"{rel!r} is not a .yaml, .yml or .json file", field)
        for owned, what in self.owned:
            if path == owned:
                raise self._refused(rel, f"it is {what}", field)
        for folder, what in self.owned_dirs:
            if path.is_relative_to(folder):
                raise self._refused(rel, f"it is inside {what} ({folder})", field)
        if path.is_relative_to(self.folder) or path in self.named:
            if path.exists() and not path.is_file():
                raise HTTPError(400, f"{rel!r} exists and is not a file", field)
            return path
        raise self._refused(rel, "it is neither in the objects folder nor an objects file the params name", field)

    def _refused(self, rel: str, why: str, field: str) -> HTTPError:
        return HTTPError(403, f"the workbench does not write {rel!r}: {why}; objects files go in "
                              f"{OBJECTS_DIR}/ beside the params file (or a file goals.objects_files names)", field,
                         allowed=f"{OBJECTS_DIR}/")
