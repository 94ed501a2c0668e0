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
turns it off. It is written one spatial tile at a time while the build folds its tiles
(:mod:`pipeline.maps.tilefold`), beside the old one, and replaces it only when complete. Layout::

    data/artifacts/<scene>/.<stage>.fold/
      meta.json        {"format", "key", "chunk_frames", "chunks": [digest of chunk 0, ...],
                        "frames_fused", "pixels", "floors"}
      floor<k>.json floor<k>.tiles.npy floor<k>.<column>.bin     floor k's FusionState (keys, sum, weight,
                                                                 count[, top]) split by tile (pipeline.maps.spill)
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from pipeline.maps.spill import TileLayout, TileRows, TileRowsWriter, state_columns

FORMAT = 2


@dataclass
class Fold:
    """The fold of chunks ``0 .. len(chunks) - 1`` and what they held."""

    key: str  # digest of everything but the frames (params, code, lattice, encoder, devices)
    chunk_frames: int
    chunks: list[str]  # digest of each chunk's frames and poses, in order
    states: list[TileRows]  # one per floor, lowest first: its FusionState split by tile
    frames_fused: int  # frames of those chunks that recon fused (the rest are skipped)
    pixels: int  # feature pixels that fell in the grid and height band

    @property
    def frames(self) -> int:
        """Frames covered (every stored chunk is complete)."""
        return len(self.chunks) * self.chunk_frames


def load_fold(path: Path, key: str, chunk_frames: int, layouts: list[TileLayout]) -> Fold | None:
    """The fold stored at ``path`` if it was made with ``key`` and ``chunk_frames``, one state per floor of
    ``layouts`` cut in its tiles; None when there is none, it is of another build or it cannot be read (a cache:
    never an error). Nothing is read until a tile is folded."""
    try:
        meta = json.loads((path / "meta.json").read_text())
        if meta.get("format") != FORMAT or meta.get("key") != key or meta.get("chunk_frames") != chunk_frames:
            return None
        if meta.get("floors") != len(layouts):
            return None
        states = [TileRows(path, _floor(k)) for k in range(len(layouts))]
        if not all(state.fits(layout) for state, layout in zip(states, layouts)):
            return None
        return Fold(key, chunk_frames, list(meta["chunks"]), states, int(meta["frames_fused"]), int(meta["pixels"]))
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _floor(k: int) -> str:
    return f"floor{k}"


class FoldWriter:
    """The next fold of ``path``, one writer per floor (``floors[k]``: :meth:`TileRowsWriter.append` floor k's
    tiles in order, as :func:`~pipeline.maps.spill.write_state` does), written in a folder beside it;
    :meth:`commit` replaces the stored fold, so a crash leaves the old fold or none (never a half-written one
    that loads). The caller holds the stage's lock, so temporary folds left by a crashed run are removed here."""

    def __init__(self, path: Path, layouts: list[TileLayout], dim: int, *, top: bool):
        for stale in path.parent.glob(f"{path.name}.tmp-*"):
            shutil.rmtree(stale, ignore_errors=True)
        self.path = path
        self.tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
        self.tmp.mkdir(parents=True)
        self.floors = [TileRowsWriter(self.tmp, _floor(k), layout, state_columns(dim, top))
                       for k, layout in enumerate(layouts)]

    def commit(self, key: str, chunk_frames: int, chunks: list[str], frames_fused: int, pixels: int) -> None:
        for writer in self.floors:
            writer.close()
        meta = {"format": FORMAT, "key": key, "chunk_frames": chunk_frames, "chunks": chunks,
                "frames_fused": frames_fused, "pixels": pixels, "floors": len(self.floors)}
        (self.tmp / "meta.json").write_text(json.dumps(meta, indent=1))
        shutil.rmtree(self.path, ignore_errors=True)
        os.replace(self.tmp, self.path)

    def abort(self) -> None:
        """Drop what was written (the stored fold stays)."""
        for writer in self.floors:
            writer.abort()
        shutil.rmtree(self.tmp, ignore_errors=True)
