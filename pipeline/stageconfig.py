"""A stage's typed config (:class:`StageConfig`) and the digests of what it covers: the params keys it is built
from (:func:`project`), digested as canonical JSON (:func:`digest_value`)."""

from __future__ import annotations

import hashlib
import json
from typing import Any

from pydantic import BaseModel

from pipeline.config import Params
from pipeline.section import Section


def canonical_json(value: Any) -> str:
    """The JSON text digests are computed on: sorted keys, no whitespace, finite floats."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)


def digest_value(value: Any) -> str:
    """Deterministic digest of plain data (params sections, attrs)."""
    return "blake2b:" + hashlib.blake2b(canonical_json(value).encode(), digest_size=16).hexdigest()



def param_value(params: Params, key: str) -> Any:
    """The plain (JSON) value of a dotted params key (a leaf or a whole section)."""
    obj: Any = params
    for part in key.split("."):
        obj = obj[part] if isinstance(obj, dict) else getattr(obj, part)
    return obj.model_dump(mode="json") if isinstance(obj, BaseModel) else json.loads(json.dumps(obj))


def project(params: Params, keys: list[str] | tuple[str, ...]) -> dict[str, Any]:
    """``{dotted key: value}`` of exactly ``keys`` (sorted): what a stage's params digest covers."""
    return {key: param_value(params, key) for key in sorted(set(keys))}


def section_keys(section: str, model: type[BaseModel], exclude: tuple[str, ...] = ()) -> list[str]:
    """``section.field`` for every field of a section model except ``exclude``."""
    return [f"{section}.{name}" for name in model.model_fields if name not in exclude]


class StageConfig(Section):
    """A stage's typed config, built from params: the stage receives only this (``ctx.config``).

    Each stage module (``stages/<name>.py``) defines ``Config(StageConfig)``. :meth:`param_keys` names the
    params keys it is built from; the stage's params digest covers exactly their values (recorded in the
    manifest, compared key by key by ``zipon status``, and listed as ``params`` in ``dvc.yaml``). A test
    perturbs every other key of the params and checks the config does not change.

    The defaults serve a config whose fields are whole params sections, named as in ``params.yaml``
    (``reconstruct: ReconstructParams``); a config that reads parts of sections or per-scene entries
    overrides both.
    """

    @classmethod
    def param_keys(cls, params: Params, scene: str) -> list[str]:
        unknown = [name for name in cls.model_fields if name not in Params.model_fields]
        if unknown:
            raise TypeError(f"{cls.__qualname__}: fields {unknown} are not params sections; override param_keys "
                            "and from_params")
        return list(cls.model_fields)

    @classmethod
    def from_params(cls, params: Params, scene: str) -> "StageConfig":
        return cls(**{name: getattr(params, name) for name in cls.param_keys(params, scene)})

    @classmethod
    def extra_inputs(cls, params: Params, scene: str) -> dict[str, str]:
        """Files named by params that the stage reads (input name -> path relative to the params file); their
        content digests are the stage's inputs beside its artifacts."""
        return {}
