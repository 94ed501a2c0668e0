"""ORION's memory: positive and negative 2-D maps of text features painted on object footprints.

As in navchat's ``retrieve_memory``: ``update_memory(cells, pos_str, neg_str)`` adds the text
feature of ``pos_str`` to the running mean of every footprint cell of the positive map (and
``neg_str`` to the negative map); ``retrieve_memory(obj_str)`` returns the painted regions whose
positive feature matches ``obj_str`` (cosine >= ``threshold``), dropping a region when its negative
feature matches at least as well (a positive hit close to a negative one is dropped).

Text features: the configured encoder's text feature concatenated with a deterministic lexical
bag-of-words feature (each word a seeded random unit vector), each half weighted 1/sqrt(2). The
lexical half keeps personal names apart ("Alice's chair" vs "Bob's chair"), which class-level
encoders (and the oracle) map to the same point. Maps are sparse: only painted cells are stored.

Regions are keyed by place, not by an episode's object ids: :meth:`MemoryMaps.region_key` gives the
region whose centre is within ``merge_m`` of an object's centre on the same floor (or a new one), so one memory is
carried across the goals of a scene (as in the paper) and each episode maps remembered regions
back into its own object registry. In a building the caller gives each floor's cells apart (shifted by the floor
times the grid's cell count), so the floors' paint never mixes.
"""

from __future__ import annotations

import hashlib
import math
import re

import numpy as np


def lexical_feature(text: str, dim: int = 256) -> np.ndarray:
    """``(dim,)`` float64 unit bag-of-words feature of ``text`` (lower-case words, deterministic)."""
    v = np.zeros(dim)
    for w in re.findall(r"[a-z0-9]+", text.lower()):
        seed = int.from_bytes(hashlib.blake2b(w.encode(), digest_size=8).digest(), "little")
        v += np.random.default_rng(seed).standard_normal(dim)
    n = np.linalg.norm(v)
    return v / n if n > 0 else v


class MemoryMaps:
    """Sparse positive/negative feature maps over the grid's flat cell ids."""

    def __init__(self, encode_text, *, threshold: float = 0.95, merge_m: float = 0.6):
        self.encode_text = encode_text  # list[str] -> (T,D) unit features
        self.threshold = float(threshold)
        self._feat: dict[str, np.ndarray] = {}
        # per map: flat cell -> [sum (D,), count]
        self.maps: dict[str, dict[int, list]] = {"pos": {}, "neg": {}}
        self.regions: dict[int, np.ndarray] = {}  # region key -> flat cells
        self.centers: dict[int, np.ndarray] = {}  # region key -> (2,) world centre
        self.floors: dict[int, int] = {}  # region key -> its floor (a building; 0 otherwise)
        self.merge_m = float(merge_m)

    def region_key(self, center_xy, floor: int = 0) -> int:
        """The key of the remembered region on ``floor`` centred within ``merge_m`` of ``center_xy`` (else a new
        key)."""
        c = np.asarray(center_xy, np.float64)
        for k in sorted(self.centers):
            if self.floors.get(k, 0) == floor and np.linalg.norm(self.centers[k] - c) <= self.merge_m:
                return k
        k = len(self.centers) + 1
        self.centers[k] = c.copy()
        if floor:
            self.floors[k] = int(floor)
        return k

    def feature(self, text: str) -> np.ndarray:
        if text not in self._feat:
            enc = np.asarray(self.encode_text([text])[0], dtype=np.float64)
            self._feat[text] = np.concatenate([enc, lexical_feature(text)]) / math.sqrt(2.0)
        return self._feat[text]

    def update(self, obj_id: int, cells: np.ndarray, pos_str: str | None, neg_str: str | None) -> None:
        """Paint ``pos_str`` / ``neg_str`` on the flat ``cells`` of region ``obj_id`` (a :meth:`region_key`)."""
        cells = np.unique(np.asarray(cells, np.int64))
        self.regions[obj_id] = cells
        for which, text in (("pos", pos_str), ("neg", neg_str)):
            if not text:
                continue
            f = self.feature(text)
            m = self.maps[which]
            for c in cells.tolist():
                slot = m.get(c)
                if slot is None:
                    m[c] = [f.copy(), 1]
                else:
                    slot[0] += f
                    slot[1] += 1

    def _score(self, which: str, cells: np.ndarray, q: np.ndarray) -> float:
        m = self.maps[which]
        vals = [m[c][0] / m[c][1] for c in cells.tolist() if c in m]
        if not vals:
            return -math.inf
        mean = np.mean(vals, axis=0)
        n = np.linalg.norm(mean)
        return float(mean @ q / n) if n > 0 else -math.inf

    def retrieve(self, obj_str: str) -> tuple[list[int], list[int]]:
        """``(positive obj_ids, negative obj_ids)`` for ``obj_str`` (see the module docstring)."""
        q = self.feature(obj_str)
        pos, neg = [], []
        for oid, cells in sorted(self.regions.items()):
            sp, sn = self._score("pos", cells, q), self._score("neg", cells, q)
            if sn >= self.threshold and sn >= sp:
                neg.append(oid)
            elif sp >= self.threshold:
                pos.append(oid)
        return pos, neg
