"""Params files: reading ``params.yaml`` (libyaml, bounded: :mod:`pipeline.userfiles`), ``-S KEY=VALUE``
overrides, keys that moved (an error naming their new home), validation against the schema (:mod:`pipeline.config`)
with errors naming the key, and writing a complete, commented ``params.yaml``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

from pipeline.config import Params, QueryParams, TaskParams
from pipeline.errors import ConfigError, InputDataError, shown
from pipeline.userfiles import parse_yaml, read_user_text


def _apply_override(raw: dict, assignment: str) -> None:
    if "=" not in assignment:
        raise ConfigError(f"override {assignment!r}: expected KEY=VALUE, e.g. simulate.frames=100")
    key, value = assignment.split("=", 1)
    parts = key.strip().split(".")
    node = raw
    for part in parts[:-1]:
        node = node.setdefault(part, {})
        if not isinstance(node, dict):
            raise ConfigError(f"override {assignment!r}: {part!r} is not a section")
    try:
        node[parts[-1]] = parse_yaml(value, origin=f"override {key.strip()}")
    except InputDataError as err:
        raise ConfigError(str(err)) from None


def _format_errors(err: ValidationError, origin: str) -> str:
    lines = []
    for e in err.errors():
        loc = ".".join(shown(p) for p in e["loc"]) or "(top level)"
        lines.append(f"{origin}: {loc}: {e['msg'].removeprefix('Value error, ')}")
    return "\n".join(lines)


# Keys that moved: old -> new. Why, per new section (_MOVED_WHY).
MOVED_KEYS: dict[str, str] = {
    "maps.device": "run.fusion_device",
    "encoders.device": "run.device",
    "encoders.batch_size": "run.encoder_batch_size",
    "encoders.threads": "run.torch_threads",
    **{f"maps.{name}": f"query.{name}" for name in QueryParams.model_fields},
    **{f"routes.{name}": f"task.{name}" for name in TaskParams.model_fields},
    "eval.success_distance_m": "task.success_m",
    "eval.hfov_deg": "task.hfov_deg",
    "eval.clearance_m": "task.clearance_m",
    "eval.stop_radius_m": "eval.goto_stop_radius_m",
}
_MOVED_WHY = {
    "run": "settings that cannot change an artifact live outside the hashed sections",
    "query": "settings that cannot change an artifact live outside the hashed sections",
    "task": "the task's facts have one home, read by the goals and routes stages and the evaluator",
    "eval": "the agents' own stop radius; task.stop_radius_m is where walks to a ground-truth goal aim",
}


def _moved_keys(raw: dict, origin: str) -> None:
    found = [(old, new) for old, new in MOVED_KEYS.items()
             if isinstance(raw.get(old.split(".")[0]), dict) and old.split(".")[1] in raw[old.split(".")[0]]]
    if found:
        raise ConfigError("\n".join(f"{origin}: {old}: moved to {new} ({_MOVED_WHY[new.split('.')[0]]})"
                                     for old, new in found))


def parse_params(raw: dict, *, origin: str = "params", overrides: list[str] | tuple[str, ...] = ()) -> Params:
    """Validate a params mapping (after ``KEY=VALUE`` overrides); raises :class:`ConfigError`."""
    try:
        raw = json.loads(json.dumps(raw or {}, allow_nan=True))  # deep copy of plain data
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{origin}: not plain data: {err}") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{origin}: expected a mapping of sections at the top level")
    for assignment in overrides:
        _apply_override(raw, assignment)
    _moved_keys(raw, origin)
    try:
        params = Params.model_validate(raw)
    except ValidationError as err:
        raise ConfigError(_format_errors(err, origin)) from None
    from pipeline.paramchecks import check_params

    check_params(params, origin)  # what several keys must agree on (voxel vs cell, memory, bounds)
    return params


def load_params(path: str | Path, overrides: list[str] | tuple[str, ...] = ()) -> Params:
    """Read and validate ``params.yaml`` (bounded: :mod:`pipeline.userfiles`)."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"{path}: params file not found (run zipon from the project folder or pass --params)")
    try:
        raw = parse_yaml(read_user_text(path, what="params YAML"), origin=path) or {}
    except InputDataError as err:
        raise ConfigError(str(err)) from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: expected a mapping of sections at the top level")
    return parse_params(raw, origin=str(path), overrides=overrides)


def params_yaml(params: Params) -> str:
    """``params.yaml`` text for ``params``: every tunable, each preceded by its description as a comment."""
    lines = ["# zipon params: every tunable, one section per stage (types and checks: pipeline/config.py).",
             "# Regenerate a complete file with: zipon params --defaults"]

    def emit(model: BaseModel, indent: int) -> None:
        pad = "  " * indent
        for name, info in type(model).model_fields.items():
            value = getattr(model, name)
            if info.description:
                lines.append(f"{pad}# {info.description}")
            if isinstance(value, BaseModel):
                lines.append(f"{pad}{name}:")
                emit(value, indent + 1)
            elif isinstance(value, dict) and value and all(isinstance(v, BaseModel) for v in value.values()):
                lines.append(f"{pad}{name}:")
                for key, sub in value.items():
                    flow = yaml.safe_dump(sub.model_dump(mode="json"), default_flow_style=True, width=1000).strip()
                    lines.append(f"{pad}  {key}: {flow}")
            else:
                dumped = yaml.safe_dump({name: _plain_value(value)}, default_flow_style=True, width=1000).strip()
                lines.append(f"{pad}{dumped[1:-1] if dumped.startswith('{') else dumped}")

    for name, info in Params.model_fields.items():
        value = getattr(params, name)
        lines.append("")
        if info.description or type(value).__doc__:
            doc = info.description if name == "scenes" else (type(value).__doc__ or "").strip().splitlines()[0]
            lines.append(f"# {doc}")
        if isinstance(value, BaseModel):
            lines.append(f"{name}:")
            emit(value, 1)
        else:
            lines.append(f"{name}:")
            for key, sub in value.items():
                flow = yaml.safe_dump(sub.model_dump(mode="json"), default_flow_style=True, width=1000).strip()
                lines.append(f"  {key}: {flow}")
    return "\n".join(lines) + "\n"


def _plain_value(value: Any) -> Any:
    return value.model_dump(mode="json") if isinstance(value, BaseModel) else value
