"""Scores of stored float16 map features against text features, shared by :class:`~pipeline.maps.store.SemanticMap`,
:class:`~pipeline.maps.query.MapQuery` and :class:`~pipeline.maps.levels.LevelScorer` (a leaf: numpy only, it
imports nothing of the project, so scoring a map needs no torch)."""

from __future__ import annotations

import numpy as np


_F16_TO_F32: np.ndarray | None = None


def upcast(feats16: np.ndarray) -> np.ndarray:
    """``feats16`` float16 as float32, exactly (one look-up per value in a 65,536-entry table: about twice as fast
    as ``astype`` on CPUs where numpy converts half floats one by one)."""
    global _F16_TO_F32
    if _F16_TO_F32 is None:
        _F16_TO_F32 = np.arange(1 << 16, dtype=np.uint16).view(np.float16).astype(np.float32)
    bits = np.ascontiguousarray(feats16, dtype=np.float16).view(np.uint16)
    out = np.empty(bits.shape, np.float32)
    flat_bits, flat_out = bits.reshape(-1), out.reshape(-1)
    for s in range(0, flat_bits.size, 1 << 21):  # 2M values a time: the int64 index temporaries stay at 16 MB
        np.take(_F16_TO_F32, flat_bits[s : s + (1 << 21)], out=flat_out[s : s + (1 << 21)])
    return out


def chunked_scores(feats16: np.ndarray, text: np.ndarray, chunk_rows: int = 65536) -> np.ndarray:
    """``(N,T)`` float32 ``feats16 @ text.T`` for float16 ``feats16`` ``(N,D)`` and ``text`` ``(T,D)``.

    Each chunk of ``chunk_rows`` rows is upcast to float32 and multiplied with BLAS (numpy has no fast
    float16 product), so memory beyond the stored map is one fp32 chunk (128 MB at D = 512), never an fp32
    copy of the map. The scores are exact float32 products of the stored fp16 features.
    """
    t = np.ascontiguousarray(np.asarray(text, np.float32))
    out = np.empty((feats16.shape[0], t.shape[0]), dtype=np.float32)
    for s in range(0, feats16.shape[0], chunk_rows):
        np.matmul(upcast(feats16[s : s + chunk_rows]), t.T, out=out[s : s + chunk_rows])
    return out


def logsumexp(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """``log(sum(exp(x)))`` along ``axis`` without overflow (``-inf`` where every entry is ``-inf``)."""
    m = np.max(x, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    with np.errstate(divide="ignore"):
        return (np.log(np.sum(np.exp(x - m), axis=axis, keepdims=True)) + m).squeeze(axis)
