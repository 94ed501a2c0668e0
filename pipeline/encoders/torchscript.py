"""``torchscript``: any user-exported dense encoder we do not ship.

Either two TorchScript files (``torch.jit.save``):

- ``image_file``: ``forward(x: Tensor) -> Tensor``, ``x`` float32 ``(B,3,H,W)`` RGB in [0,1]
  (the module does its own normalisation), returns ``(B,D,h,w)`` features covering the whole image;
- ``text_file``: ``forward(texts: List[str]) -> Tensor`` ``(T,D)``;

or ``factory = 'pkg.mod:callable'`` returning an object with ``encode_image(x) -> (B,D,h,w)`` and
``encode_text(list[str]) -> (T,D)`` under the same conventions (optional attribute
``temperature``). Outputs are L2-normalised here; a cell whose feature is all zeros, or not
finite, is marked invalid. The identity records digests of both files (or the factory path).
"""

from __future__ import annotations

import importlib
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import torch.nn.functional as F

from pipeline.encoder_params.torchscript import TorchScriptParams
from pipeline.encoders.base import DenseFeatures, Encoder, file_digest, l2_normalize, require_file, to_tensor01
from pipeline.errors import ConfigError, StageError

if TYPE_CHECKING:
    from pipeline.config import EncodersParams


def _load_script(path: Path, param: str) -> torch.jit.ScriptModule:
    try:
        with warnings.catch_warnings():  # torch 2.14 deprecates TorchScript; user exports still load
            warnings.simplefilter("ignore", FutureWarning)
            return torch.jit.load(str(path), map_location="cpu").eval()
    except Exception as err:  # noqa: BLE001 - any load failure means not a usable TorchScript module
        raise ConfigError(f"{param}: {path} is not a TorchScript module ({str(err).splitlines()[0][:200]})") from None


def load_factory(spec: str) -> Any:
    """Import ``'pkg.mod:callable'`` and call it."""
    mod_name, _, attr = spec.partition(":")
    if not mod_name or not attr:
        raise ConfigError(f"encoders.torchscript.factory {spec!r}: expected 'package.module:callable'")
    try:
        fn = getattr(importlib.import_module(mod_name), attr)
    except (ImportError, AttributeError) as err:
        raise ConfigError(f"encoders.torchscript.factory {spec!r}: {err}") from None
    obj = fn()
    for method in ("encode_image", "encode_text"):
        if not callable(getattr(obj, method, None)):
            raise ConfigError(f"encoders.torchscript.factory {spec!r}: the object has no {method}()")
    return obj


class TorchScriptEncoder(Encoder):
    """A dense encoder from user files or a factory; see the module docstring."""

    name = "torchscript"
    params_model = TorchScriptParams

    def __init__(
        self,
        image_fn: Any,
        text_fn: Any,
        *,
        sources: dict[str, Any],
        name: str = "torchscript",
        version: str = "1",
        input_size: tuple[int, int] | None = None,
        temperature: float | None = None,
        device: str = "cpu",
        batch_size: int = 4,
    ):
        super().__init__(device=device, batch_size=batch_size)
        for fn in (image_fn, text_fn):
            if isinstance(fn, torch.nn.Module):
                fn.to(self.device)
        self._image, self._text = image_fn, text_fn
        self.name, self.version = name, version  # instance values: the user's encoder, recorded as such
        self.sources = sources
        self.input_size = tuple(input_size) if input_size is not None else None
        self._temperature = temperature
        self._dim: int | None = None

    @classmethod
    def from_params(cls, params: "EncodersParams", *, device: str, batch_size: int = 4) -> "TorchScriptEncoder":
        p = cls.settings(params)
        common = dict(name=p.name, version=p.version, input_size=p.input_size, device=device,
                      batch_size=batch_size)
        if p.factory is not None:
            obj = load_factory(p.factory)
            return cls(obj.encode_image, obj.encode_text, sources={"factory": p.factory},
                       temperature=getattr(obj, "temperature", None), **common)
        image = require_file(p.image_file, "encoders.torchscript.image_file", "the torchscript encoder (images)")
        text = require_file(p.text_file, "encoders.torchscript.text_file", "the torchscript encoder (text)")
        sources = {"image_file": image.name, "image_digest": file_digest(image),
                   "text_file": text.name, "text_digest": file_digest(text)}
        return cls(_load_script(image, "encoders.torchscript.image_file"),
                   _load_script(text, "encoders.torchscript.text_file"), sources=sources, **common)

    @property
    def dim(self) -> int:
        if self._dim is None:
            self._dim = int(self.encode_text(["object"]).shape[1])
        return self._dim

    @property
    def temperature(self) -> float | None:
        return self._temperature

    def config_identity(self) -> dict[str, Any]:
        return {"input_size": list(self.input_size) if self.input_size else None}

    def weights_identity(self) -> dict[str, Any]:
        return dict(self.sources)

    def encode_text(self, texts: list[str]) -> torch.Tensor:
        with torch.inference_mode():
            out = torch.as_tensor(self._text(list(texts))).float()
        if out.ndim != 2 or out.shape[0] != len(texts):
            raise StageError(f"torchscript encoder {self.name}: text output {tuple(out.shape)}, expected ({len(texts)},D)")
        return l2_normalize(out).cpu()

    def _encode_batch(self, rgb: np.ndarray, depth_m, instance) -> DenseFeatures:
        x = to_tensor01(rgb, self.device)
        if self.input_size is not None and tuple(x.shape[-2:]) != self.input_size:
            x = F.interpolate(x, size=self.input_size, mode="bilinear", align_corners=False, antialias=True)
        feat = torch.as_tensor(self._image(x)).float()
        if feat.ndim != 4 or feat.shape[0] != rgb.shape[0]:
            raise StageError(f"torchscript encoder {self.name}: image output {tuple(feat.shape)}, expected (B,D,h,w)")
        feat = feat.permute(0, 2, 3, 1)
        norm = feat.norm(dim=-1)
        valid = torch.isfinite(norm) & (norm > 0)
        feat = torch.where(valid[..., None], feat / norm.clamp_min(1e-12)[..., None], torch.zeros_like(feat))
        return DenseFeatures(feat.contiguous().cpu(), valid.cpu(), tuple(rgb.shape[1:3]))
