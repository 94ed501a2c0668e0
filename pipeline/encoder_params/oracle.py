"""Settings of the ``oracle`` encoder (:mod:`pipeline.encoders.oracle`), section ``encoders.oracle``: its
``params_model``, in the torch-free module named after the encoder's (the params schema imports it)."""

from __future__ import annotations

from pydantic import Field

from pipeline.section import CellSize, Section


class OracleParams(Section):
    """DIAGNOSTIC encoder for simulated scenes: features from ground-truth instance classes, never a model."""

    dim: int = Field(512, gt=1, description="feature dimension")
    seed: int = Field(0, description="seed of the per-word random unit vectors and of the confusion/noise draws")
    color_weight: float = Field(0.5, ge=0, description="weight of colour words against the class word (1)")
    material_weight: float = Field(0.3, ge=0, description="weight of material words against the class word (1)")
    confusion: float = Field(0.0, ge=0, le=1, description="probability an instance takes another class's word")
    noise_std: float = Field(
        0.0, ge=0, description="per-component std of gaussian noise added to each cell before renormalising "
        "(noise norm ~ noise_std * sqrt(dim))"
    )
    out_size: CellSize = Field((120, 160), description="feature (height, width), cells")
