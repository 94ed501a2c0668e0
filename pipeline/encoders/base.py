"""The encoder interface: RGB images -> per-pixel features, text -> features in the same space.

Contract (every implementation; checked by ``tests/pipeline/encoders/test_base.py::TestEncoderContract``):

- ``encode_images(rgb, *, depth_m=None, instance=None) -> DenseFeatures``

  * ``rgb``: ``(B,H,W,3)`` uint8, RGB order.
  * ``depth_m``: optional ``(B,H,W)`` float32 metres (0 = invalid); used by region generators.
  * ``instance``: optional ``(B,H,W)`` uint16 instance ids (0 = none); used by 'gt' regions and the oracle.
  * returns :class:`DenseFeatures` with ``features`` ``(B,h,w,D)`` float32 (CPU torch tensor),
    L2-normalised along D where ``valid``, zero elsewhere, and ``valid`` ``(B,h,w)`` bool.

- ``encode_text(texts: list[str]) -> torch.Tensor`` ``(T,D)`` float32, L2-normalised.
  Similarity of a cell and a query is the dot product; an encoder that was trained with a
  temperature records it (``identity()['temperature']``: logits = dot / temperature).

Resolution: a feature map of ``h x w`` cells covers the WHOLE input image, resampled with the
pixel-corner convention (cell ``(r, c)`` covers pixels ``[r*H/h, (r+1)*H/h) x [c*W/w, (c+1)*W/w)``).
So the intrinsics of the feature grid are ``Intrinsics.scaled(w, h)`` (see :meth:`DenseFeatures.intrinsics`),
and depth for back-projection is depth resampled to ``(h, w)`` (:meth:`DenseFeatures.resample_depth`).

Family: :class:`Encoder` (ABC) + :data:`ENCODERS` (name -> class, filled on use from the one registry: zipon's own
encoders declared in :data:`pipeline.plugins.BUILT_IN_ENCODERS`, the installed ``zipon.encoders``; see
:func:`pipeline.encoders.choice.encoder_class`).
``bind_scene(gt)`` hands the scene's ground truth to encoders that use it (only the oracle, a
diagnostic); it is a no-op for real encoders. Nothing downloads weights: a real encoder without
its weights file is a :class:`ConfigError` naming the param, a missing file a
:class:`MissingInputError` naming the file, a file that does not fit the model a ConfigError naming both.

Every encoder declares ``name``, ``version``, ``dim``, ``normalization`` (always 'l2') and
``temperature``, and a JSON-able ``identity()`` (which includes a digest of its weights file) that
the map stages store in their attrs. Encoders are chosen by name in ``params.yaml``
(:class:`pipeline.config.EncodersParams`) and built by :func:`pipeline.encoders.build.build_encoder`.
"""

from __future__ import annotations

import contextlib
import os
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import torch
import torch.nn.functional as F

from pipeline import plugins
from pipeline.encoders.text import file_digest
from pipeline.errors import ConfigError, InputDataError, MissingInputError
from pipeline.section import Section

if TYPE_CHECKING:
    from pipeline.config import EncodersParams
    from pipeline.geometry import Intrinsics
    from pipeline.scene_gt import GTScene

# CLIP's image normalisation (open_clip OPENAI_DATASET_MEAN/STD).
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)


@dataclass
class DenseFeatures:
    """Per-cell features of a batch of images.

    ``features``: ``(B,h,w,D)`` float32 CPU tensor, unit L2 norm where ``valid``, 0 elsewhere.
    ``valid``: ``(B,h,w)`` bool. ``image_size``: ``(H, W)`` of the input images; the ``h x w`` grid
    covers the whole image (pixel-corner convention, see the module docstring).
    """

    features: torch.Tensor
    valid: torch.Tensor
    image_size: tuple[int, int]

    @property
    def size(self) -> tuple[int, int]:
        """``(h, w)`` of the feature grid."""
        return int(self.features.shape[1]), int(self.features.shape[2])

    @property
    def scale(self) -> tuple[float, float]:
        """``(sy, sx)``: feature cells per image pixel along rows / columns."""
        return self.size[0] / self.image_size[0], self.size[1] / self.image_size[1]

    def intrinsics(self, image_intrinsics: "Intrinsics") -> "Intrinsics":
        """Intrinsics of the feature grid, given those of the input images."""
        if (image_intrinsics.height, image_intrinsics.width) != tuple(self.image_size):
            raise ValueError(
                f"intrinsics are {image_intrinsics.width}x{image_intrinsics.height}, "
                f"features were computed on {self.image_size[1]}x{self.image_size[0]} images"
            )
        return image_intrinsics.scaled(self.size[1], self.size[0])

    def resample_depth(self, depth_m: np.ndarray) -> np.ndarray:
        """``(B,H,W)`` metres -> ``(B,h,w)``: nearest pixel at each cell centre (no mixing across edges)."""
        depth_m = np.asarray(depth_m)
        H, W = self.image_size
        h, w = self.size
        rows = np.minimum(((np.arange(h) + 0.5) * H / h).astype(np.int64), H - 1)
        cols = np.minimum(((np.arange(w) + 0.5) * W / w).astype(np.int64), W - 1)
        return depth_m[:, rows[:, None], cols[None, :]]

    @classmethod
    def concat(cls, parts: "list[DenseFeatures]") -> "DenseFeatures":
        """The batches ``parts`` (same grid and image size) as one, in order."""
        return DenseFeatures(torch.cat([p.features for p in parts]), torch.cat([p.valid for p in parts]),
                             parts[0].image_size)


class PaletteFeatures(DenseFeatures):
    """Features whose cells each take one of a few vectors: cell ``(b, r, c)`` holds ``palette[index[b, r, c]]``.

    ``palette``: ``(T,D)`` float32 unit rows; ``index``: ``(B,h,w)`` int64 rows of it; ``valid`` as in
    :class:`DenseFeatures`. ``features`` (``(B,h,w,D)``, zero where not valid) is built on first use
    only: map fusion (:mod:`pipeline.maps.fusion`) sums point weights per (cell, palette row) and
    multiplies by the palette, reading ``T x D`` numbers instead of ``B*h*w x D``.
    """

    def __init__(self, palette: torch.Tensor, index: torch.Tensor, valid: torch.Tensor, image_size: tuple[int, int]):
        self.palette, self.index, self.valid, self.image_size = palette, index, valid, tuple(image_size)
        self._features: torch.Tensor | None = None

    @property
    def features(self) -> torch.Tensor:  # type: ignore[override]
        if self._features is None:
            self._features = self.palette[self.index] * self.valid[..., None]
        return self._features

    @property
    def size(self) -> tuple[int, int]:
        return int(self.index.shape[1]), int(self.index.shape[2])

    @classmethod
    def concat(cls, parts: "list[DenseFeatures]") -> "DenseFeatures":
        """One palette when every part shares it (the same tensor), else the palettes stacked, indices shifted."""
        if not all(isinstance(p, PaletteFeatures) for p in parts):
            return DenseFeatures.concat(parts)
        valid = torch.cat([p.valid for p in parts])
        if all(p.palette is parts[0].palette for p in parts):
            return cls(parts[0].palette, torch.cat([p.index for p in parts]), valid, parts[0].image_size)
        offsets = np.cumsum([0] + [len(p.palette) for p in parts[:-1]])
        return cls(torch.cat([p.palette for p in parts]), torch.cat([p.index + int(o) for p, o in zip(parts, offsets)]),
                   valid, parts[0].image_size)


class Encoder(ABC):
    """An open-vocabulary dense encoder (see the module docstring for the contract)."""

    name: ClassVar[str]
    version: ClassVar[str] = "1"
    normalization: ClassVar[str] = "l2"
    #: True only for the ground-truth oracle; maps record it so nobody mistakes it for perception.
    diagnostic: ClassVar[bool] = False
    #: True for encoders that read the scene's ground truth (the oracle, the simulated perception models)
    needs_ground_truth: ClassVar[bool] = False
    #: False for encoders that never look at the colour images (the oracle): readers may then skip decoding them.
    reads_rgb: ClassVar[bool] = True
    #: the class of the encoder's settings (a :class:`pipeline.section.Section`), declared beside it: the
    #: ``encoders.<name>`` section of zipon's own encoders, ``encoders.plugins.<name>`` of an installed package's,
    #: validated against it when the params load; None: the encoder takes no settings
    params_model: ClassVar[type[Section] | None] = None

    def __init__(self, *, device: str = "cpu", batch_size: int = 4):
        self.device = torch.device(device)
        self.batch_size = int(batch_size)

    # ------------------------------------------------------------------ interface
    @classmethod
    def settings(cls, params: "EncodersParams") -> Section | None:
        """The encoder's settings in the ``encoders`` section ``params``, as its :attr:`params_model`."""
        if cls.name in type(params).model_fields:
            return getattr(params, cls.name)
        if cls.params_model is None:
            return None
        return cls.params_model.model_validate(params.plugins.get(cls.name, {}))

    @classmethod
    @abstractmethod
    def from_params(cls, params: "EncodersParams", *, device: str, batch_size: int = 4) -> "Encoder":
        """Build from the ``encoders`` section (its own sub-section plus batch size); no downloads."""

    @property
    @abstractmethod
    def dim(self) -> int:
        """Feature dimension D."""

    @property
    def temperature(self) -> float | None:
        """Temperature of the training objective (logits = cosine / temperature), if any."""
        return None

    @abstractmethod
    def _encode_batch(self, rgb: np.ndarray, depth_m: np.ndarray | None, instance: np.ndarray | None) -> DenseFeatures:
        """One batch of at most ``batch_size`` images (inputs already checked)."""

    @abstractmethod
    def encode_text(self, texts: list[str]) -> torch.Tensor:
        """``(T,D)`` float32 CPU tensor, L2-normalised."""

    #: the local weights file an implementation loaded (None: no weights, e.g. the oracle)
    weights: Path | None = None
    _weights_digest: str | None = None

    def weights_identity(self) -> dict[str, Any]:
        """The weights the encoder runs with: ``{"weights_file": name, "weights_digest": ...}`` or ``{}``."""
        if self.weights is None:
            return {}
        if self._weights_digest is None:
            self._weights_digest = file_digest(self.weights)
        return {"weights_file": Path(self.weights).name, "weights_digest": self._weights_digest}

    def config_identity(self) -> dict[str, Any]:
        """Settings that change the features (sizes, arch); recorded in :meth:`identity`."""
        return {}

    def bind_scene(self, gt: "GTScene | None") -> None:
        """Give the encoder the scene's ground truth (only the oracle uses it; a no-op otherwise)."""

    # ------------------------------------------------------------------ shared
    def identity(self) -> dict[str, Any]:
        """JSON-able description the maps store in their attrs."""
        return {
            "name": self.name,
            "version": self.version,
            "dim": self.dim,
            "normalization": self.normalization,
            "temperature": self.temperature,
            "diagnostic": self.diagnostic,
            **self.config_identity(),
            **self.weights_identity(),
            **({"precision": self.precision} if self.precision != "fp32" else {}),
        }

    def encode_images(
        self,
        rgb: np.ndarray,
        *,
        depth_m: np.ndarray | None = None,
        instance: np.ndarray | None = None,
    ) -> DenseFeatures:
        """Dense features of ``(B,H,W,3)`` uint8 images, computed ``batch_size`` images at a time.

        Dense batches are copied into one ``(B,h,w,D)`` tensor as they come (a block's features exist once, plus
        one batch: not the batches and their concatenation, 2 x 630 MB for 16 LSeg-sized frames)."""
        rgb, depth_m, instance = check_images(rgb, depth_m, instance)
        parts, whole = [], None
        with torch.inference_mode():
            for start in range(0, rgb.shape[0], self.batch_size):
                sl = slice(start, start + self.batch_size)
                with self._autocast(), plugins.running(type(self), "encode_images"):
                    part = as_float32(self._encode_batch(
                        rgb[sl],
                        None if depth_m is None else depth_m[sl],
                        None if instance is None else instance[sl],
                    ))
                if start == 0 and type(part) is DenseFeatures and rgb.shape[0] > self.batch_size:
                    n = rgb.shape[0]
                    whole = DenseFeatures(torch.empty((n,) + tuple(part.features.shape[1:]), dtype=part.features.dtype,
                                                      device=part.features.device),
                                          torch.empty((n,) + tuple(part.valid.shape[1:]), dtype=part.valid.dtype,
                                                      device=part.valid.device), part.image_size)
                if whole is not None:  # the same values torch.cat of the parts' features would give
                    whole.features[sl] = part.features
                    whole.valid[sl] = part.valid
                else:
                    parts.append(part)
        if whole is not None:
            return whole
        return parts[0] if len(parts) == 1 else type(parts[0]).concat(parts)

    #: ``run.precision``: 'fp32', or the autocast precision of the forward passes ('bf16', 'fp16')
    precision: str = "fp32"

    def _autocast(self):
        if self.precision == "fp32":
            return contextlib.nullcontext()
        return torch.autocast(device_type=self.device.type, dtype=PRECISIONS[self.precision])


class OpenClipText:
    """Text side and temperature of an open_clip model (``self.model``, ``self._tokenize``, ``self.device``)."""

    @property
    def temperature(self) -> float:
        return float(1.0 / self.model.logit_scale.exp().item())

    def encode_text(self, texts: list[str]) -> torch.Tensor:
        with torch.inference_mode():
            return l2_normalize(self.model.encode_text(self._tokenize(list(texts)).to(self.device)).float()).cpu()


# ----------------------------------------------------------------------------- helpers

def cached_text_features(encoder: "Encoder", cache: dict[str, torch.Tensor], texts: list[str]) -> torch.Tensor:
    """``(T,D)`` float32 text features of ``texts``; prompts missing from ``cache`` are encoded in one call and kept."""
    missing = [t for t in dict.fromkeys(texts) if t not in cache]
    if missing:
        for t, f in zip(missing, encoder.encode_text(missing).float()):
            cache[t] = f
    return torch.stack([cache[t] for t in texts])


def check_images(
    rgb: np.ndarray, depth_m: np.ndarray | None, instance: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Validate the batch layout; raises :class:`InputDataError` naming the field."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 4 or rgb.shape[-1] != 3 or rgb.dtype != np.uint8 or rgb.shape[0] == 0:
        raise InputDataError(f"got {rgb.dtype} {rgb.shape}", field="rgb", expected="(B,H,W,3) uint8 with B >= 1")
    B, H, W, _ = rgb.shape
    if depth_m is not None:
        depth_m = np.asarray(depth_m, dtype=np.float32)
        if depth_m.shape != (B, H, W):
            raise InputDataError(f"got {depth_m.shape}", field="depth_m", expected=f"({B},{H},{W}) metres")
    if instance is not None:
        instance = np.asarray(instance)
        if instance.shape != (B, H, W) or instance.dtype.kind not in "ui":
            raise InputDataError(
                f"got {instance.dtype} {instance.shape}", field="instance", expected=f"({B},{H},{W}) integer ids"
            )
    return rgb, depth_m, instance


def resolve_device(device: str, key: str = "run.device") -> str:
    """'auto' -> 'cuda' when available else 'cpu'; 'cuda' / 'cuda:N' without that GPU is a :class:`ConfigError`
    naming ``key``."""
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device.startswith("cuda"):
        index = int(device.partition(":")[2] or 0)
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if index >= count:
            raise ConfigError(f"{key}: {device!r} requested but torch sees {count} CUDA device(s) "
                              "(use 'cpu', 'auto' or an index below that count)")
    return device


PRECISIONS = {"bf16": torch.bfloat16, "fp16": torch.float16}  # run.precision -> autocast dtype ('fp32': off)


def require_file(path: str | Path | None, param: str, what: str) -> Path:
    """The weights file named by ``param``; a clear error when it is unset or missing. Never downloads."""
    if path is None:
        raise ConfigError(
            f"{param} is not set: {what} needs a local weights file (nothing is downloaded); "
            f"set {param} in params.yaml"
        )
    p = Path(os.path.expanduser(str(path)))
    if not p.is_file():
        raise MissingInputError(f"{param}: weights file {p} not found ({what})")
    return p


def weights_error(param: str, path: Path, err: Exception) -> ConfigError:
    """A weights file that does not fit the model: name the param, the file and the first problem."""
    text = str(err).strip().splitlines()
    detail = " ".join(text[:3])[:600]
    return ConfigError(f"{param}: {path} does not match the model: {detail}")


def to_tensor01(rgb: np.ndarray, device: torch.device) -> torch.Tensor:
    """``(B,H,W,3)`` uint8 -> ``(B,3,H,W)`` float32 in [0, 1] on ``device``."""
    return torch.from_numpy(np.ascontiguousarray(rgb)).to(device).permute(0, 3, 1, 2).float().div_(255.0)


def normalize(x: torch.Tensor, mean: tuple[float, ...], std: tuple[float, ...]) -> torch.Tensor:
    """Per-channel ``(x - mean) / std`` of a ``(B,3,H,W)`` tensor."""
    m = torch.tensor(mean, dtype=x.dtype, device=x.device).view(1, -1, 1, 1)
    s = torch.tensor(std, dtype=x.dtype, device=x.device).view(1, -1, 1, 1)
    return (x - m) / s


def as_float32(part: DenseFeatures) -> DenseFeatures:
    """Features computed under autocast, back in the contract's float32 (unit rows where valid, 0 elsewhere)."""
    if isinstance(part, PaletteFeatures):
        if part.palette.dtype == torch.float32:
            return part
        return PaletteFeatures(l2_normalize(part.palette.float()), part.index, part.valid, part.image_size)
    if part.features.dtype == torch.float32:
        return part
    return DenseFeatures(l2_normalize(part.features.float()) * part.valid[..., None], part.valid, part.image_size)


def l2_normalize(x: torch.Tensor, dim: int = -1, eps: float = 1e-12) -> torch.Tensor:
    """Unit-norm along ``dim`` (zero vectors stay zero)."""
    return x / x.norm(dim=dim, keepdim=True).clamp_min(eps)


def resize_features(feat_bdhw: torch.Tensor, out_size: tuple[int, int] | None) -> torch.Tensor:
    """``(B,D,h,w)`` -> ``(B,out_h,out_w,D)`` float32 CPU, L2-normalised; bilinear over the whole extent
    (pixel-corner), antialiased when shrinking by more than 2x."""
    if out_size is not None and tuple(feat_bdhw.shape[-2:]) != tuple(out_size):
        # antialias only when shrinking more than 2x (plain bilinear then skips input cells entirely)
        down = out_size[0] * 2 < feat_bdhw.shape[-2] or out_size[1] * 2 < feat_bdhw.shape[-1]
        feat_bdhw = F.interpolate(
            feat_bdhw.float(), size=tuple(out_size), mode="bilinear", align_corners=False, antialias=down
        )
    return l2_normalize(feat_bdhw.float(), dim=1).permute(0, 2, 3, 1).contiguous().cpu()


def all_valid(feat: torch.Tensor) -> torch.Tensor:
    """``(B,h,w)`` True everywhere for a ``(B,h,w,D)`` map."""
    return torch.ones(feat.shape[:3], dtype=torch.bool)


# ----------------------------------------------------------------------------- registry

#: encoder name -> implementation, the ones loaded so far (:func:`pipeline.encoders.choice.encoder_class` fills it)
ENCODERS: dict[str, type[Encoder]] = {}
