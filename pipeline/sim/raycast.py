"""Ray-cast RGB-D + instance rendering of a ground-truth scene with open3d's ``RaycastingScene``.

Every solid (walls, floor slabs, ceiling, object parts) is a box of 12 triangles in one mesh, so
a hit's ``primitive_id // 12`` indexes per-box lookup arrays (colour, instance id, texture).
Rays go through pixel centres as in :func:`pipeline.geometry.backproject` (``u - cx``), with
camera-frame direction ``((u-cx)/fx, (v-cy)/fy, 1)``: the hit distance is then the z-depth.

The renderer uses only the :class:`~pipeline.scene_gt.GTScene`, so any stage (the evaluator's ego
views, reconstruction checks) gets the same pictures as the simulator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.geometry import Intrinsics
from pipeline.scene_gt import GTScene
from pipeline.sim.building import rect_minus
from pipeline.sim.catalog import MATERIAL_CODE
from pipeline.sim.layout import Rect

# Texture codes beyond the object materials.
TEX_WALL, TEX_PLANKS, TEX_TILES, TEX_CEILING = 100, 101, 102, 103
WALL_RGB = (222, 218, 208)
CEILING_RGB = (240, 240, 236)
FLOORS = {  # room type -> (rgb, texture)
    "kitchen": ((200, 196, 186), TEX_TILES), "bathroom": ((214, 222, 228), TEX_TILES),
    "living room": ((170, 128, 88), TEX_PLANKS), "bedroom": ((186, 146, 104), TEX_PLANKS),
    "office": ((150, 112, 80), TEX_PLANKS), "hallway": ((176, 140, 100), TEX_PLANKS),
    "open office": ((140, 140, 146), TEX_TILES), "meeting room": ((120, 124, 140), TEX_TILES),
}
STAIR_RGB = (150, 108, 72)
LIGHT_DIR = np.array([0.35, 0.55, 0.76]) / np.linalg.norm([0.35, 0.55, 0.76])
INVALID_ID = np.uint32(0xFFFFFFFF)

# Box corners and the 12 outward-wound triangles of a box.
_CORNERS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64)
_TRIS = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], dtype=np.uint32)


@dataclass
class RaycastFrames:
    """A block of ``B`` rendered frames."""

    rgb: np.ndarray  # (B,H,W,3) uint8
    depth_m: np.ndarray  # (B,H,W) float32 z-depth, inf where no surface
    instance: np.ndarray  # (B,H,W) uint16, 0 = walls/floor/ceiling/none

    def depth_mm(self, depth_min_m: float, depth_max_m: float) -> np.ndarray:
        """``(B,H,W)`` uint16 millimetres, 0 outside ``[depth_min_m, depth_max_m]``."""
        d = self.depth_m
        valid = np.isfinite(d) & (d >= depth_min_m) & (d <= depth_max_m)
        return np.where(valid, np.round(np.where(valid, d, 0.0) * 1000.0), 0).astype(np.uint16)


def scene_boxes(gt: GTScene):
    """Lookup arrays of every solid: ``mins (N,3)``, ``maxs (N,3)``, ``rgb (N,3) float32 0..1``,
    ``instance (N,) uint16``, ``texture (N,) int16``, ``tone (N,) float32``."""
    mins, maxs, rgb, inst, tex, tone = [], [], [], [], [], []

    def add(lo, hi, colour, iid, code, t=1.0):
        mins.append(lo), maxs.append(hi), rgb.append(colour), inst.append(iid), tex.append(code), tone.append(t)

    for wall in gt.walls:
        add(wall.min, wall.max, WALL_RGB, 0, TEX_WALL)
    if gt.floors:
        _building_surfaces(gt, add)
    else:
        for room in gt.rooms:
            p = np.asarray(room.polygon)
            colour, code = FLOORS.get(room.type, ((180, 170, 150), TEX_PLANKS))
            add((p[:, 0].min(), p[:, 1].min(), gt.floor_z - 0.05), (p[:, 0].max(), p[:, 1].max(), gt.floor_z),
                colour, 0, code)
        x0, x1, y0, y1 = gt.bounds_xy()
        top = gt.floor_z + gt.wall_height_m
        add((x0 - 0.2, y0 - 0.2, top), (x1 + 0.2, y1 + 0.2, top + 0.05), CEILING_RGB, 0, TEX_CEILING)
    for obj in gt.objects:
        vols = [np.prod(np.subtract(p.max, p.min)) for p in obj.parts]
        main = int(np.argmax(vols))
        for k, part in enumerate(obj.parts):
            # Secondary parts (legs, handles, shades) a little darker or lighter than the main one.
            t = 1.0 if k == main else (0.72 if part.max[2] - part.min[2] > 0.5 * (part.max[0] - part.min[0]) else 1.12)
            add(part.min, part.max, obj.color_rgb, obj.id, MATERIAL_CODE.get(obj.material, 0), t)
    return (np.asarray(mins, np.float64), np.asarray(maxs, np.float64), np.asarray(rgb, np.float32) / 255.0,
            np.asarray(inst, np.uint16), np.asarray(tex, np.int16), np.asarray(tone, np.float32))


def _polygon_rect(polygon) -> Rect:
    p = np.asarray(polygon, dtype=np.float64)
    return Rect(float(p[:, 0].min()), float(p[:, 1].min()), float(p[:, 0].max()), float(p[:, 1].max()))


def _building_surfaces(gt: GTScene, add) -> None:
    """Steps, every floor's room surfaces and the slabs between floors, both cut by the stair openings."""
    for stair in gt.stairs:
        for step in stair.steps:
            add(step.min, step.max, STAIR_RGB, 0, TEX_PLANKS)
    x0, x1, y0, y1 = gt.bounds_xy()
    floors = gt.all_floors
    for f in floors:
        holes = [_polygon_rect(s.opening) for s in gt.stairs if s.upper == f.id]
        for room in (r for r in gt.rooms if r.floor == f.id):
            colour, code = FLOORS.get(room.type, ((180, 170, 150), TEX_PLANKS))
            pieces = [_polygon_rect(room.polygon)]
            for hole in holes:
                pieces = [q for piece in pieces for q in rect_minus(piece, hole)]
            for q in pieces:
                add((q.x0, q.y0, f.floor_z - 0.05), (q.x1, q.y1, f.floor_z), colour, 0, code)
        if f.id == 0:
            continue
        slab = [Rect(x0 - 0.2, y0 - 0.2, x1 + 0.2, y1 + 0.2)]  # under this floor, over the one below
        for hole in holes:
            slab = [q for piece in slab for q in rect_minus(piece, hole)]
        below = floors[f.id - 1].ceiling_z
        for q in slab:
            add((q.x0, q.y0, below), (q.x1, q.y1, f.floor_z - 0.05), CEILING_RGB, 0, TEX_CEILING)
    top = floors[-1].ceiling_z
    add((x0 - 0.2, y0 - 0.2, top), (x1 + 0.2, y1 + 0.2, top + 0.05), CEILING_RGB, 0, TEX_CEILING)


def boxes_mesh(mins: np.ndarray, maxs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``(8N,3)`` float32 and triangles ``(12N,3)`` uint32 of ``N`` boxes (box k owns triangles 12k..12k+11)."""
    verts = mins[:, None, :] + _CORNERS[None] * (maxs - mins)[:, None, :]
    tris = _TRIS[None] + (8 * np.arange(len(mins), dtype=np.uint32))[:, None, None]
    return verts.reshape(-1, 3).astype(np.float32), tris.reshape(-1, 3)


def _hash01(*ints: np.ndarray) -> np.ndarray:
    """Deterministic pseudo-random values in [0, 1) from integer lattice coordinates."""
    h = np.uint32(2166136261)
    for a in ints:
        h = (h ^ a.astype(np.uint32)) * np.uint32(16777619)
        h ^= h >> np.uint32(13)
    h = h * np.uint32(0x5BD1E995)
    h ^= h >> np.uint32(15)
    return (h & np.uint32(0xFFFFFF)).astype(np.float32) / np.float32(0x1000000)


def _grain(u, v):
    return np.sin((u * 9.0 + 0.6 * np.sin(v * 5.0)) * 6.0)


def _planks(u, v, fine, ax):
    board = np.floor(u / 0.16)
    return 0.88 + 0.22 * _hash01(board.astype(np.int64), np.floor((v + 0.4 * board) / 1.2).astype(np.int64)) \
        + 0.04 * _grain(u, v)


def _tiles(u, v, fine, ax):
    grout = (np.abs((u / 0.3) % 1.0 - 0.5) > 0.47) | (np.abs((v / 0.3) % 1.0 - 0.5) > 0.47)
    return np.where(grout, 0.7, 1.0 + 0.04 * (fine - 0.5))


# texture code -> brightness factor of (u, v, fine noise, face axis), all (N,) arrays.
_RULES = {
    MATERIAL_CODE["wood"]: lambda u, v, f, ax: 1.0 + 0.07 * _grain(u, v) + 0.03 * (f - 0.5),
    MATERIAL_CODE["fabric"]: lambda u, v, f, ax: 1.0 + 0.12 * (f - 0.5),
    MATERIAL_CODE["leather"]: lambda u, v, f, ax: 1.0 + 0.05 * np.sin(u * 23.0) * np.sin(v * 19.0),
    MATERIAL_CODE["metal"]: lambda u, v, f, ax: 1.05 + 0.06 * (_hash01(np.floor(u * 400).astype(np.int64), ax) - 0.5),
    MATERIAL_CODE["plastic"]: lambda u, v, f, ax: 1.0 + 0.02 * (f - 0.5),
    MATERIAL_CODE["ceramic"]: lambda u, v, f, ax: 1.08 + 0.02 * (f - 0.5),
    MATERIAL_CODE["glass"]: lambda u, v, f, ax: 0.95 + 0.04 * np.sin(u * 3.0 + v * 3.0),
    MATERIAL_CODE["paper"]: lambda u, v, f, ax: 1.0 + 0.25 * np.sin(u * 11.0) * np.cos(v * 13.0),
    TEX_WALL: lambda u, v, f, ax: 1.0 + 0.03 * (f - 0.5),
    TEX_CEILING: lambda u, v, f, ax: 1.0 + 0.02 * (f - 0.5),
    TEX_PLANKS: _planks,
    TEX_TILES: _tiles,
}


def texture(points: np.ndarray, normals: np.ndarray, code: np.ndarray) -> np.ndarray:
    """Brightness factor ``(N,)`` float32 around 1 from world hit points ``(N,3)``, normals ``(N,3)``, codes ``(N,)``.

    A function of world position only, so a surface looks the same from every viewpoint.
    """
    ax = np.abs(normals).argmax(axis=1)
    # In-plane coordinates of the face: (x, y) on horizontal faces, (y, z) / (x, z) on vertical ones.
    u = np.where(ax == 0, points[:, 1], points[:, 0]).astype(np.float32)
    v = np.where(ax == 2, points[:, 1], points[:, 2]).astype(np.float32)
    out = np.ones(len(points), np.float32)
    order = np.argsort(code, kind="stable")
    codes, starts = np.unique(code[order], return_index=True)
    bounds = list(starts[1:]) + [len(order)]
    for c, s0, s1 in zip(codes, starts, bounds):
        rule = _RULES.get(int(c))
        if rule is None:
            continue
        idx = order[s0:s1]
        uu, vv, aa = u[idx], v[idx], ax[idx]
        fine = _hash01(np.floor(uu * 200).astype(np.int64), np.floor(vv * 200).astype(np.int64), aa)
        out[idx] = rule(uu, vv, fine, aa)
    return out


class SceneRaycaster:
    """Renders RGB, z-depth and instance ids of a :class:`GTScene` for batches of camera poses."""

    def __init__(self, gt: GTScene, intrinsics: Intrinsics, *, nthreads: int = 0):
        import open3d as o3d

        self.gt = gt
        self.intrinsics = intrinsics
        self.nthreads = nthreads
        self.mins, self.maxs, self.rgb, self.instance, self.texture, self.tone = scene_boxes(gt)
        verts, tris = boxes_mesh(self.mins, self.maxs)
        self._o3d = o3d
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(verts), o3d.core.Tensor(tris))
        K = intrinsics
        u = np.arange(K.width, dtype=np.float64)
        v = np.arange(K.height, dtype=np.float64)
        dirs = np.stack(np.broadcast_arrays((u[None, :] - K.cx) / K.fx, (v[:, None] - K.cy) / K.fy,
                                            np.ones((K.height, K.width))), axis=-1)
        self.dirs_cam = dirs.astype(np.float32)  # (H,W,3), z = 1 so t_hit is z-depth

    def rays(self, T_world_camera: np.ndarray) -> np.ndarray:
        """``(B,H,W,6)`` float32 rays ``[origin, direction]`` for poses ``(B,4,4)``."""
        T = np.asarray(T_world_camera, dtype=np.float64).reshape(-1, 4, 4)
        B, (H, W) = len(T), self.dirs_cam.shape[:2]
        out = np.empty((B, H, W, 6), np.float32)
        out[..., :3] = T[:, None, None, :3, 3].astype(np.float32)
        out[..., 3:] = (self.dirs_cam.reshape(-1, 3) @ T[:, :3, :3].transpose(0, 2, 1).astype(np.float32)
                        ).reshape(B, H, W, 3)
        return out

    def cast(self, rays: np.ndarray) -> dict[str, np.ndarray]:
        """Raw hits of ``(...,6)`` rays: ``t_hit`` (float32, inf = miss), ``primitive_ids`` (uint32), ``normals``."""
        hits = self.scene.cast_rays(self._o3d.core.Tensor(np.ascontiguousarray(rays)), nthreads=self.nthreads)
        return {"t_hit": hits["t_hit"].numpy(), "primitive_ids": hits["primitive_ids"].numpy(),
                "normals": hits["primitive_normals"].numpy()}

    def raycast(self, T_world_camera: np.ndarray) -> RaycastFrames:
        """Render poses ``(B,4,4)`` (``T_world_camera``, OpenCV optical) in one ray-casting call."""
        rays = self.rays(T_world_camera)
        hits = self.cast(rays)
        return self.shade(rays, hits)

    def shade(self, rays: np.ndarray, hits: dict[str, np.ndarray]) -> RaycastFrames:
        """Colour, depth and instance images from the hits of :meth:`rays`."""
        t = hits["t_hit"]
        prim = hits["primitive_ids"]
        hit = prim != INVALID_ID
        box = np.where(hit, prim // 12, 0).astype(np.int64)
        flat_hit = hit.reshape(-1)
        b = box.reshape(-1)[flat_hit]
        r = rays.reshape(-1, 6)[flat_hit]
        tt = t.reshape(-1)[flat_hit]
        points = r[:, :3] + r[:, 3:] * tt[:, None]
        n = hits["normals"].reshape(-1, 3)[flat_hit]
        # A key light plus a weak opposite fill so no face is black; mild falloff with range.
        cos = n @ LIGHT_DIR.astype(np.float32)
        lambert = 0.5 + 0.4 * np.maximum(cos, 0.0) + 0.15 * np.maximum(-cos, 0.0)
        lambert[self.texture[b] == TEX_CEILING] = 0.9  # lit from the room below
        falloff = 1.0 / (1.0 + 0.015 * tt * tt)
        shade = (lambert * (0.75 + 0.25 * falloff) * texture(points, n, self.texture[b]) * self.tone[b])
        colour = np.clip(self.rgb[b] * shade[:, None], 0.0, 1.0)
        rgb = np.zeros(t.shape + (3,), np.uint8)
        rgb.reshape(-1, 3)[flat_hit] = (colour * 255.0 + 0.5).astype(np.uint8)
        instance = np.where(hit, self.instance[box], 0).astype(np.uint16)
        depth = np.where(hit, t, np.inf).astype(np.float32)
        return RaycastFrames(rgb=rgb, depth_m=depth, instance=instance)
