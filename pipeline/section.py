"""The base of every params model (:class:`Section`): unknown keys are errors, values are immutable, scalars are
strict. A leaf module: the params schema (:mod:`pipeline.config`), the simulated perception's settings
(:mod:`pipeline.perception_params`) and plug-ins' own settings all derive from it."""

from __future__ import annotations

from types import UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

from pydantic import BaseModel, ConfigDict, ValidationInfo, field_validator


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
