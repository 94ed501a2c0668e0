"""Level-aware scores (``query.levels: max``) of a built cfmap, read block by block: seconds per call with and without
the background prompts, and the process's peak RSS (one JSON object per line).

    .venv/bin/python benchmarks/bench_levels.py --project DIR --scene S [--floor 0] [--texts chair table ...]
        [--hold-mb 0] [--repeats 2]

Opens floor ``--floor`` of scene S's ``cfmap.zarr`` in the project at DIR (read only: nothing is written there),
encodes the texts and the params' ``query.background`` prompts with the map's encoder
(:func:`~pipeline.maps.query.open_query`), and calls :meth:`~pipeline.maps.levels.LevelScorer.cell_scores` for each
text ``--repeats`` times with the background prompts and once without: the difference is what scoring the background
prompts in every query's pass costs (nothing per voxel is cached). ``--hold-mb`` as ``query.hold_features_mb``: from
the scorer's second call on, voxel features that fit it are held in memory (0: every call reads them).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from _common import emit, peak_rss_mb

from pipeline.maps.levels import LevelScorer
from pipeline.maps.query import open_query
from pipeline.paramsfile import load_params
from pipeline.paths import Workspace


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--project", type=Path, required=True, help="a project folder with a built cfmap")
    ap.add_argument("--scene", required=True)
    ap.add_argument("--floor", type=int, default=0)
    ap.add_argument("--texts", nargs="+", default=["chair", "table", "plant"])
    ap.add_argument("--hold-mb", type=float, default=0.0)
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    ws = Workspace.resolve(args.project / "params.yaml")
    params = load_params(ws.params_path)
    mq = open_query(ws.artifact("cfmap", args.scene), params, frames_path=ws.artifact("frames", args.scene),
                    floor=args.floor)
    smap, temp = mq.map, mq.temperature
    t0 = time.perf_counter()
    scorer = LevelScorer(smap, hold_mb=args.hold_mb)
    emit(what="map", voxels=scorer.n_voxels, blocks=scorer.n_blocks, cells=smap.n_cells, dim=smap.dim,
         voxel_features_mb=round(scorer.n_voxels * smap.dim * 2 / 2**20, 1),
         open_s=round(time.perf_counter() - t0, 3), peak_rss_mb=peak_rss_mb())
    background = mq.text_features(list(params.query.background))
    n = smap.n_cells
    top = np.zeros(n, np.float32), np.full(n, -np.inf, np.float32), np.full(n, -np.inf, np.float32)
    calls = 0
    for text in args.texts:
        q = mq.text_features([text])[0]
        bg = background[background @ q <= 0.99]
        for repeat in range(args.repeats):
            t0 = time.perf_counter()
            scorer.cell_scores(q, bg, temp, *top)
            calls += 1
            emit(what="cell_scores", text=text, background=len(bg), call=calls, held=scorer.held, seconds=round(time.perf_counter() - t0, 3), peak_rss_mb=peak_rss_mb())
        t0 = time.perf_counter()
        scorer.cell_scores(q, None, temp, *top)
        calls += 1
        emit(what="cell_scores", text=text, background=0, call=calls, held=scorer.held,
             seconds=round(time.perf_counter() - t0, 3), peak_rss_mb=peak_rss_mb())


if __name__ == "__main__":
    main()
