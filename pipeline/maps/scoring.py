"""Scores of stored float16 map features against text features, shared by :class:`~pipeline.maps.store.SemanticMap`,
:class:`~pipeline.maps.query.MapQuery` and :class:`~pipeline.maps.levels.LevelScorer` (a leaf: numpy only, it
imports nothing of the project, so scoring a map needs no torch)."""

from __future__ import annotations

import numpy as np


def chunked_scores(feats16: np.ndarray, text: np.ndarray, chunk_rows: int = 4096) -> np.ndarray:
    """``(N,T)`` float32 ``feats16 @ text.T`` for float16 ``feats16`` ``(N,D)`` and ``text`` ``(T,D)``.

    Each chunk of ``chunk_rows`` rows is upcast into one reused float32 buffer (8 MB at D = 512, so its pages
    are touched once and stay in cache) and multiplied with BLAS; numpy has no fast float16 product. Memory
    beyond the stored map is that buffer, never an fp32 copy of the map, whose first touch alone costs more
    than the products. The scores are exact float32 products of the stored fp16 features.
    """
    return chunked_scores_each(feats16, [text], chunk_rows)[0]


def chunked_scores_each(feats16: np.ndarray, texts: list[np.ndarray], chunk_rows: int = 4096) -> list[np.ndarray]:
    """``[(N,T_k) float32 feats16 @ texts[k].T]``: :func:`chunked_scores` of each text set, upcasting each chunk once.

    Each set is its own product, so its scores are the bytes :func:`chunked_scores` gives it alone: BLAS rounds a
    row's product by the shape of the call (a query's column scored with the background prompts in one ``(D,T+1)``
    product differs in the last bit from the same column scored alone), and by where the row falls in it, so a
    caller that must reproduce a whole array's scores block by block starts its blocks at multiples of
    ``chunk_rows``.
    """
    ts = [np.ascontiguousarray(np.asarray(t, np.float32)) for t in texts]
    n = feats16.shape[0]
    outs = [np.empty((n, t.shape[0]), dtype=np.float32) for t in ts]
    buf = np.empty((min(chunk_rows, n), feats16.shape[1]), dtype=np.float32)
    for s in range(0, n, chunk_rows):
        chunk = feats16[s : s + chunk_rows]
        b = buf[: len(chunk)]
        np.copyto(b, chunk)
        for t, out in zip(ts, outs):
            np.matmul(b, t.T, out=out[s : s + len(chunk)])
    return outs


def logsumexp(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """``log(sum(exp(x)))`` along ``axis`` without overflow (``-inf`` where every entry is ``-inf``)."""
    m = np.max(x, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    with np.errstate(divide="ignore"):
        return (np.log(np.sum(np.exp(x - m), axis=axis, keepdims=True)) + m).squeeze(axis)
