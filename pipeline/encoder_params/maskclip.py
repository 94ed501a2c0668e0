"""Settings of the ``maskclip`` encoder (:mod:`pipeline.encoders.maskclip`), section ``encoders.maskclip``: its
``params_model``, in the torch-free module named after the encoder's (the params schema imports it)."""

from __future__ import annotations

from pydantic import Field

from pipeline.section import CellSize, Section


class MaskClipParams(Section):
    """MaskCLIP dense features from an open_clip ViT (value embeddings of the last block, no query-key attention)."""

    arch: str = Field(
        "ViT-B-32",
        description="open_clip model name (a ViT); OpenAI-trained weights need the '-quickgelu' variant "
        "(e.g. ViT-B-32-quickgelu): the state dict is the same, the activation is not",
    )
    weights: str | None = Field(
        None, description="local open_clip weights file (.pt/.bin/.safetensors); None = error when maskclip is chosen"
    )
    input_size: CellSize = Field(
        (480, 640), description="(height, width) the image is resized to before the ViT; multiples of the patch size"
    )
    out_size: CellSize | None = Field(None, description="feature (height, width); None = the patch grid")
