"""The oracle encoder's word space and text side, numpy only (:mod:`pipeline.encoders.oracle` adds the
image side with torch): ``zipon query`` on an oracle map encodes its prompts without importing torch.

Every word has a deterministic random unit vector (seeded by ``seed`` and the word); a query maps its
known words (classes of the scene and :data:`COMMON_CLASSES`, colours, materials) into that space,
see :mod:`pipeline.encoders.oracle`.
"""

from __future__ import annotations

import hashlib
import re
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from pipeline.scene_gt import GTScene

VERSION = "1"
BACKGROUND = "background"
BACKGROUND_WORDS = {"background", "floor", "floors", "wall", "walls", "other", "ceiling", "none", "nothing", "ground"}
COLOR_WORDS = {
    "red", "green", "blue", "yellow", "orange", "purple", "pink", "brown", "black", "white", "grey", "beige",
    "dark", "light", "navy", "teal", "cream", "tan", "olive", "maroon", "gold", "silver", "violet", "cyan",
}
MATERIAL_WORDS = {"wood", "leather", "metal", "fabric", "glass", "plastic", "ceramic", "marble", "stone", "wool",
                  "cotton", "steel", "velvet", "wicker", "rattan", "concrete", "paper"}
SYNONYMS = {"gray": "grey", "wooden": "wood", "metallic": "metal", "tv": "television"}
COMMON_CLASSES = {
    "chair", "table", "sofa", "couch", "bed", "cabinet", "shelf", "bookshelf", "desk", "lamp", "plant", "toilet",
    "sink", "tv", "television", "monitor", "computer", "laptop", "refrigerator", "fridge", "oven", "stove",
    "microwave", "bathtub", "shower", "mirror", "picture", "painting", "door", "window", "pillow", "cushion",
    "rug", "carpet", "clock", "vase", "book", "bottle", "cup", "mug", "bowl", "box", "basket", "stool", "bench",
    "dresser", "wardrobe", "nightstand", "counter", "curtain", "towel", "trash can", "dining table",
    "coffee table", "tv stand", "armchair", "fireplace", "piano", "printer", "keyboard",
}


def _words(text: str) -> list[str]:
    return [SYNONYMS.get(w, w) for w in re.findall(r"[a-z]+", text.lower())]


class OracleText:
    """The oracle's word vectors and text encoder (numpy); :class:`~pipeline.encoders.oracle.OracleEncoder`
    builds its instance features from the same word vectors."""

    def __init__(self, *, dim: int = 512, seed: int = 0, color_weight: float = 0.5, material_weight: float = 0.3):
        self._dim, self.seed = int(dim), int(seed)
        self.color_weight, self.material_weight = float(color_weight), float(material_weight)
        self._cache: dict[str, np.ndarray] = {}
        self._gt: GTScene | None = None
        self._classes: list[str] = []

    @property
    def dim(self) -> int:
        return self._dim

    def word_vector(self, word: str) -> np.ndarray:
        """Deterministic unit vector ``(D,)`` float64 of a word (background words share one)."""
        word = BACKGROUND if word in BACKGROUND_WORDS else word
        if word not in self._cache:
            h = hashlib.blake2b(f"{self.seed}\0{word}".encode(), digest_size=8).digest()
            v = np.random.default_rng(int.from_bytes(h, "little")).standard_normal(self._dim)
            self._cache[word] = v / np.linalg.norm(v)
        return self._cache[word]

    def _compose(self, classes: list[str], colors: list[str], materials: list[str]) -> np.ndarray:
        v = np.zeros(self._dim)
        for c in classes:
            v += self.word_vector(c)
        if colors:
            v += self.color_weight * np.mean([self.word_vector(c) for c in colors], axis=0)
        for m in materials:
            v += self.material_weight * self.word_vector(m)
        return v

    def bind_scene(self, gt: "GTScene | None") -> None:
        """Add ``gt``'s classes to the words a query can name."""
        self._gt = gt
        self._classes = sorted({" ".join(_words(o.cls)) for o in gt.objects}) if gt is not None else []

    def _class_vocab(self) -> set[str]:
        return COMMON_CLASSES | set(self._classes)

    def encode_text(self, texts: list[str]) -> np.ndarray:
        """``(T,D)`` float32 unit text features (numpy; see the module docstring of :mod:`pipeline.encoders.oracle`)."""
        vocab = self._class_vocab()
        scene_colors = {w for o in (self._gt.objects if self._gt else []) for w in _words(o.color_name)}
        scene_materials = {w for o in (self._gt.objects if self._gt else []) for w in _words(o.material)}
        out = []
        for text in texts:
            words = _words(text)
            classes, colors, materials = [], [], []
            i = 0
            while i < len(words):
                for n in (3, 2, 1):  # longest class phrase first ('dining table' before 'table')
                    phrase = " ".join(words[i : i + n])
                    cand = [phrase] + ([phrase[:-1]] if phrase.endswith("s") else [])
                    hit = next((c for c in cand if c in vocab or c in BACKGROUND_WORDS), None)
                    if len(words[i : i + n]) == n and hit is not None:
                        classes.append(hit)
                        i += n
                        break
                else:
                    w = words[i]
                    if w in COLOR_WORDS or w in scene_colors:
                        colors.append(w)
                    elif w in MATERIAL_WORDS or w in scene_materials:
                        materials.append(w)
                    i += 1
            v = self._compose(classes, colors, materials)
            if not np.any(v):
                v = self.word_vector("\0query\0" + text.strip().lower())  # unknown: a direction of its own
            out.append(v)
        v = np.stack(out).astype(np.float32)
        return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), np.float32(1e-12))
