"""Open-vocabulary dense encoders: the interface and registry in :mod:`pipeline.encoders.base`,
one module per implementation (declared by name in :data:`pipeline.plugins.BUILT_IN_ENCODERS`), building one in
:mod:`pipeline.encoders.build`.

Nothing heavy is imported with the package: :mod:`pipeline.encoders.choice` (which encoder a stage
uses) needs no torch, and each implementation is imported when its name is first built
(:func:`pipeline.encoders.choice.load`); ``ENCODERS`` read from here holds every implementation.
"""

from __future__ import annotations

from typing import Any

__all__ = ["ENCODERS", "DenseFeatures", "Encoder", "build_encoder", "check_encoder", "encoder_choice"]


def __getattr__(name: str) -> Any:  # PEP 562: the names above, imported on first use
    if name == "ENCODERS":
        from pipeline.encoders import base
        from pipeline.encoders.choice import load

        load()
        return base.ENCODERS
    if name == "encoder_choice":
        from pipeline.encoders.choice import encoder_choice

        return encoder_choice
    if name in ("build_encoder", "check_encoder"):
        from pipeline.encoders import build

        return getattr(build, name)
    if name in __all__:
        from pipeline.encoders import base

        return getattr(base, name)
    raise AttributeError(f"module 'pipeline.encoders' has no attribute {name!r}")
