"""Scores of stored float16 map features against text features, shared by :class:`~pipeline.maps.store.SemanticMap`
and :class:`~pipeline.maps.levels.LevelScorer` (a leaf: it imports nothing of the project)."""

from __future__ import annotations

import torch


def chunked_scores(feats16: torch.Tensor, text: torch.Tensor, chunk_rows: int = 65536) -> torch.Tensor:
    """``(N,T)`` float32 ``feats16 @ text.T`` for float16 ``feats16`` ``(N,D)`` and ``text`` ``(T,D)``.

    The product runs in half precision on the stored fp16 features chunk by chunk (no fp32 copy of
    the map): on CPU an fp16 x fp16 product of a 360k x 512 map takes about 1.4x the fp32 time for
    one prompt and less than fp32 for four, while upcasting each chunk to fp32 first takes about 6x
    (benchmarks/bench_maps.py ``scores``). Error against fp32 scores of the same fp16 features:
    the fp16 rounding of the result (at most 2.5e-4 for scores in [-1, 1]).
    """
    t = text.to(feats16.dtype)
    out = torch.empty((feats16.shape[0], text.shape[0]), dtype=torch.float32)
    for s in range(0, feats16.shape[0], chunk_rows):
        out[s : s + chunk_rows] = feats16[s : s + chunk_rows] @ t.T
    return out
