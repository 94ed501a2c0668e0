"""The stage graph: what a stage is (:class:`StageSpec`), which stages a scene runs in which order, and what
makes a stage stale.

A stage is stale when its manifest is missing, an output is missing, a file of its code changed (the import
closure of its module, :mod:`pipeline.engine.codedeps`), a params key of its config changed, or an input's digest
changed; :func:`staleness` names which. :func:`plan` lists the (scene, stage) pairs to consider,
:func:`stage_order` and :func:`stage_levels` order them; :mod:`pipeline.engine.runner` runs them.
"""

from __future__ import annotations

import importlib
import importlib.util
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from pipeline.engine import codedeps
from pipeline.config import Params
from pipeline.stageconfig import StageConfig, canonical_json, digest_value, project
from pipeline.errors import MissingInputError, ZiponError
from pipeline.engine.manifest import Manifest
from pipeline.paths import Workspace

SOURCE = "source"  # the pseudo-input naming a scene's raw data (a log, a folder)


@dataclass(frozen=True)
class StageSpec:
    """One stage of the DAG, declared once in :mod:`stages` (dvc.yaml is checked against it)."""

    name: str
    entry: str  # "module:function"; the module also defines the stage's Config (see config_class)
    inputs: tuple[str, ...]  # artifact names, or SOURCE for the scene's raw data
    outputs: tuple[str, ...]  # artifact names (see pipeline.paths.ARTIFACTS)
    simulated_only: bool = False
    description: str = ""
    config: str = ""  # "module:Class" of the stage's StageConfig; default: "<entry module>:Config"
    # one long native loop whose output does not depend on its thread count: it may take the native threads of the
    # workers that fewer scenes than workers leave idle (runner.stage_threads)
    spreads_threads: bool = False

    @property
    def module(self) -> str:
        return self.entry.split(":")[0]

    def load(self) -> Callable[..., dict]:
        """The stage function, ``run(ctx: pipeline.engine.runner.StageContext) -> summary``."""
        module, func = self.entry.split(":")
        return getattr(importlib.import_module(module), func)

    def config_class(self) -> type[StageConfig]:
        module, cls = (self.config or f"{self.module}:Config").split(":")
        return getattr(importlib.import_module(module), cls)

    def build_config(self, params: Params, scene: str) -> tuple[StageConfig, dict[str, Any]]:
        """(the typed config, its params projection ``{key: value}``) for ``scene``."""
        cls = self.config_class()
        return cls.from_params(params, scene), project(params, cls.param_keys(params, scene))

    def applies_to(self, params: Params, scene: str) -> bool:
        return params.scenes[scene].simulated or not self.simulated_only


def stage_code_digest(spec: StageSpec) -> str:
    """Digest of the source of every project module the stage's module imports (transitively)."""
    return codedeps.code_digest(spec.module)


def source_paths(ws: Workspace, params: Params, scene: str) -> list[Path]:
    """The raw data of a scene in reading order: the simulated log, or the configured paths (relative to
    params.yaml; ``scenes.<scene>.source`` or ``.sources``)."""
    src = params.scenes[scene]
    if src.simulated:
        return [ws.artifact("raw_log", scene)]
    return [path if path.is_absolute() else (ws.root / path) for path in map(Path, src.paths)]


def source_key(i: int) -> str:
    """The input name of a scene's ``i``-th raw source (0-based): ``source``, ``source_2``, ``source_3``, ..."""
    return SOURCE if i == 0 else f"{SOURCE}_{i + 1}"


def scene_sources(inputs: dict[str, Path]) -> list[Path]:
    """The raw sources among a stage's inputs (``source``, ``source_2``, ...), in reading order."""
    return [inputs[source_key(i)] for i in range(len(inputs)) if source_key(i) in inputs]


def producer(stages: dict[str, StageSpec], artifact: str) -> StageSpec:
    for spec in stages.values():
        if artifact in spec.outputs:
            return spec
    raise KeyError(f"no stage produces artifact {artifact!r}")


def files_digest(paths: list[Path]) -> str:
    """:func:`pipeline.store.files_digest`, imported when a raw file or a config's file is hashed: the stage graph of
    a simulated scene (``zipon status``) then loads neither numpy nor the artifact stores."""
    from pipeline.store import files_digest as digest

    return digest(paths)


def input_digests(ws: Workspace, params: Params, stages: dict[str, StageSpec], spec: StageSpec, scene: str,
                  ) -> dict[str, str]:
    """Current digests of a stage's inputs: upstream outputs (from their manifests), raw data and the files
    its config names (hashed)."""
    out = {}
    for name in spec.inputs:
        if name == SOURCE and not params.scenes[scene].simulated:
            paths = source_paths(ws, params, scene)
            key = "sources" if params.scenes[scene].sources is not None else "source"
            for path in paths:
                if not path.exists():
                    raise MissingInputError(f"{path}: raw data of scene {scene!r} not found "
                                            f"(params.yaml scenes.{scene}.{key})")
            out[name] = files_digest(paths)  # every log's bytes, in order: appending a log is a new input
            continue
        artifact = "raw_log" if name == SOURCE else name
        up = producer(stages, artifact)
        man = Manifest.read(ws.manifest(scene, up.name))
        if man is None or artifact not in man.outputs:
            raise MissingInputError(f"scene {scene}: input {artifact!r} of stage {spec.name} is missing; run stage {up.name} first")
        out[name] = man.outputs[artifact].digest
    for name, rel in spec.config_class().extra_inputs(params, scene).items():
        path = ws.root / rel
        if not path.exists():
            raise MissingInputError(f"{path}: {name} of scene {scene!r} not found")
        out[name] = files_digest([path])
    return out


def _short(value: Any) -> str:
    text = canonical_json(value) if not isinstance(value, str) else value
    return text if len(text) <= 40 else text[:37] + "..."


def params_changes(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """``key old -> new`` for every params key whose value differs (added/removed keys included)."""
    missing = object()
    out = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key, missing), new.get(key, missing)
        if a == b:
            continue
        if isinstance(a, dict) and isinstance(b, dict):  # a whole section: name its leaves
            out += [f"{key}.{change}" for change in params_changes(a, b)]
        else:
            out.append(f"{key} {'(none)' if a is missing else _short(a)} -> {'(none)' if b is missing else _short(b)}")
    return out


def staleness(ws: Workspace, params: Params, stages: dict[str, StageSpec], spec: StageSpec, scene: str,
              current: dict[str, str] | None = None) -> str:
    """Why the stage must run ('' when its outputs are up to date), naming what changed: the code files,
    the params keys (``params: maps.level_height_m 0.1 -> 0.2``) or the inputs.

    ``current``: the input digests when the caller already has them (raw logs are hashed once per run).
    """
    if ws.journal(scene, spec.name).exists():
        return "publication interrupted (the next run finishes or undoes it)"
    man = Manifest.read(ws.manifest(scene, spec.name))
    if man is None:
        return "never run"
    for name in spec.outputs:
        if not ws.artifact(name, scene).exists():
            return f"output {name} missing"
    reasons = []
    if man.code_digest != stage_code_digest(spec):
        files = codedeps.changed_files(man.code_files, codedeps.file_digests(spec.module))
        reasons.append("code changed" + (f": {', '.join(files)}" if files and man.code_files else ""))
    _, projection = spec.build_config(params, scene)
    if man.params_digest != digest_value(projection):
        changes = params_changes(man.params, projection)
        reasons.append("params: " + "; ".join(changes) if changes else "params changed")
    if current is None:
        try:
            current = input_digests(ws, params, stages, spec, scene)
        except MissingInputError:
            reasons.append("input missing")
            current = man.inputs
    if current != man.inputs:
        changed = sorted(k for k in set(current) | set(man.inputs) if current.get(k) != man.inputs.get(k))
        reasons.append(f"input changed: {', '.join(changed)}")
    return " | ".join(reasons)


def stale_stages(ws: Workspace, params: Params, stages: dict[str, StageSpec], pairs: list[tuple[str, str]]
                 ) -> dict[str, str]:
    """``{"scene/stage": why}`` for each of the (scene, stage) ``pairs`` whose outputs are not up to date
    (:func:`staleness`, the rule ``zipon run`` and ``zipon status`` follow); up-to-date pairs are left out."""
    return {f"{scene}/{stage}": why for scene, stage in pairs
            if (why := staleness(ws, params, stages, stages[stage], scene))}


def producers_of(stages: dict[str, StageSpec], name: str) -> set[str]:
    """The stages whose outputs stage ``name`` reads in the stage graph (a raw log's ``SOURCE`` counts as the
    raw log's producer, as for a simulated scene; :func:`upstream_stages` is the per-scene answer)."""
    return {producer(stages, "raw_log" if i == SOURCE else i).name for i in stages[name].inputs}


def stage_order(stages: dict[str, StageSpec]) -> list[str]:
    """Stages in dependency order (stable: registry order breaks ties)."""
    order: list[str] = []
    pending = list(stages)
    while pending:
        for name in pending:
            if producers_of(stages, name) <= set(order):
                order.append(name)
                pending.remove(name)
                break
        else:
            raise ZiponError(f"stage graph has a cycle among {pending}")
    return order


def upstream_stages(stages: dict[str, StageSpec], params: Params, scene: str, stage: str) -> list[str]:
    """Stages whose outputs this (scene, stage) reads; a recorded log's SOURCE has no producer."""
    ups = []
    for i in stages[stage].inputs:
        if i != SOURCE:
            ups.append(producer(stages, i).name)
        elif params.scenes[scene].simulated:
            ups.append(producer(stages, "raw_log").name)
    return ups


def stage_levels(stages: dict[str, StageSpec]) -> dict[str, int]:
    """Each stage's level: the number of stages on the longest path from it to a stage nothing reads (0).

    ``run_many`` gives a stage task its level as dask priority (highest first, the classic list-scheduling rule):
    the long chains every scene must go through one after the other (ingest, reconstruct) run before the stages
    whose work spreads over every worker (the maps' chunks), so the last scene's chain does not leave a worker
    idle at the end of a batch."""
    level: dict[str, int] = {}
    for name in reversed(stage_order(stages)):
        level[name] = 1 + max((level[r] for r in stages if name in producers_of(stages, r)), default=-1)
    return level


def plan(stages: dict[str, StageSpec], params: Params, scenes: list[str], only: list[str] | None = None
         ) -> list[tuple[str, str]]:
    """(scene, stage) pairs to consider, in an order that respects dependencies."""
    wanted = set(only) if only else None
    pairs = []
    for scene in scenes:
        for stage in stage_order(stages):
            if stages[stage].applies_to(params, scene) and (wanted is None or stage in wanted):
                pairs.append((scene, stage))
    return pairs
