"""The fold cache of a map stage: the fold of the complete frame chunks fused so far, kept beside the map.

A map is built over fixed chunks of ``maps.chunk_frames`` frames (:func:`pipeline.maps.build.build_map`);
each chunk's partial accumulator is folded in chunk order. After the last COMPLETE chunk the fold is saved
here with one digest per chunk of what it read (frames, recon poses; see ``build.chunk_digest``) and a
key covering everything else (params and code digests, lattice, encoder identity, devices). A rerun whose
frames grew (a log appended to a scene) re-reads the stored chunks' frames to check their digests and,
when every one matches and the key is the same, folds the stored state and fuses only the frames after
it: the same floats as a build from scratch, since the fold is the same sequence of additions
(:mod:`pipeline.maps.fusion`). Any mismatch rebuilds from scratch. The last, incomplete chunk is always
recomputed.

Not an artifact: never hashed, published or tracked (``zipon verify`` ignores it); deleting it costs one
full rebuild, nothing else. It is as big as the map's accumulators (fp32 sums): ``run.map_fold_cache``
turns it off. Layout::

    data/artifacts/<scene>/.<stage>.fold/
      meta.json        {"format", "key", "chunk_frames", "chunks": [digest of chunk 0, ...],
                        "frames_fused", "pixels"}
      keys.npy sum.npy weight.npy count.npy [top.npy]    the FusionState (vlmap: top levels too) of floor 0
      floor<k>.keys.npy ...                              of floor k >= 1 of a building (meta "floors": their count)
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from pipeline.maps.fusion import FusionState

FORMAT = 1
_ARRAYS = ("keys", "sum", "weight", "count", "top")


@dataclass
class Fold:
    """The fold of chunks ``0 .. len(chunks) - 1`` and what they held."""

    key: str  # digest of everything but the frames (params, code, lattice, encoder, devices)
    chunk_frames: int
    chunks: list[str]  # digest of each chunk's frames and poses, in order
    states: list[FusionState]  # one per floor, lowest first
    frames_fused: int  # frames of those chunks that recon fused (the rest are skipped)
    pixels: int  # feature pixels that fell in the grid and height band

    @property
    def frames(self) -> int:
        """Frames covered (every stored chunk is complete)."""
        return len(self.chunks) * self.chunk_frames


def load_fold(path: Path, key: str, chunk_frames: int) -> Fold | None:
    """The fold stored at ``path`` if it was made with ``key`` and ``chunk_frames``; None when there is none, it
    is of another build or it cannot be read (a cache: never an error)."""
    try:
        meta = json.loads((path / "meta.json").read_text())
        if meta.get("format") != FORMAT or meta.get("key") != key or meta.get("chunk_frames") != chunk_frames:
            return None
        entries = meta["entries"] if isinstance(meta["entries"], list) else [meta["entries"]]
        states = [_load_state(path, _prefix(k), n) for k, n in enumerate(entries)]
        if any(state is None for state in states) or len(states) != meta.get("floors", 1):
            return None
        return Fold(key, chunk_frames, list(meta["chunks"]), states, int(meta["frames_fused"]), int(meta["pixels"]))
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _prefix(floor: int) -> str:
    """File name prefix of floor ``floor``'s arrays (none for floor 0: a single floor's fold as before floors)."""
    return "" if floor == 0 else f"floor{floor}."


def _load_state(path: Path, prefix: str, entries: int) -> FusionState | None:
    """One floor's stored state, None when its arrays disagree with the meta."""
    # mapped copy-on-write, not read: a stage standing in line for its turn to fuse (pipeline.engine.runner's
    # ordered_tasks) holds none of it; pages are read when the fold is merged
    arrays = {name: np.load(path / f"{prefix}{name}.npy", mmap_mode="c") for name in _ARRAYS
              if (path / f"{prefix}{name}.npy").exists()}
    n = len(arrays["keys"])
    if any(len(a) != n for a in arrays.values()) or n != entries:
        return None
    return FusionState(keys=arrays["keys"], sum=torch.from_numpy(arrays["sum"]),
                       weight=torch.from_numpy(arrays["weight"]), count=torch.from_numpy(arrays["count"]),
                       top=torch.from_numpy(arrays["top"]) if "top" in arrays else None)


def save_fold(path: Path, fold: Fold) -> None:
    """Write ``fold`` at ``path``, replacing what is there; written beside and renamed, so a crash leaves the
    old fold or none (never a half-written one that loads). The caller holds the stage's lock, so temporary
    folds left by a crashed run are removed here."""
    for stale in path.parent.glob(f"{path.name}.tmp-*"):
        shutil.rmtree(stale, ignore_errors=True)
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    tmp.mkdir(parents=True)
    for k, s in enumerate(fold.states):
        arrays = {"keys": s.keys, "sum": s.sum, "weight": s.weight, "count": s.count, "top": s.top}
        for name, a in arrays.items():
            if a is not None:
                np.save(tmp / f"{_prefix(k)}{name}.npy", a.numpy() if isinstance(a, torch.Tensor) else a)
    entries = [int(len(s.keys)) for s in fold.states]
    meta = {"format": FORMAT, "key": fold.key, "chunk_frames": fold.chunk_frames, "chunks": fold.chunks,
            "entries": entries[0] if len(entries) == 1 else entries, "frames_fused": fold.frames_fused,
            "pixels": fold.pixels, **({"floors": len(entries)} if len(entries) > 1 else {})}
    (tmp / "meta.json").write_text(json.dumps(meta, indent=1))
    shutil.rmtree(path, ignore_errors=True)
    os.replace(tmp, path)
