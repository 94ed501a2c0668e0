"""The text side of the simulated perception models: real CLIP ViT-B/32 text embeddings of the LVIS names.

``pipeline/data/clip_text/`` (shipped with zipon) holds the CLIP ViT-B/32 text features of the prompt "a <name>" for the 1,203
LVIS v1 class names (Detic's metadata; see its README). Classes therefore relate as in CLIP
(chair-armchair 0.96, desk-table 0.93, cabinet-cupboard 0.93, mean pairwise 0.74).

What the table cannot give is written here, each a documented modelling choice:

- **simulated classes -> LVIS rows** (:data:`SIM_CLASS_LVIS`): each class of :mod:`pipeline.sim.catalog`
  is its LVIS name, or the mean of two rows where LVIS has no single name (nightstand = cabinet +
  drawer, picture = painting + poster, plant = flowerpot, shelf = bookcase, computer = monitor);
- **background words** ('floor', 'wall', 'ceiling', 'other', ...; no LVIS rows): one shared unit vector
  (the simulated frames' instance 0 holds walls, floor and ceiling alike) with cosine ~0.74 to the
  average LVIS row, like any other class (0.86 along the rows' mean direction, the rest a fixed random
  direction);
- **colours and materials** (no rows): a fixed random unit direction per colour phrase / material,
  added with weight 0.5 (colour) and 0.3 (material): "a red chair" vs "a chair" ~0.89, near CLIP's;
- personal names and unknown words carry nothing; a text with no known word gets a direction of its own.

A text is parsed longest phrase first (up to 4 words) against the simulated class names, LVIS names
and synonyms, colour phrases, materials and background words; its vector is
``normalise(sum(class rows) + 0.5 mean(colour dirs) + 0.3 mean(material dirs))``.
"""

from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np

from pipeline.encoders.oracle_text import BACKGROUND_WORDS, COLOR_WORDS, MATERIAL_WORDS
from pipeline.errors import InputDataError, MissingInputError
from pipeline.sim.catalog import COLOURS, MATERIALS

EMBEDDINGS_FILE = "lvis_v1_clip_vitb32_a+cname.npy"
NAMES_FILE = "lvis_v1_names.txt"
COLOR_WEIGHT, MATERIAL_WEIGHT = 0.5, 0.3
BACKGROUND_COS = 0.74  # a background word's cosine to the average LVIS row (CLIP's mean pairwise cosine)

#: simulated class -> the LVIS rows (names) whose normalised mean is its CLIP text feature
SIM_CLASS_LVIS: dict[str, tuple[str, ...]] = {
    "bed": ("bed",), "nightstand": ("cabinet", "drawer"), "wardrobe": ("wardrobe",), "chair": ("chair",),
    "armchair": ("armchair",), "table": ("table",), "desk": ("desk",), "couch": ("sofa",), "sofa": ("sofa",),
    "cabinet": ("cabinet",), "shelf": ("bookcase",), "tv": ("television_set",), "television": ("television_set",),
    "computer": ("computer_monitor",), "plant": ("flowerpot",), "lamp": ("lamp",),
    "toilet": ("toilet",), "sink": ("sink",), "fridge": ("refrigerator",), "refrigerator": ("refrigerator",),
    "stove": ("stove",), "bathtub": ("bathtub",), "microwave": ("microwave_oven",), "picture": ("painting", "poster"),
}


def _unit(v: np.ndarray) -> np.ndarray:
    return v / max(float(np.linalg.norm(v)), 1e-12)


def _random_direction(key: str, dim: int) -> np.ndarray:
    h = hashlib.blake2b(key.encode(), digest_size=8).digest()
    return _unit(np.random.default_rng(int.from_bytes(h, "little")).standard_normal(dim))


def _phrase(name: str) -> str:
    """LVIS name -> the words a user would type: 'monitor_(computer_equipment)' -> 'monitor'."""
    return " ".join(re.sub(r"\(.*?\)", " ", name.replace("_", " ")).lower().split())


@dataclass
class ParsedText:
    """A text's known parts: class rows (unit vectors), colour phrases, materials, background words."""

    classes: list[np.ndarray] = field(default_factory=list)
    class_names: list[str] = field(default_factory=list)
    colors: list[str] = field(default_factory=list)
    materials: list[str] = field(default_factory=list)


class ClipTextSpace:
    """CLIP ViT-B/32 text features of LVIS names + the documented extensions (see the module docstring)."""

    def __init__(self, folder: str | os.PathLike, param: str = "encoders.simulated_*.embeddings"):
        folder = Path(folder)
        emb_path, names_path = folder / EMBEDDINGS_FILE, folder / NAMES_FILE
        for p in (emb_path, names_path):
            if not p.is_file():
                raise MissingInputError(f"{param}: {p} not found (CLIP text embeddings of the LVIS names: "
                                        f"{EMBEDDINGS_FILE} and {NAMES_FILE})")
        try:
            emb = np.load(emb_path, allow_pickle=False)
            lines = names_path.read_text(encoding="utf-8").splitlines()
        except (ValueError, OSError, UnicodeDecodeError) as err:
            raise InputDataError(f"{param}: {emb_path if isinstance(err, ValueError) else names_path} cannot be read "
                                 f"({type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}); expected "
                                 f"a .npy float array (names, D) and a UTF-8 list of names") from None
        if emb.ndim != 2 or emb.shape[0] != len(lines) or emb.shape[1] < 2 or emb.dtype.kind != "f":
            raise InputDataError(f"{param}: {emb_path} holds a {emb.dtype} array of shape {emb.shape}; expected a "
                                 f"float array ({len(lines)}, D): one row per name line of {names_path}")
        emb = emb.astype(np.float64)
        norms = np.linalg.norm(emb, axis=1)
        if not np.all(np.isfinite(norms) & (norms > 0)):
            raise InputDataError(f"{param}: {emb_path}: row {int(np.argmin(np.isfinite(norms) & (norms > 0)))} is zero "
                                 f"or not finite; expected a text embedding in every row")
        self.path = emb_path
        self.rows = emb / norms[:, None]
        self.dim = int(self.rows.shape[1])
        self.names = [ln.split("\t")[0] for ln in lines]
        index: dict[str, int] = {}  # every LVIS name and synonym -> row
        self.vocab: dict[str, np.ndarray] = {}  # phrase -> unit vector
        for i, ln in enumerate(lines):
            # a few LVIS names hold two names separated by a space ('monitor_(computer_equipment) computer_monitor')
            for syn in " ".join([ln.split("\t")[0], *(ln.split("\t")[1].split("|") if "\t" in ln else [])]).split():
                index.setdefault(syn.strip(), i)
                self.vocab.setdefault(_phrase(syn), self.rows[i])
        for cls, lvis in SIM_CLASS_LVIS.items():
            self.vocab[cls] = _unit(self.rows[[index[n] for n in lvis]].mean(axis=0))
        mean_dir = _unit(self.rows.mean(axis=0))
        along = BACKGROUND_COS / float((self.rows @ mean_dir).mean())
        r = _random_direction("background", self.dim)
        r = _unit(r - (r @ mean_dir) * mean_dir)
        #: walls, floor, ceiling, 'other' (instance 0 of the simulated frames) share one feature
        self.background_vector = along * mean_dir + np.sqrt(1 - along**2) * r
        self.colors = {" ".join(c.split()) for c in COLOURS} | COLOR_WORDS | {"gray", "navy"}
        self.materials = set(MATERIALS) | MATERIAL_WORDS | {"wooden", "metallic"}

    # ------------------------------------------------------------------ pieces
    def attribute(self, phrase: str) -> np.ndarray:
        """Fixed random unit direction of a colour phrase or material (no CLIP row exists for them)."""
        phrase = {"gray": "grey", "wooden": "wood", "metallic": "metal"}.get(phrase, phrase)
        return _random_direction(f"attribute\0{phrase}", self.dim)

    def class_vector(self, cls: str) -> np.ndarray:
        """Unit CLIP feature of a (simulated or LVIS) class name; KeyError when unknown."""
        return self.vocab[" ".join(cls.lower().split())]

    def compose(self, classes: list[np.ndarray], colors: list[str], materials: list[str],
                color_weight: float = COLOR_WEIGHT, material_weight: float = MATERIAL_WEIGHT) -> np.ndarray:
        """``sum(classes) + color_weight mean(colour dirs) + material_weight mean(material dirs)`` (not normalised)."""
        v = np.zeros(self.dim)
        for c in classes:
            v = v + c
        if colors:
            v = v + color_weight * np.mean([self.attribute(c) for c in colors], axis=0)
        if materials:
            v = v + material_weight * np.mean([self.attribute(m) for m in materials], axis=0)
        return v

    # ------------------------------------------------------------------ text
    def parse(self, text: str) -> ParsedText:
        words = re.findall(r"[a-z]+", text.lower().replace("'s", " "))
        out = ParsedText()
        i = 0
        while i < len(words):
            for n in (4, 3, 2, 1):
                if i + n > len(words):
                    continue
                p = " ".join(words[i : i + n])
                if p in self.colors:
                    out.colors.append(p)
                elif p in self.materials:
                    out.materials.append(p)
                elif p in BACKGROUND_WORDS:
                    out.classes.append(self.background_vector)
                    out.class_names.append(p)
                elif p in self.vocab or (p.endswith("s") and p[:-1] in self.vocab):
                    key = p if p in self.vocab else p[:-1]
                    out.classes.append(self.vocab[key])
                    out.class_names.append(key)
                else:
                    continue
                i += n
                break
            else:
                i += 1
        return out

    def encode(self, text: str) -> np.ndarray:
        """Unit ``(D,)`` float64 feature of a text (see the module docstring)."""
        p = self.parse(text)
        v = self.compose(p.classes, p.colors, p.materials)
        if not np.any(v):
            return _random_direction("query\0" + " ".join(text.lower().split()), self.dim)
        return _unit(v)


#: CLIP's learned logit scale is 100, but cosine gaps in this space (a chair cell vs 'chair' / 'floor':
#: ~0.25) are ~2.5x those of real CLIP image-text pairs (~0.1), so logits use T = 0.025 to keep real margins.
TEMPERATURE = 0.025
#: version of each simulated perception model (its features change when it does)
VERSIONS = {"simulated_lseg": "2", "simulated_cf": "3"}


@lru_cache(maxsize=4)
def load_text_space(folder: str, param: str = "encoders.simulated_*.embeddings") -> ClipTextSpace:
    """One :class:`ClipTextSpace` per folder and process; errors name ``param``."""
    return ClipTextSpace(folder, param)


def shipped_embeddings() -> Path:
    """The folder of the CLIP ViT-B/32 LVIS text embeddings that ship with zipon (package data)."""
    return Path(str(resources.files("pipeline.data") / "clip_text"))


def resolve_embeddings(path: str | None, param: str) -> str:
    """The embeddings folder ``path`` names: ``None`` = the shipped one (:func:`shipped_embeddings`), else
    absolute or relative to the working directory; a one-line error naming ``param`` and the folder."""
    folder = shipped_embeddings() if path is None else Path(os.path.expanduser(path))
    folder = folder if folder.is_absolute() else Path.cwd() / folder
    if not (folder / EMBEDDINGS_FILE).is_file():
        raise MissingInputError(f"{param}: no {EMBEDDINGS_FILE} in {folder} (a folder of CLIP text embeddings of the "
                                f"LVIS names, as shipped in {shipped_embeddings()}; null uses those)")
    return str(folder.resolve())
