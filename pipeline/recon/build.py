"""Reconstruction: ``frames.zarr`` -> ``recon.zarr`` + ``recon_mesh.ply`` + ``recon_points.ply`` (the work of the
``reconstruct`` stage).

TSDF fusion of every frame (streamed in blocks; optional frame-to-model pose refinement), then
the mesh and surface points, the floors (:mod:`pipeline.recon.floors`), each floor's top-down grids
(occupancy, navigable, colour, height) on the project grid and the stairs joining them
(:mod:`pipeline.recon.stairs`). The format is documented in :mod:`pipeline.recon.store`.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

from pipeline.config import GridParams, ReconstructParams
from pipeline.stageconfig import digest_value
from pipeline.errors import StageError
from pipeline.frames import FrameStore
from pipeline.recon import grids as grids_mod
from pipeline.recon.floors import find_floors
from pipeline.recon.stairs import find_flights, stair_links, unlinked_warnings
from pipeline.recon.store import ARTIFACT, FORMAT_VERSION, floor_bands, write_mesh, write_recon
from pipeline.recon.surface import Surface
from pipeline.store import artifact_attrs


def reconstruct(frames_path: Path, recon_path: Path, mesh_path: Path, points_path: Path,
                p: ReconstructParams, grid: GridParams, *, frames: Sequence[int] | None = None,
                params_digest: str | None = None, tile_m: float = 0.0, log: Callable[[str], None] = lambda m: None,
                progress=None) -> dict:
    """Fuse ``frames_path`` (``frames``: a subset of frame indices; default all) and write the outputs.

    ``tile_m`` > 0 fuses in tiles of that side (:mod:`pipeline.recon.tiles`: memory bounded by a tile, the same
    outputs); 0 fuses one volume. Returns the summary figures (the stage's manifest summary).
    """
    from pipeline.recon import tiles

    with tiles.spill_dir(recon_path) as workdir:
        return _reconstruct(frames_path, recon_path, mesh_path, points_path, p, grid, frames=frames,
                            params_digest=params_digest, tile_m=tile_m, workdir=Path(workdir), log=log,
                            progress=progress)


def _reconstruct(frames_path: Path, recon_path: Path, mesh_path: Path, points_path: Path, p: ReconstructParams,
                 grid: GridParams, *, frames, params_digest, tile_m: float, workdir: Path, log, progress) -> dict:
    from pipeline.recon import tiles, tsdf  # open3d: imported by the work, not by the stage's config (zipon status)
    from pipeline.recon.refine import PoseRefiner

    store = FrameStore(frames_path)
    grids_mod.lattice_ratio(grid, p)  # fail on a bad voxel/cell pairing before the long part
    t0 = time.perf_counter()
    refiner = PoseRefiner(p) if p.refine_poses else None
    tiled = None
    if tile_m > 0 and refiner is None:
        tiled = tiles.fuse_tiled(store, p, tile_m, workdir, frames=frames, progress=progress)
    fusion = tiled or tsdf.fuse(store, p, frames=frames, refiner=refiner, progress=progress)
    t_fuse = time.perf_counter() - t0
    if fusion.empty_frames:
        log(f"warning: {len(fusion.empty_frames)} frames without valid depth skipped (first: {fusion.empty_frames[0]})")

    t1 = time.perf_counter()
    if tiled is not None:
        surface, voxels, n_triangles = tiled.surface, tiled.voxels, tiled.n_triangles
        log(f"fused in {tiled.tiles_fused} tiles of {tiled.layout.tile_blocks * tiled.layout.block_m:g} m "
            f"(at most {tiled.peak_blocks} of {tiled.n_blocks} TSDF blocks held at once)")
    else:
        mesh = tsdf.extract_mesh(fusion.volume, p)
        surface = Surface.of(*tsdf.extract_points(fusion.volume, p, canonical=False))  # Surface sorts them
        voxels = lambda: tsdf.iter_voxels(fusion.volume, p, min_weight=p.occupancy_min_weight)  # noqa: E731
        n_triangles = len(mesh.triangles)
    if n_triangles == 0 or surface.count == 0:
        if len(fusion.frames_fused) == 1:
            raise StageError(f"{frames_path}: a single frame was fused (frame {fusion.frames_fused[0]}): a place counts "
                             f"as seen in {p.min_weight:g}+ frames (reconstruct.min_weight), so one frame maps "
                             "nothing; record more frames of the scene")
        raise StageError(f"{frames_path}: the fused volume has no surface ({len(fusion.frames_fused)} frames fused); "
                         f"an empty scene, or no place seen in {p.min_weight:g}+ frames (reconstruct.min_weight)")
    mesh_info = tiled.write_mesh(mesh_path) if tiled is not None else write_mesh(mesh_path, mesh)
    points_info = surface.write_ply(points_path)
    mesh = None
    t_extract = time.perf_counter() - t1

    t2 = time.perf_counter()
    found, spec, per_floor, stairs, warnings = floors_grids_stairs(
        surface, voxels, fusion.T_world_camera, grid, p, source=str(frames_path), whole_columns=tiled is not None)
    building = len(found.floors) > 1
    t_grids = time.perf_counter() - t2
    grids = per_floor[0]
    outside = sum(g.stats["points_outside_grid"] for g in per_floor)
    if outside:
        log(f"warning: {outside} surface points lie outside the grid "
            f"({outside / surface.count:.2%}); they are counted, not mapped")
    for line in warnings:
        log(f"warning: {line}")

    poses = np.full((store.n_frames, 4, 4), np.nan)
    fused = np.zeros(store.n_frames, dtype=bool)
    for i, T in fusion.T_world_camera.items():
        poses[i], fused[i] = T, True
    for i, T in fusion.not_keyframes.items():  # a pose, not fused: the maps may still read them
        poses[i] = T
    keyframes = keyframe_summary(p, fusion)
    recorded = store.poses().astype(np.float64)
    moved = np.linalg.norm(poses[fused, :3, 3] - recorded[fused, :3, 3], axis=1)
    refinement = {"enabled": p.refine_poses, "max_moved_m": round(float(moved.max()), 5),
                  "median_moved_m": round(float(np.median(moved)), 5)}
    if refiner is not None:
        refinement.update(refiner.summary())
    figures = {
        "frames": store.n_frames,
        "frames_fused": len(fusion.frames_fused),
        "frames_empty": len(fusion.empty_frames),
        "tsdf_blocks": fusion.n_blocks,
        "mesh_vertices": mesh_info["vertices"],
        "mesh_triangles": mesh_info["triangles"],
        "bounds_min": mesh_info["bounds_min"],
        "bounds_max": mesh_info["bounds_max"],
        "points": points_info["count"],
        **grids.stats,
        "grid_origin_xy": [round(v, 4) for v in grids.grid.origin_xy],
        "grid_shape": [spec.rows, spec.cols],
        "floors": [f.model_dump(mode="json") for f in found.floors],
        "floor_evidence": found.figures,
        **({"floor_stats": {str(f.id): g.stats for f, g in zip(found.floors[1:], per_floor[1:])},
            "stairs": [{"id": s.id, "kind": s.kind, "floors": [s.bottom.floor, s.top.floor], "rise_m": s.rise_m,
                        "length_m": s.length_m, "bottom_endpoint": list(s.bottom.endpoint),
                        "top_endpoint": list(s.top.endpoint)} for s in stairs]} if building else {}),
        **({"warnings": warnings} if warnings else {}),
        "seconds_fuse": round(t_fuse, 3),
        "seconds_extract": round(t_extract, 3),
        "seconds_grids": round(t_grids, 3),
        "frames_per_s": round(len(fusion.frames_fused) / max(t_fuse, 1e-9), 2),
        "refinement": refinement,
        "keyframes": keyframes,
        **({"tiles": tiled.summary()} if tiled is not None else {}),
    }
    attrs = artifact_attrs(
        ARTIFACT, FORMAT_VERSION, "reconstruct", params_digest or digest_value(p.model_dump(mode="json")),
        floor_estimated=p.floor_z_m is None and p.floors is None,
        robot_radius_m=p.robot_radius_m,
        height_band_m=[p.obstacle_min_height_m, p.obstacle_max_height_m],
        tsdf={"voxel_size_m": p.voxel_size_m, "sdf_trunc_m": p.sdf_trunc_m, "min_weight": p.min_weight,
              "occupancy_min_weight": p.occupancy_min_weight, "depth_range_m": [p.depth_min_m, p.depth_max_m],
              "depth_stride": tsdf.fusion_stride(p, store.intrinsics), "blocks": fusion.n_blocks},
        mesh=mesh_info, points=points_info,
        frames={"n_frames": store.n_frames, "fused": len(fusion.frames_fused), "empty": fusion.empty_frames[:100]},
        refinement=refinement,
        keyframes=keyframes,
        conventions={"world": "right-handed, z up, metres (as frames.zarr)", "grid": grids.grid.ORIENTATION},
        source_frames_attrs=store.meta.model_dump(include={"conventions", "provenance"}, exclude_unset=True),
    )
    write_recon(recon_path, per_floor, poses, fused, attrs, stairs=stairs,
                floors=found.floors if building or p.floors is not None else None)
    return figures


def floors_grids_stairs(surface: Surface, voxels: Callable[[], Iterable], T_world_camera: dict[int, np.ndarray],
                        grid: GridParams, p: ReconstructParams, *, source: str, whole_columns: bool = False):
    """The floors (:func:`find_floors`), the grid they share, each floor's grids from the surface of its band, the
    stairs joining them (each flight solid on the floor it rises from) and what disagreed.

    ``surface`` is read a chunk (or a tile) at a time; ``voxels()`` iterates the volume's observed voxels afresh
    (once per floor; ``whole_columns``: a chunk holds whole lattice columns, :func:`grids.column_occupancy`). Returns
    ``(FoundFloors, GridSpec, [Grids per floor], [StairLink], [warning lines])``.
    """
    camera_z = np.array([T_world_camera[i][2, 3] for i in sorted(T_world_camera)])
    found = find_floors(surface, camera_z, p)
    spec = grids_mod.placed_grid(surface, T_world_camera, grid, p, source=source)
    building = len(found.floors) > 1
    flights = find_flights(surface, found.floors, spec, p) if building else []
    footprints = [f.footprint((spec.rows, spec.cols), spec.cell_size_m) for f in flights]
    per_floor = []
    for k, (floor, band, n_points) in enumerate(zip(found.floors, floor_bands(found.floors), found.floor_points)):
        wells = [m for f, m in zip(flights, footprints) if f.upper == k]  # the stairwells over flights arriving here
        per_floor.append(grids_mod.floor_grids(
            spec, floor.floor_z_m, surface, voxels(), p, band=band if building else None, whole_columns=whole_columns,
            floor_points=n_points, source=source, floor_name=f"{floor.name} ({floor.floor_z_m:.2f} m)" if building else None,
            void=np.logical_or.reduce(wells) if wells else None))
    for flight, footprint in zip(flights, footprints):  # the flight is solid on the floor it rises from
        per_floor[flight.lower] = grids_mod.with_solid(per_floor[flight.lower], footprint, p)
    stairs = stair_links(flights, found.floors, spec, [g.navigable for g in per_floor])
    warnings = found.warnings + (unlinked_warnings(found.floors, stairs) if building else [])
    return found, spec, per_floor, stairs, warnings


def keyframe_summary(p: ReconstructParams, fusion) -> dict:
    """The keyframe selection as recorded in recon.zarr's attrs and the stage summary: the rule, how many frames
    with depth were kept and why (``fused`` in recon.zarr says which)."""
    if not p.keyframes:
        return {"enabled": False}
    kept, offered = len(fusion.frames_fused), len(fusion.frames_fused) + len(fusion.not_keyframes)
    return {"enabled": True, "translation_m": p.keyframe_translation_m, "rotation_deg": p.keyframe_rotation_deg,
            "novel_fraction": p.keyframe_novel_fraction, "pixel_stride": p.keyframe_pixel_stride,
            "depth_tolerance": p.keyframe_depth_tolerance, "keyframes": kept, "frames_with_depth": offered,
            "kept_fraction": round(kept / max(offered, 1), 4), "reasons": fusion.keyframe_reasons}
