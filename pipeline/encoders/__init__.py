"""Open-vocabulary dense encoders: the interface and registry in :mod:`pipeline.encoders.base`,
one module per implementation (importing them fills :data:`ENCODERS`)."""

from pipeline.encoders.base import ENCODERS, DenseFeatures, Encoder, build_encoder, check_encoder, encoder_choice
from pipeline.encoders import conceptfusion, lseg, maskclip, oracle, perception, torchscript  # noqa: F401  (registration)

__all__ = ["ENCODERS", "DenseFeatures", "Encoder", "build_encoder", "check_encoder", "encoder_choice"]
