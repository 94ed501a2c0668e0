"""``zipon verify``: re-hash every artifact on disk and compare it with its manifest.

Every artifact gets a row, whatever state it is in: one whose content matches, one that differs,
one that cannot be read at all (a corrupt chunk or ``zarr.json``), one recorded but missing, one on
disk without a manifest, and the artifacts of scenes that are on disk but no longer in the params
file. Reading one artifact never stops the others from being checked.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zarr

from pipeline.config import Params
from pipeline.errors import ZiponError
from pipeline.engine.manifest import Manifest
from pipeline.paths import ARTIFACTS, MANIFEST, Workspace
from pipeline.engine.stagegraph import StageSpec, plan, stage_order
from pipeline.store import content_digest


@dataclass
class VerifyRow:
    scene: str
    stage: str
    artifact: str
    ok: bool
    problem: str = ""
    note: str = ""  # e.g. "scene not in params.yaml": said, but not a failure by itself


def verify_stage(ws: Workspace, spec: StageSpec, scene: str) -> list[VerifyRow]:
    """Rows for the outputs of one (scene, stage); none when the stage never ran and left nothing."""
    present = [name for name in spec.outputs if _exists(ws.artifact(name, scene))]
    try:
        man = Manifest.read(ws.manifest(scene, spec.name))
    except (ZiponError, OSError, UnicodeDecodeError) as err:
        problem = f"manifest unreadable: {err}"
        return [VerifyRow(scene, spec.name, name, False, problem) for name in (present or spec.outputs)]
    if man is None:
        return [VerifyRow(scene, spec.name, name, False,
                          f"no manifest ({ws.manifest(scene, spec.name)}): {ws.artifact(name, scene)} cannot be "
                          f"verified; rebuild it with `zipon run -s {scene} --stage {spec.name} --force`")
                for name in present]
    rows = []
    for name in spec.outputs:
        rec = man.outputs.get(name)
        path = ws.artifact(name, scene)
        if rec is None:
            rows.append(VerifyRow(scene, spec.name, name, False, "not recorded in the manifest"))
        elif not _exists(path):
            rows.append(VerifyRow(scene, spec.name, name, False, f"missing: {path}"))
        else:
            try:
                got = content_digest(path)
            except Exception as err:  # noqa: BLE001 - any read failure is the finding: the artifact is corrupt
                where = locate_corruption(path) or f"{path}: {_one_line(err)}"
                rows.append(VerifyRow(scene, spec.name, name, False, f"unreadable: {where}"))
                continue
            ok = got == rec.digest
            problem = "" if ok else f"digest {got} != manifest {rec.digest}"
            algo, recorded_algo = got.split(":", 1)[0], rec.digest.split(":", 1)[0]
            if not ok and algo != recorded_algo:
                problem += (f" (recorded by an older zipon, as {recorded_algo!r}; rebuild it with "
                            f"`zipon run -s {scene} --stage {spec.name} --force` to record it as {algo!r})")
            rows.append(VerifyRow(scene, spec.name, name, ok, problem))
    return rows


def locate_corruption(path: Path) -> str | None:
    """The first unreadable part of a zarr store (a ``zarr.json`` that is not JSON, a chunk that does not
    decode), named by its file; ``None`` when every part reads (or ``path`` is not a zarr store)."""
    path = Path(path)
    if not path.is_dir():
        return None
    for meta in sorted(path.rglob("zarr.json")):
        try:
            json.loads(meta.read_bytes())
        except (ValueError, UnicodeDecodeError) as err:
            return f"{meta} is not valid JSON ({_one_line(err)})"
    try:
        root = zarr.open_group(zarr.storage.LocalStore(str(path), read_only=True), mode="r")
        members = sorted(root.members(max_depth=None), key=lambda kv: kv[0])
    except Exception as err:  # noqa: BLE001 - reported, not raised: the store's metadata is invalid
        return f"{path / 'zarr.json'} is not valid zarr metadata ({_one_line(err)})"
    for name, node in members:
        if not isinstance(node, zarr.Array) or node.ndim == 0:
            continue
        for idx in np.ndindex(*node.cdata_shape):
            try:
                node.blocks[idx]
            except Exception as err:  # noqa: BLE001 - the chunk that fails is the finding
                chunk = path / name / node.metadata.encode_chunk_key(idx)
                return f"chunk {chunk} of array {name!r} does not decode ({_one_line(err)})"
    return None


def content_staleness(ws: Workspace, spec: StageSpec, scene: str) -> str:
    """Why the outputs of a built stage do not hold what its manifest says ('' when they do).

    For ``zipon status --verify``: staleness compares digests recorded in manifests; this re-hashes.
    """
    bad = [r for r in verify_stage(ws, spec, scene) if not r.ok]
    return "; ".join(f"{r.artifact} {r.problem}" for r in bad)


def scenes_on_disk(ws: Workspace) -> list[str]:
    """Scenes that have an artifact or a manifest on disk (found through the path templates)."""
    found: set[str] = set()
    for root, templates in ((ws.data_dir, ARTIFACTS.values()), (ws.manifests_dir, [MANIFEST])):
        for template in templates:
            pattern = _template_regex(template)
            for path in root.glob(template.format(scene="*", stage="*")):
                m = pattern.fullmatch(path.relative_to(root).as_posix())
                if m and not m["scene"].startswith("."):
                    found.add(m["scene"])
    return sorted(found)


def verify_all(ws: Workspace, params: Params, stages: dict[str, StageSpec]) -> list[VerifyRow]:
    """One row per artifact on disk or recorded in a manifest, for the scenes in params and on disk.

    A raw log of a scene not in params that no stage recorded (``zipon simulate`` writes them, users copy
    theirs there) is an input, not an artifact: it gets no row.
    """
    rows = []
    for scene, stage in plan(stages, params, list(params.scenes)):
        rows += verify_stage(ws, stages[stage], scene)
    for scene in (s for s in scenes_on_disk(ws) if s not in params.scenes):
        for stage in stage_order(stages):
            if not stages[stage].inputs and not ws.manifest(scene, stage).exists():
                continue  # a raw log nobody recorded
            for row in verify_stage(ws, stages[stage], scene):
                row.note = f"scene not in {ws.params_path.name}"
                rows.append(row)
    return rows


def _exists(path: Path) -> bool:
    return path.exists() or path.is_symlink()


def _template_regex(template: str) -> re.Pattern:
    parts = re.split(r"(\{scene\}|\{stage\})", template)
    return re.compile("".join("(?P<scene>[^/]+)" if p == "{scene}" else "[^/]+" if p == "{stage}" else re.escape(p)
                              for p in parts))


def _one_line(err: Exception) -> str:
    text = " ".join(str(err).split())
    return f"{type(err).__name__}: {text[:300]}"
