"""The Python API's round trip on a built workspace: import + open, first query, repeated queries, xarray views,
and the viewer's recording of the scene.

    .venv/bin/python benchmarks/bench_api.py PATH [--scene S] [--rrd OUT.rrd]

PATH is what ``zipon.open`` takes (a params.yaml, its folder, or a data root). Prints one JSON object per line:

- ``api``: seconds for ``import zipon`` + ``zipon.open`` + the scene's readers; the first ``vlmap.query`` (imports
  torch and the encoders, builds the text encoder, loads the map's features) split into ``first_query_imports_s``
  (importing :mod:`pipeline.maps.query` and :mod:`pipeline.encoders`) and the rest; the median of five further
  queries; ``to_xarray`` (lazy dense grid) and reading one cell's feature vector from it;
- ``viewer`` (with ``--rrd``): seconds and bytes of ``zipon view`` for the scene (no episode).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from _common import emit


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("path", help="params.yaml, its folder, or a data root")
    ap.add_argument("--scene", help="scene name (default: the first)")
    ap.add_argument("--rrd", type=Path, help="also write the scene's rerun recording here and time it")
    args = ap.parse_args()

    t0 = time.perf_counter()
    import zipon

    ds = zipon.open(args.path)
    scene = ds[args.scene] if args.scene else ds.scenes[0]
    goal = scene.goals.goals[0]
    cls = scene.goals.objects[goal.object_keys[0]].cls
    pose = scene.episodes[0].start
    t_open = time.perf_counter() - t0

    t1 = time.perf_counter()
    import pipeline.encoders  # noqa: F401
    import pipeline.maps.query  # noqa: F401

    t_imports = time.perf_counter() - t1
    result = scene.vlmap.query(cls, pose=pose)
    t_first = time.perf_counter() - t1
    repeats = []
    for text in ("chair", "table", "bed", "sofa", "plant"):
        t = time.perf_counter()
        scene.vlmap.query(text, pose=pose)
        repeats.append(time.perf_counter() - t)
    t = time.perf_counter()
    grid = scene.vlmap.to_xarray()
    t_x = time.perf_counter() - t
    t = time.perf_counter()
    grid.features.sel(x=goal.mass_center[0], y=goal.mass_center[1], method="nearest").values
    t_sel = time.perf_counter() - t
    store = scene.vlmap.store
    emit(api={"scene": scene.name, "cells": store.n_cells, "dim": store.dim,
              "import_open_s": round(t_open, 2), "first_query_s": round(t_first, 2),
              "first_query_imports_s": round(t_imports, 2),
              "repeat_query_median_s": round(statistics.median(repeats), 4),
              "to_xarray_s": round(t_x, 2), "one_cell_sel_s": round(t_sel, 3),
              "candidates": len(result.candidates)})
    if args.rrd:
        from pipeline.viewer import write_recording

        t = time.perf_counter()
        s = write_recording(ds.workspace, ds.params, scene.name, args.rrd)
        emit(viewer={"seconds": round(time.perf_counter() - t, 1), "bytes": s["bytes"],
                     "frames": s["frames"], "mesh_vertices": s.get("mesh_vertices")})


if __name__ == "__main__":
    main()
