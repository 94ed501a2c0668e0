"""``zipon verify``: re-hash artifacts and compare them with their manifests."""

from __future__ import annotations

from dataclasses import dataclass

from pipeline.config import Params
from pipeline.manifest import Manifest
from pipeline.paths import Workspace
from pipeline.runner import StageSpec, plan
from pipeline.store import content_digest


@dataclass
class VerifyRow:
    scene: str
    stage: str
    artifact: str
    ok: bool
    problem: str = ""


def verify_all(ws: Workspace, params: Params, stages: dict[str, StageSpec]) -> list[VerifyRow]:
    """One row per artifact recorded in a manifest; stages never run are not listed."""
    rows = []
    for scene, stage in plan(stages, params, list(params.scenes)):
        man = Manifest.read(ws.manifest(scene, stage))
        if man is None:
            continue
        for name in stages[stage].outputs:
            rec = man.outputs.get(name)
            path = ws.artifact(name, scene)
            if rec is None:
                rows.append(VerifyRow(scene, stage, name, False, "not recorded in the manifest"))
            elif not path.exists():
                rows.append(VerifyRow(scene, stage, name, False, f"missing: {path}"))
            else:
                got = content_digest(path)
                ok = got == rec.digest
                rows.append(VerifyRow(scene, stage, name, ok, "" if ok else f"digest {got} != manifest {rec.digest}"))
    return rows
