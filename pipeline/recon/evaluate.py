"""Accuracy of a reconstruction: held-out depth error, and grid IoU against a simulated scene's ground truth.

Held-out depth error: fuse all frames but every ``holdout_every``-th, render depth at the held-out poses
(``zipon recon-eval FRAMES_ZARR [--holdout-every N]`` prints it as JSON).
Depth is ray-cast from the extracted mesh (open3d ``RaycastingScene`` with
:func:`pipeline.recon.tsdf.pinhole_rays`: OpenCV pixel centres, ``t_hit`` is z-depth) and compared with the measured depth on pixels valid in both.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d

from pipeline.config import ReconstructParams
from pipeline.errors import InputDataError
from pipeline.frames import FrameStore
from pipeline.recon import tsdf


def grid_accuracy(recon, gt, p: ReconstructParams) -> dict:
    """IoU of the occupied / free / navigable grids of ``recon`` (:class:`pipeline.recon.Recon`) against ``gt``.

    Ground truth on the same grid: occupied = :meth:`GTScene.occupancy` over the robot's height band
    (cell centre inside a wall or object part overlapping the band); free = inside a room and not
    occupied; navigable = free and clear of occupied cells by ``robot_radius_m`` (the same
    :func:`navigable_mask`). Cells whose centre lies exactly on a box face
    (:meth:`GTScene.ambiguous`: their label is floating-point rounding) are left out of the
    occupied and free figures and counted in ``gt_ambiguous_cells``. Also the floor error (m), the
    fraction of GT floor cells observed (free or occupied: 240 frames do not see a whole
    apartment), the error cell counts, and ``iou_occupied_seen`` / ``iou_free_seen``: the same
    IoU inside the area the walk saw (:func:`pipeline.recon.grids.building_mask` of the
    reconstruction, with ``building_closing_m``), which separates accuracy from coverage.
    """
    from pipeline.recon.grids import building_mask, navigable_mask
    from pipeline.recon.store import FREE, OCCUPIED

    g = recon.grid
    g_occ = gt.occupancy(g, p.obstacle_min_height_m, p.obstacle_max_height_m)
    g_floor = gt.floor_mask(g)
    g_free = g_floor & ~g_occ
    g_nav = navigable_mask(g_free, g_occ, g.cell_size_m, p.robot_radius_m)
    counted = ~gt.ambiguous(g, p.obstacle_min_height_m, p.obstacle_max_height_m)
    occ = recon.occupancy
    seen = building_mask(occ == OCCUPIED, occ == FREE, g.cell_size_m, p.building_closing_m)

    def iou(a, b, where=True):
        return round(float((a & b & where).sum() / max(((a | b) & where).sum(), 1)), 4)

    return {"iou_occupied": iou(occ == OCCUPIED, g_occ, counted), "iou_free": iou(occ == FREE, g_free, counted),
            "iou_navigable": iou(recon.navigable, g_nav), "floor_error_m": round(abs(recon.floor_z - gt.floor_z), 4),
            "gt_floor_observed": round(float(((occ != 0) & g_floor).sum() / max(g_floor.sum(), 1)), 4),
            "occupied_false_pos": int((~g_occ & (occ == OCCUPIED) & counted).sum()),
            "occupied_false_neg": int((g_occ & (occ != OCCUPIED) & counted).sum()), "gt_occupied": int(g_occ.sum()),
            "gt_ambiguous_cells": int((~counted).sum()),
            "iou_occupied_seen": iou(occ == OCCUPIED, g_occ, counted & seen),
            "iou_free_seen": iou(occ == FREE, g_free, counted & seen)}


def evaluate_grids(frames_path: str | Path, recon_path: str | Path, params: ReconstructParams | None = None) -> dict:
    """:func:`grid_accuracy` of ``recon_path`` against the ground truth ``frames_path`` carries (simulated scenes);
    for a building, also each floor's against that floor's truth (``floors``) and the floors found and true.

    Raises :class:`InputDataError` when the frames carry none (real logs: use the held-out depth error).
    """
    from pipeline.recon import Recon

    gt = FrameStore(Path(frames_path)).ground_truth
    if gt is None:
        raise InputDataError("these frames carry no ground truth to score grids against (a real log?)",
                             path=frames_path, field="attrs.ground_truth",
                             expected="frames ingested from a simulated log; for real logs use the held-out depth error")
    recon, p = Recon(Path(recon_path)), params or ReconstructParams()
    figures = {"recon": str(recon_path), **grid_accuracy(recon, gt, p)}
    if len(recon.floors) > 1 or len(gt.all_floors) > 1:  # a building: each floor against the same floor's truth
        figures["floors"] = [{"floor": i, "name": f.name, **grid_accuracy(recon.floor(i), gt.floor_view(i), p)}
                             for i, f in enumerate(recon.floors) if i < len(gt.all_floors)]
        figures["floors_found"], figures["floors_true"] = len(recon.floors), len(gt.all_floors)
    return figures


def holdout_indices(n_frames: int, holdout_every: int) -> np.ndarray:
    """Held-out frames: the middle frame of every run of ``holdout_every`` (never the first)."""
    if holdout_every < 2:
        raise InputDataError("holdout_every must be at least 2", field="holdout_every", expected=">= 2")
    return np.arange(holdout_every // 2, n_frames, holdout_every)


def evaluate_holdout(frames_path: str | Path, params: ReconstructParams | None = None, holdout_every: int = 10
                     ) -> dict:
    """Median / mean / 90th-percentile absolute depth error (metres) at held-out frames.

    Returns ``{"median_abs_error_m", "mean_abs_error_m", "p90_abs_error_m", "pixels", "coverage",
    "frames_fused", "frames_held_out", "per_frame_median_m"}``; coverage is the fraction of valid
    measured pixels the reconstruction renders.
    """
    p = params or ReconstructParams()
    store = FrameStore(Path(frames_path))
    held = holdout_indices(store.n_frames, holdout_every)
    fused = np.setdiff1d(np.arange(store.n_frames), held)
    if len(held) == 0 or len(fused) == 0:
        raise InputDataError(f"{store.n_frames} frames cannot be split with holdout_every={holdout_every}",
                             path=frames_path, expected="at least holdout_every frames")
    fusion = tsdf.fuse(store, p, frames=fused)
    mesh = tsdf.extract_mesh(fusion.volume, p)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    intr = store.intrinsics
    errors, per_frame, valid_total = [], [], 0
    for i in held:
        block = store.read(int(i), int(i) + 1, rgb=False)
        depth = block.depth_mm[0].astype(np.float64) * 1e-3
        valid = (depth >= p.depth_min_m) & (depth <= p.depth_max_m)
        rays = tsdf.pinhole_rays(intr, block.T_world_camera[0])
        rendered = scene.cast_rays(rays)["t_hit"].numpy()
        both = valid & np.isfinite(rendered)
        err = np.abs(rendered[both] - depth[both])
        valid_total += int(valid.sum())
        errors.append(err)
        per_frame.append(round(float(np.median(err)), 5) if err.size else None)
    err = np.concatenate(errors)
    if err.size == 0:
        raise InputDataError("the reconstruction renders no valid pixel at the held-out frames", path=frames_path)
    return {
        "median_abs_error_m": round(float(np.median(err)), 5),
        "mean_abs_error_m": round(float(err.mean()), 5),
        "p90_abs_error_m": round(float(np.percentile(err, 90)), 5),
        "pixels": int(err.size),
        "coverage": round(err.size / max(valid_total, 1), 4),
        "frames_fused": len(fusion.frames_fused),
        "frames_held_out": held.tolist(),
        "per_frame_median_m": per_frame,
        "voxel_size_m": p.voxel_size_m,
    }
