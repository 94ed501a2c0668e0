"""The base of every params model (:class:`Section`): unknown keys are errors, values are immutable, scalars are
strict. A leaf module: the params schema (:mod:`pipeline.config` and the per-area modules it imports: each built-in
encoder's settings in ``pipeline/encoder_params/<name>.py``) and plug-ins' own settings all derive from it;
:class:`DepthRange` is the base of the sections that read depth images, ``CellSize`` a feature map's (height, width)."""

from __future__ import annotations

from types import UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator


def _scalar_types(annotation: Any) -> set[type]:
    """The plain types a field annotation admits (through Optional, unions, Annotated, Literal)."""
    origin = get_origin(annotation)
    if origin is Annotated:
        return _scalar_types(get_args(annotation)[0])
    if origin is Literal:
        return {type(a) for a in get_args(annotation)}
    if origin in (Union, UnionType):
        return set().union(*(_scalar_types(a) for a in get_args(annotation)))
    return {origin or annotation} if isinstance(origin or annotation, type) else {object}


class Section(BaseModel):
    """Base of every params section: unknown keys are errors, values are immutable, types are strict:
    ``true`` is not an integer, ``"3"`` is not a number, NaN and infinity are not numbers."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _strict_scalars(cls, value: Any, info: ValidationInfo) -> Any:
        if not isinstance(value, (bool, str)):
            return value
        admits = _scalar_types(cls.model_fields[info.field_name].annotation)
        if object in admits or type(value) in admits:
            return value
        if isinstance(value, bool) and admits & {int, float}:
            raise ValueError(f"expected a number, got {str(value).lower()} (a boolean)")
        if isinstance(value, str) and admits <= {int, float, type(None)}:
            raise ValueError(f"expected a number, got the string {value!r}")
        return value


class DepthRange(Section):
    """Base of the sections that read depth images (simulate, ingest, reconstruct, maps): the valid depth band
    ``[depth_min_m, depth_max_m]``, metres, checked once here. Each section keeps its own keys (and may change
    their defaults and descriptions); what falls outside the band is that stage's business (stored as 0,
    ignored, not fused)."""

    depth_min_m: float = Field(0.1, ge=0, description="nearest valid depth, metres")
    depth_max_m: float = Field(10.0, gt=0, description="farthest valid depth, metres")

    @model_validator(mode="after")
    def _depth_range(self) -> "DepthRange":
        if self.depth_min_m >= self.depth_max_m:
            raise ValueError(f"depth_min_m ({self.depth_min_m:g}) must be below depth_max_m ({self.depth_max_m:g})")
        return self


CellSize = tuple[Annotated[int, Field(gt=0)], Annotated[int, Field(gt=0)]]  # (height, width)
