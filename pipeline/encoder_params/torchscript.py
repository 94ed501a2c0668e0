"""Settings of the ``torchscript`` encoder (:mod:`pipeline.encoders.torchscript`), section ``encoders.torchscript``:
its ``params_model``, in the torch-free module named after the encoder's (the params schema imports it)."""

from __future__ import annotations

from pydantic import Field, model_validator

from pipeline.section import CellSize, Section


class TorchScriptParams(Section):
    """Any user-exported dense encoder: two TorchScript files, or a python factory 'pkg.mod:factory'."""

    image_file: str | None = Field(
        None, description="TorchScript module: float (B,3,H,W) RGB in [0,1] -> (B,D,h,w) features"
    )
    text_file: str | None = Field(None, description="TorchScript module: list[str] -> (T,D) features")
    factory: str | None = Field(
        None,
        description="'pkg.mod:factory' returning an object with encode_image(x (B,3,H,W) [0,1]) -> (B,D,h,w) and "
        "encode_text(list[str]) -> (T,D); used instead of the two files",
    )
    input_size: CellSize | None = Field(None, description="resize images to (height, width) first; None = as is")
    name: str = Field("torchscript", description="encoder name recorded in the maps' attrs")
    version: str = Field("1", description="encoder version recorded in the maps' attrs")

    @model_validator(mode="after")
    def _one_source(self) -> "TorchScriptParams":
        if self.factory is not None and (self.image_file or self.text_file):
            raise ValueError("give either factory or image_file + text_file, not both")
        return self
