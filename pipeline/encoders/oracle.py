"""``oracle``: a DIAGNOSTIC encoder for simulated scenes, built from ground truth, not a perception model.

It isolates geometry and fusion from recognition: with it, a map's errors are the mapping's own.
It is never chosen implicitly; maps built with it record ``diagnostic: true`` in their attrs.

Space: every word has a deterministic random unit vector (seeded by ``seed`` and the word).
An instance's feature is ``normalise(v(class) + color_weight * mean(v(colour words))
+ material_weight * v(material))``; instance 0 (walls, floor, nothing) is ``v('background')``.
A query maps its known words into the same space with the same weights ("a red chair" ->
``v(chair) + color_weight * v(red)``), so the red chair scores above the blue one; 'floor',
'wall', 'other' ... mean background; a query with no known word gets a vector of its own
(near-orthogonal to everything). Personal names are not the encoder's business.

Imperfection on purpose: per frame, each instance takes another scene class's word with
probability ``confusion``; each cell gets gaussian noise of std ``noise_std`` before
renormalising. Draws are seeded by ``seed`` and the frame's instance image, so results do not
depend on batching.

Speed: the instance table is built once per scene (:meth:`OracleEncoder.bind_scene`) with its rows
already unit-norm; a frame is a row look-up per cell, returned as
:class:`~pipeline.encoders.base.PaletteFeatures` (the table + an index image), which map fusion
adds without ever writing ``h*w x D`` features. Only ``noise_std > 0`` makes dense features.
"""

from __future__ import annotations

import hashlib
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from pipeline.encoder_params.oracle import OracleParams
from pipeline.encoders.base import DenseFeatures, Encoder, PaletteFeatures
from pipeline.encoders.oracle_text import BACKGROUND, VERSION, OracleText, _words
from pipeline.errors import ConfigError, InputDataError

if TYPE_CHECKING:
    from pipeline.config import EncodersParams
    from pipeline.scene_gt import GTScene


def _centre_pixels(n_pixels: int, n_cells: int) -> slice | np.ndarray:
    """Index of the pixel at each cell centre along one axis (pixel-corner convention, as
    :meth:`DenseFeatures.resample_depth`): a strided slice when a cell is a whole number of pixels."""
    if n_pixels % n_cells == 0:
        step = n_pixels // n_cells
        return slice(step // 2, None, step)
    return np.minimum(((np.arange(n_cells) + 0.5) * n_pixels / n_cells).astype(np.int64), n_pixels - 1)


class OracleEncoder(OracleText, Encoder):
    """Ground-truth features for simulated scenes (a diagnostic); see the module docstring. The word space and
    the text side are :class:`~pipeline.encoders.oracle_text.OracleText`'s (numpy)."""

    name = "oracle"
    params_model = OracleParams
    version = VERSION
    diagnostic = True
    reads_rgb = False

    def __init__(
        self,
        *,
        dim: int = 512,
        seed: int = 0,
        color_weight: float = 0.5,
        material_weight: float = 0.3,
        confusion: float = 0.0,
        noise_std: float = 0.0,
        out_size: tuple[int, int] = (120, 160),
        device: str = "cpu",
        batch_size: int = 4,
    ):
        Encoder.__init__(self, device="cpu", batch_size=batch_size)  # table look-ups: no accelerator needed
        OracleText.__init__(self, dim=dim, seed=seed, color_weight=color_weight, material_weight=material_weight)
        self.confusion, self.noise_std = float(confusion), float(noise_std)
        self.out_size = tuple(out_size)

    @classmethod
    def from_params(cls, params: "EncodersParams", *, device: str, batch_size: int = 4) -> "OracleEncoder":
        p = cls.settings(params)
        return cls(dim=p.dim, seed=p.seed, color_weight=p.color_weight, material_weight=p.material_weight,
                   confusion=p.confusion, noise_std=p.noise_std, out_size=p.out_size, device=device,
                   batch_size=batch_size)

    # ------------------------------------------------------------------ space
    def config_identity(self) -> dict[str, Any]:
        return {"kind": "ground-truth oracle (DIAGNOSTIC of geometry and fusion, not a perception model)",
                "seed": self.seed, "color_weight": self.color_weight, "material_weight": self.material_weight,
                "confusion": self.confusion, "noise_std": self.noise_std, "out_size": list(self.out_size),
                "scene": self._gt.name if self._gt is not None else None}

    def bind_scene(self, gt: "GTScene | None") -> None:
        """Use ``gt``'s objects (instance id -> class, colour, material) for the image side."""
        OracleText.bind_scene(self, gt)
        if gt is not None:
            self._scene_table(gt)

    def encode_text(self, texts: list[str]) -> torch.Tensor:
        return torch.from_numpy(OracleText.encode_text(self, texts))

    # ------------------------------------------------------------------ images
    def _scene_table(self, gt: "GTScene") -> None:
        """The scene's instance table, built once per scene: ``_lut`` id -> object slot (0 = background,
        ids beyond the scene's map to the last entry, background too), ``_raw`` ``(R,D)`` float64 composed
        vectors (rows 0..N: background and each object with its own class; confusion appends a row per
        (object, other class) the first time a frame draws it) and ``_unit`` their unit rows, float32."""
        objs = gt.objects
        ids = np.array([o.id for o in objs], dtype=np.int64)
        self._lut = np.zeros(int(ids.max(initial=0)) + 2, dtype=np.int64)
        self._lut[ids] = np.arange(1, len(ids) + 1)
        self._attrs = [(" ".join(_words(o.cls)), _words(o.color_name), _words(o.material)) for o in objs]
        self._raw = np.stack([self.word_vector(BACKGROUND)] + [self._compose([c], col, mat) for c, col, mat in self._attrs])
        self._row_of: dict[tuple[int, str], int] = {}
        self._unit_rows()

    def _unit_rows(self) -> None:
        raw = self._raw
        self._unit = torch.from_numpy((raw / np.linalg.norm(raw, axis=-1, keepdims=True).clip(1e-12)).astype(np.float32))

    def _frame_rng(self, instance: np.ndarray) -> np.random.Generator:
        key = hashlib.blake2b(np.ascontiguousarray(instance).tobytes(), digest_size=8).digest()
        return np.random.default_rng([self.seed, int.from_bytes(key, "little")])

    def _confused_rows(self, rng: np.random.Generator) -> np.ndarray:
        """``(N+1,)`` table row of each object slot for one frame: its own class, or with probability
        ``confusion`` another scene class's word (drawn in object order)."""
        row = np.arange(len(self._attrs) + 1)
        if self.confusion <= 0 or len(self._classes) < 2:
            return row
        grown = False
        for i, (cls, colors, materials) in enumerate(self._attrs):
            if rng.random() < self.confusion:
                others = [c for c in self._classes if c != cls]
                other = others[int(rng.integers(len(others)))]
                if (i, other) not in self._row_of:
                    self._row_of[i, other] = len(self._raw)
                    self._raw = np.concatenate([self._raw, self._compose([other], colors, materials)[None]])
                    grown = True
                row[i + 1] = self._row_of[i, other]
        if grown:
            self._unit_rows()
        return row

    def _encode_batch(self, rgb: np.ndarray, depth_m, instance) -> DenseFeatures:
        """Row look-ups into the scene's table: :class:`PaletteFeatures` (the table and an index per cell);
        with noise, dense features (``normalise(row + noise)`` per cell)."""
        if self._gt is None:
            raise ConfigError("the oracle encoder needs the scene's ground truth (bind_scene); it is a diagnostic "
                              "for simulated scenes only — choose a real encoder for real data")
        if instance is None:
            raise InputDataError("the oracle encoder needs instance images", field="instance",
                                 expected="(B,H,W) uint16 ids (simulated scenes)")
        B, H, W = instance.shape
        h, w = self.out_size
        sampled = instance[:, _centre_pixels(H, h)][:, :, _centre_pixels(W, w)]
        if sampled.dtype.kind == "i":
            sampled = np.maximum(sampled, 0)
        index = self._lut[np.minimum(sampled, len(self._lut) - 1)]  # unknown ids fall back to background (row 0)
        valid = torch.ones((B, h, w), dtype=torch.bool)
        if self.confusion <= 0 and self.noise_std <= 0:
            return PaletteFeatures(self._unit, torch.from_numpy(index), valid, (H, W))
        dense = np.empty((B, h, w, self._dim), dtype=np.float32) if self.noise_std > 0 else None
        for b in range(B):  # per-frame draws, seeded by the frame's instance image (independent of batching)
            rng = self._frame_rng(instance[b])
            index[b] = self._confused_rows(rng)[index[b]]
            if dense is not None:
                f = self._raw[index[b]] + rng.standard_normal((h, w, self._dim)) * self.noise_std
                dense[b] = f / np.linalg.norm(f, axis=-1, keepdims=True).clip(1e-12)
        if dense is not None:
            return DenseFeatures(torch.from_numpy(dense), valid, (H, W))
        return PaletteFeatures(self._unit, torch.from_numpy(index), valid, (H, W))
