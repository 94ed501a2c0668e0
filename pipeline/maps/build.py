"""Build one semantic map from ``frames.zarr`` + ``recon.zarr``: the work of the vlmap/cfmap stages.

The frames are cut into fixed chunks of ``maps.chunk_frames`` by frame index. The unit of work,
:func:`fuse_chunk`, streams one chunk in blocks of ``maps.block_frames``, encodes each block in batches
of ``run.encoder_batch_size`` and fuses it with one vectorized scatter (:mod:`pipeline.maps.fusion`)
into the chunk's own accumulator; :func:`build_map` folds the chunks' states in chunk order. The chunks
run as dask tasks on every worker (the runner's ``StageContext.map_ordered``) or one after the other
(``sync``): the same partials folded in the same order, so the map's digest does not depend on the
scheduler or the number of workers. Memory is bounded by the map (observed cells / voxels), never by
the number of frames. Poses come from ``recon.zarr`` (the poses the geometry was fused with); frames
recon did not fuse are skipped and counted.

Why chunk tasks submitted from inside the stage rather than chunk nodes in the runner's graph: the
number of chunks is known only once ingest has run, after the graph of a ``zipon run`` is built; a
stage task that secedes and submits its chunks to its own cluster works on a local cluster
(``processes``) and a remote one (``tcp://``) alike, and the serial schedulers call the same
function. The fold of the complete chunks is kept beside the map (:mod:`pipeline.maps.incremental`)
so that frames appended to a scene are the only ones fused on the next run.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from pipeline.config import MapsParams, RunParams
from pipeline.maps.config import MapConfig
from pipeline.stageconfig import digest_value
from pipeline.errors import StageError
from pipeline.frames import FrameStore
from pipeline.prefetch import prefetched
from pipeline.store import DIGEST_ALGO, new_digest, update_array

FOLD_FORMAT = 3  # bump when the chunk digests or the fold's content change meaning


@dataclass(frozen=True)
class MapJob:
    """What every chunk of one map build reads (picklable: chunk tasks run on dask workers)."""

    config: MapConfig
    frames_path: Path
    recon_path: Path
    runtime: RunParams
    reads_rgb: bool  # the encoder reads the colour images (else they are neither decoded nor digested)
    scratch: Path | None = None  # where chunk tasks leave their states, split by tile (pipeline.maps.spill)


@dataclass
class ChunkResult:
    """One chunk of frames: the digest of what it read and, unless it was only digested, the names of its partial
    states in the job's scratch folder (one per floor, lowest first; :class:`~pipeline.maps.spill.TileRows`)."""

    index: int
    digest: str
    parts: list[str] | None = None
    frames_fused: int = 0
    pixels: int = 0


def chunk_ranges(n_frames: int, chunk_frames: int) -> list[tuple[int, int, int]]:
    """``(index, start, stop)`` of the fixed frame chunks ``[i * chunk_frames, (i + 1) * chunk_frames)``."""
    return [(i, s, min(s + chunk_frames, n_frames)) for i, s in enumerate(range(0, n_frames, chunk_frames))]


def floor_lattices(recon, p: MapsParams) -> tuple[list, list[tuple[float, float] | None]]:
    """One :class:`~pipeline.maps.store.Lattice` per floor of ``recon`` (its grid, above its ``floor_z``) and each
    floor's height band (world z ``(lo, hi)``, :func:`~pipeline.recon.store.floor_bands`; None for a single floor,
    which takes every height as before floors existed)."""
    from pipeline.maps.store import Lattice
    from pipeline.recon.store import floor_bands

    if len(recon.floors) == 1:
        return [Lattice(recon.grid, recon.floor_z, p.min_height_m, p.max_height_m, p.level_height_m)], [None]
    lattices = []
    for k in range(len(recon.floors)):
        view = recon.floor(k)
        lattices.append(Lattice(view.grid, view.floor_z, p.min_height_m, p.max_height_m, p.level_height_m))
    return lattices, [tuple(float(v) for v in band) for band in floor_bands(recon.floors)]


def _open_inputs(frames_path: Path, recon_path: Path, p: MapsParams):
    """(frame store, recon, poses ``(N,4,4)``, usable ``(N,)`` bool, lattices and height bands per floor) of one
    build."""
    from pipeline.recon import Recon

    fs = FrameStore(frames_path)
    recon = Recon(recon_path)
    if fs.n_frames != len(recon.fused):
        raise StageError(f"{recon_path}: holds {len(recon.fused)} poses but {frames_path} has {fs.n_frames} frames "
                         f"(recon from another frame store? rerun: zipon run --force --stage reconstruct)")
    poses = recon.poses
    usable = np.isfinite(poses).all(axis=(1, 2))  # a pose: fused by reconstruct, or a frame it passed over
    if p.keyframes_only:
        usable &= recon.fused
    lattices, bands = floor_lattices(recon, p)
    return fs, recon, poses, usable, lattices, bands


def fuse_chunk(job: MapJob, chunk: tuple[int, int, int], *, fuse: bool = True) -> ChunkResult:
    """The unit of work of a map stage: frames ``[start, stop)`` of ``chunk = (index, start, stop)`` streamed in
    blocks of ``maps.block_frames``, encoded once and fused into a fresh accumulator per floor (each floor takes
    the points of its height band); writes their states split by tile to ``job.scratch``
    (:func:`~pipeline.maps.spill.spill`) and returns their names with the digest of what the chunk read (colour
    if the encoder reads it, depth, instance masks, recon's poses and fused flags). ``fuse=False`` only reads and
    digests (checking a stored fold, :mod:`pipeline.maps.incremental`)."""
    import torch

    from pipeline.encoders import build_encoder
    from pipeline.encoders.base import resolve_device
    from pipeline.maps.fusion import TopDownAccumulator, VoxelAccumulator, locate_block, point_weights
    from pipeline.maps.spill import TileLayout, spill

    index, start, stop = chunk
    kind, p = job.config.kind, job.config.maps
    fs, _, poses, usable, lattices, bands = _open_inputs(job.frames_path, job.recon_path, p)
    digest = new_digest()
    update_array(digest, poses[start:stop])
    update_array(digest, usable[start:stop])
    encoder = accs = None
    if fuse and usable[start:stop].any():
        encoder = build_encoder(job.config.encoders, job.config.encoder, runtime=job.runtime)
        encoder.bind_scene(fs.ground_truth)
        device = resolve_device(job.runtime.fusion_device, "run.fusion_device")
        accs = [(VoxelAccumulator if kind.fuses_voxels else TopDownAccumulator)(lattice, encoder.dim, device=device)
                for lattice in lattices]
    sigma = kind.weight_sigma_m(p)
    fused_frames = pixels = 0
    with torch.inference_mode():
        blocks = fs.iter_blocks(p.block_frames, start=start, stop=stop, rgb=job.reads_rgb, instance=fs.has_instance)
        for block in prefetched(blocks, name="map-read"):  # the next block is read and decoded while this one is encoded
            for array in (block.rgb if job.reads_rgb else None, block.depth_mm, block.instance):
                if array is not None:
                    update_array(digest, array)
            ok = usable[block.start : block.start + len(block)]
            if encoder is None or not ok.any():
                continue
            sel = slice(None) if ok.all() else ok  # no copies of whole blocks
            depth = block.depth_m()[sel]
            dense = encoder.encode_images(block.rgb[sel], depth_m=depth,
                                          instance=None if block.instance is None else block.instance[sel])
            feature_depth, valid = dense.resample_depth(depth), dense.valid.numpy()
            intrinsics = dense.intrinsics(fs.intrinsics)
            for acc, lattice, band in zip(accs, lattices, bands):
                pts = locate_block(lattice, feature_depth, valid, poses[block.start : block.start + len(block)][ok],
                                   intrinsics, depth_min_m=p.depth_min_m, depth_max_m=p.depth_max_m,
                                   max_depth_jump=p.max_depth_jump, z_band=band)
                acc.add(pts, dense, point_weights(pts.dist_m, sigma))
                pixels += pts.n_fused
            fused_frames += int(ok.sum())
            del dense, pts  # a block's features (630 MB for 16 LSeg-sized frames) are gone before the next is encoded
    parts = None
    if fuse and accs is not None:
        parts = [f"chunk{index:05d}.floor{k}" for k in range(len(accs))]
        for k, lattice in enumerate(lattices):
            spill(accs[k], TileLayout(lattice.grid, p.tile_cells), job.scratch, parts[k])
            accs[k] = None  # freed before the next floor's rows are gathered
    return ChunkResult(index, f"{DIGEST_ALGO}:{digest.hexdigest()}", parts, fused_frames, pixels)


def build_map(
    config: MapConfig,
    frames_path: Path,
    recon_path: Path,
    out_path: Path,
    attrs: dict,
    *,
    runtime: RunParams | None = None,
    progress: Callable[[Iterable, int, str], Iterable] | None = None,
    map_ordered: Callable[[Callable, list], Iterable] | None = None,
    fold_path: Path | None = None,
    fold_key: dict | None = None,
    log: Callable[[str], None] = lambda message: None,
) -> dict:
    """Fuse every frame into a new map store at ``out_path``; returns the summary figures.

    The frames are cut into fixed chunks of ``maps.chunk_frames`` (by frame index, whatever runs them); each
    chunk is fused by :func:`fuse_chunk` into its own accumulator, which it leaves split by spatial tile in a
    scratch folder beside ``out_path``; then each floor is folded one tile at a time, the chunks' rows of the tile
    in chunk order (:mod:`pipeline.maps.tilefold`), so the map is the same float for float however many workers
    ran the chunks, and streamed into the store. ``map_ordered(fn, items)`` must yield ``fn(item)`` in item
    order; the stages pass the runner's ``StageContext.map_ordered`` (tasks on every dask worker); default: one
    chunk after the other, here. Memory: the chunks in flight (each bounded by the cells / voxels its frames saw)
    and one tile, never the floor's area nor the number of frames. Disk: the chunks' fp32 sums, until the map is
    written. On any error neither the store nor the scratch folder is left behind.

    With ``fold_path``, the fold of the complete chunks is kept there (:mod:`pipeline.maps.incremental`), keyed
    by ``fold_key`` (what else the map depends on: the stage's params and code digests) with the lattice, the
    encoder's identity and the devices. When the frames grow, the stored chunks are re-read and digested and, if
    each matches, only the frames after them are fused.
    """
    import shutil

    import torch

    from pipeline.encoders import build_encoder
    from pipeline.encoders.base import resolve_device
    from pipeline.maps.incremental import FoldWriter, load_fold
    from pipeline.maps.spill import TileLayout, TileRows
    from pipeline.maps.tilefold import fold_floor, write_floor
    from pipeline.maps.writer import create_map

    kind, p, runtime = config.kind, config.maps, runtime or RunParams()
    fs, recon, _, _, lattices, _ = _open_inputs(frames_path, recon_path, p)
    encoder = build_encoder(config.encoders, config.encoder, runtime=runtime)
    identity, reads_rgb, encoder_device = encoder.identity(), encoder.reads_rgb, str(encoder.device)
    del encoder  # each chunk task builds its own
    out_path = Path(out_path)
    scratch = out_path.with_name(f".{out_path.name}.scratch")
    job = MapJob(config, Path(frames_path), Path(recon_path), runtime, reads_rgb, scratch)
    run = map_ordered or (lambda fn, items: map(fn, items))
    chunks = chunk_ranges(fs.n_frames, p.chunk_frames)
    complete = fs.n_frames // p.chunk_frames
    device = resolve_device(runtime.fusion_device, "run.fusion_device")
    layouts = [TileLayout(lattice.grid, p.tile_cells) for lattice in lattices]
    key = digest_value({"format": FOLD_FORMAT, **(fold_key or {}), "encoder": identity, "lattice": lattices[0].to_attrs(),
                        "grid": [recon.grid.rows, recon.grid.cols, recon.grid.cell_size_m, list(recon.grid.origin_xy)],
                        "intrinsics": fs.meta.intrinsics.to_dict(), "ground_truth": digest_value(fs.meta.ground_truth),
                        "devices": [encoder_device, device], "encoder_batch": runtime.encoder_batch_size,
                        "torch": torch.__version__, "tile_cells": p.tile_cells,
                        **({"floors": [[lat.to_attrs(), lat.grid.to_attrs()] for lat in lattices[1:]]}
                           if len(lattices) > 1 else {})})
    digests: list[str] = []
    fused_frames = pixels = reused = 0
    parts: list[list[TileRows]] = [[] for _ in lattices]  # per floor, in chunk order
    stored = load_fold(fold_path, key, p.chunk_frames, layouts) if fold_path is not None else None
    if stored is not None and 0 < len(stored.chunks) <= complete:
        checks = run(functools.partial(fuse_chunk, job, fuse=False), chunks[: len(stored.chunks)])
        try:
            changed = next((c for c, d in zip(checks, stored.chunks) if c.digest != d), None)  # the first mismatch
        finally:
            getattr(checks, "close", lambda: None)()
        if changed is None:
            for floor_parts, state in zip(parts, stored.states):
                floor_parts.append(state)
            digests, fused_frames, pixels, reused = list(stored.chunks), stored.frames_fused, stored.pixels, len(stored.chunks)
            log(f"reusing the fold of frames 0-{stored.frames - 1} ({fold_path.name}); fusing {fs.n_frames - stored.frames}")
        else:
            log(f"frames or poses of chunk {changed.index} (frames {chunks[changed.index][1]}-"
                f"{chunks[changed.index][2] - 1}) changed since {fold_path.name} was kept: fusing every frame")
    cache = None
    created = False
    try:
        scratch.mkdir(parents=True, exist_ok=True)
        results = run(functools.partial(fuse_chunk, job), chunks[reused:])
        if progress is not None:
            results = progress(results, len(chunks) - reused, "fusing")
        for chunk in results:
            for floor_parts, name in zip(parts, chunk.parts or ()):
                floor_parts.append(TileRows(scratch, name))
            fused_frames, pixels = fused_frames + chunk.frames_fused, pixels + chunk.pixels
            digests.append(chunk.digest)
            if chunk.index == complete - 1:
                fold_counts = (fused_frames, pixels)  # what the fold of the complete chunks holds
        if fold_path is not None and complete > reused:  # new complete chunks: keep the fold of all of them
            cache = FoldWriter(fold_path, layouts, identity["dim"], top=not kind.fuses_voxels)
        folds = []
        for k, (lattice, layout) in enumerate(zip(lattices, layouts)):
            # the parts of the complete chunks: the stored fold's (one part) and those fused now
            cache_after = (1 if reused else 0) + complete - reused
            folds.append(fold_floor(parts[k], lattice, layout, identity["dim"], scratch, f"floor{k}",
                                    voxels=kind.fuses_voxels, keep_voxels=kind.fuses_voxels and p.cfmap_voxels,
                                    device=device, cache=None if cache is None else cache.floors[k],
                                    cache_after=cache_after))
        if cache is not None:
            cache.commit(key, p.chunk_frames, digests[:complete], *fold_counts)
            cache = None
        spilled = sum(part.nbytes for floor_parts in parts for part in floor_parts)
        layers, fills, summary = _plan(p, recon, frames_path, folds, lattices, log)
        full_attrs = {**attrs, "encoder": identity, "weighting": {"sigma_m": kind.weight_sigma_m(p)},
                      "frames": {"n_frames": fs.n_frames, "fused": fused_frames, "keyframes_only": p.keyframes_only},
                      "points_fused": folds[0].points, "pixels_in_band": int(pixels),
                      "cells_observed": folds[0].cells_observed, "cells_filled": len(fills[0]),
                      "fill_radius_m": p.fill_radius_m}
        writers = create_map(out_path, full_attrs, layers, tile_cells=p.tile_cells, floors=list(recon.floors))
        created = True
        for writer, fold, fill in zip(writers, folds, fills):
            write_floor(writer, fold, fill)
    except BaseException:
        if cache is not None:
            cache.abort()
        if created:
            shutil.rmtree(out_path, ignore_errors=True)  # never a half-written store
        raise
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    frames_reused = min(reused * p.chunk_frames, fs.n_frames)
    return {**summary, "spilled_mb": round(spilled / 2**20, 1),  # the chunk states (and a reused fold) on disk
            "frames_fused": fused_frames, "frames_skipped": fs.n_frames - fused_frames,
            "keyframes_only": p.keyframes_only, "chunks": len(chunks), "chunks_reused": reused,
            "frames_reused": frames_reused, "frames_processed": fs.n_frames - frames_reused,
            "encoder": identity["name"], "diagnostic_encoder": bool(identity.get("diagnostic", False))}


def _plan(p: MapsParams, recon, frames_path: Path, folds: list, lattices: list, log: Callable[[str], None]):
    """Each floor's :class:`~pipeline.maps.writer.LayerShape` and :class:`~pipeline.maps.tilefold.FillPlan` (unseen
    tops filled within ``maps.fill_radius_m`` where that floor's recon grid is not free) and the map's summary
    figures; an error when no floor holds a cell, a warning per empty floor of a building."""
    from pipeline.maps.tilefold import plan_fill
    from pipeline.maps.writer import LayerShape
    from pipeline.recon import FREE

    fills = []
    for k, fold in enumerate(folds):
        occupancy = recon.occupancy if k == 0 else recon.floor(k).occupancy
        fills.append(plan_fill(fold, occupancy != FREE, p.fill_radius_m))
    n_cells = [fold.cells_observed + len(fill) for fold, fill in zip(folds, fills)]
    if sum(n_cells) == 0:
        raise StageError(f"{frames_path}: no pixel fell inside the grid and height band; nothing to map "
                         f"(check maps.depth_* / maps.*_height_m and the recon grid)")
    building = len(folds) > 1
    floors = list(recon.floors)
    warnings = [f"floor {f.id} ({f.name}, {f.floor_z_m:.2f} m): no pixel fell in its height band; its map is empty"
                for f, n in zip(floors, n_cells) if building and not n]
    for line in warnings:
        log(f"warning: {line}")
    layers, per_floor = [], []
    for k, (fold, fill, lattice) in enumerate(zip(folds, fills, lattices)):
        figures = {"points_fused": fold.points, "cells_observed": fold.cells_observed, "cells_filled": len(fill)}
        n_voxels = None if fold.voxels is None else fold.voxels.rows
        layers.append(LayerShape(lattice.grid, lattice, n_cells[k], fold.cells.columns["features"][1][0],
                                 n_voxels, floor=floors[k], figures=figures))
        per_floor.append({"id": floors[k].id, "name": floors[k].name, "cells": n_cells[k], "voxels": n_voxels or 0,
                          **figures, "observed_area_m2": round(n_cells[k] * lattice.grid.cell_size_m**2, 3)})
    summary = {"cells": sum(n_cells), "cells_filled": sum(len(fill) for fill in fills),
               "voxels": sum(f["voxels"] for f in per_floor), "points_fused": sum(fold.points for fold in folds),
               "observed_area_m2": round(sum(n * lat.grid.cell_size_m**2 for n, lat in zip(n_cells, lattices)), 3),
               **({"floors": per_floor} if building else {}), **({"warnings": warnings} if warnings else {})}
    return layers, fills, summary
