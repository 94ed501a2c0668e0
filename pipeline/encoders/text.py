"""Text sides of encoders that need no torch: what ``zipon query`` builds to encode its prompts.

A map query needs only an encoder's text features. For the diagnostic oracle
(:class:`~pipeline.encoders.oracle_text.OracleText`) and the simulated perception models (the CLIP text
embeddings of :class:`~pipeline.encoders.perception_text.ClipTextSpace`) they are numpy data, so
:func:`text_encoder` gives a :class:`TextEncoder` for them and the query imports neither torch nor the
image side; for every other encoder it answers None and the caller builds the whole encoder
(:func:`pipeline.encoders.build_encoder`). Both give the same features: the image-side classes call the
same text code.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

if TYPE_CHECKING:
    from pipeline.config import EncodersParams
    from pipeline.scene_gt import GTScene


class TextEncoder:
    """The text side of an encoder: ``encode_text(texts)`` ``(T,D)`` float32 unit rows (numpy), ``name``, ``dim``,
    ``identity()`` (what a map's ``attrs.encoder`` is checked against) and ``bind_scene(gt)``."""

    def __init__(self, name: str, version: str, dim: int, temperature: float | None,
                 encode: Callable[[list[str]], np.ndarray], bind: Callable[["GTScene | None"], None] | None = None,
                 weights: dict[str, Any] | None = None):
        self.name, self.version, self.dim, self.temperature = name, version, int(dim), temperature
        self._encode, self._bind, self._weights = encode, bind, dict(weights or {})

    def identity(self) -> dict[str, Any]:
        return {"name": self.name, "version": self.version, "dim": self.dim, "normalization": "l2",
                "temperature": self.temperature, **self._weights}

    def encode_text(self, texts: list[str]) -> np.ndarray:
        return np.asarray(self._encode(list(texts)), dtype=np.float32)

    def bind_scene(self, gt: "GTScene | None") -> None:
        if self._bind is not None:
            self._bind(gt)


def text_encoder(params: "EncodersParams", name: str) -> TextEncoder | None:
    """A torch-free :class:`TextEncoder` for encoder ``name`` configured by ``params``, or None when its text side
    needs the encoder's model (build the encoder then)."""
    if name == "oracle":
        from pipeline.encoders.oracle_text import VERSION, OracleText

        p = params.oracle
        words = OracleText(dim=p.dim, seed=p.seed, color_weight=p.color_weight, material_weight=p.material_weight)
        return TextEncoder(name, VERSION, p.dim, None, words.encode_text, words.bind_scene)
    if name in ("simulated_lseg", "simulated_cf"):
        from pipeline.encoders.perception_text import TEMPERATURE, VERSIONS, load_text_space, resolve_embeddings

        param = f"encoders.{name}.embeddings"
        space = load_text_space(resolve_embeddings(getattr(params, name).embeddings, param), param)
        return TextEncoder(name, VERSIONS[name], space.dim, TEMPERATURE,
                           lambda texts: np.stack([space.encode(t) for t in texts]).astype(np.float32),
                           weights={"weights_file": Path(space.path).name, "weights_digest": file_digest(space.path)})
    return None


def file_digest(path: str | Path) -> str:
    """blake2b digest of a file's bytes (weights identity)."""
    h = hashlib.blake2b(digest_size=16)
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 22), b""):
            h.update(chunk)
    return "blake2b:" + h.hexdigest()
