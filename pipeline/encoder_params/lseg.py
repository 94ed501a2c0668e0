"""Settings of the ``lseg`` encoder (:mod:`pipeline.encoders.lseg`), section ``encoders.lseg``: its
``params_model``, in the torch-free module named after the encoder's (the params schema imports it)."""

from __future__ import annotations

from pydantic import Field

from pipeline.section import CellSize, Section


class LSegParams(Section):
    """LSeg (DPT head on ViT-L/16, CLIP ViT-B/32 text space), loaded from the public LSeg checkpoint."""

    weights: str | None = Field(
        None,
        description="path to the LSeg checkpoint (e.g. demo_e200.ckpt: a pytorch-lightning ckpt whose state_dict "
        "keys start with 'net.', or a bare state dict); None = no weights, an error when lseg is chosen",
    )
    crop_size: int = Field(480, gt=0, multiple_of=32, description="sliding-window crop edge, pixels (VLMaps: 480)")
    base_size: int = Field(520, gt=0, description="the long image side is resized to this before cropping (VLMaps: 520)")
    stride_rate: float = Field(2.0 / 3.0, gt=0, le=1, description="window stride as a fraction of crop_size")
    out_size: CellSize = Field((120, 160), description="feature map (height, width) returned, cells")
