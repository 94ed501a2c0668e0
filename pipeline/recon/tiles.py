"""TSDF fusion in spatial tiles: reconstruct's memory bounded by a tile, not by the floor's area.

The hashed TSDF volume holds every block of the observed surface's truncation band: on a 60 m x 40 m office
that is gigabytes. Here the xy plane is cut into square tiles of whole TSDF blocks (:class:`TileLayout`), and the
frames are fused one tile at a time, each tile into its own ``VoxelBlockGrid`` holding the tile's blocks and a
one-block margin around them. One pass over the frames' depth finds the blocks each frame touches
(:func:`_frame_plan`); a frame is then read for every tile it has blocks in (the tiles its frustum to
``depth_max_m + sdf_trunc_m`` can reach, from the pose alone, are searched) and integrates only those blocks, into
a volume allocated once at the size the tile's frames need (:func:`volume_capacity`: open3d's growth copies every
block). The tile's surface points, mesh triangles and observed voxels are then extracted, its voxels spilled to a
temporary file (the grids read them once the floors are known), and the volume freed.

Exactness: a voxel's TSDF, weight and colour depend only on the frames whose blocks include it, in frame order,
so a block fused in a tile's volume holds the same bits as in one volume of the whole scene. Extraction looks at
most two voxels past a zero crossing (the crossing's neighbour and the central-difference normal), well inside the
margin, so each tile extracts exactly the points, vertices and triangles the whole volume has near its core. Each
output is kept by the one tile that owns it: a point or vertex by its position, a triangle by its centroid, a
voxel by its block (:meth:`TileLayout.owner`, boundaries half a voxel before each tile's first voxel). So the
points (put in canonical order), the mesh (canonicalised by :func:`pipeline.recon.store.canonical_mesh`, which
merges the vertices two tiles both used) and every grid are byte for byte those of one volume, for any tile size
and thread count. A frame whose blocks leave the footprint it was read for is an error, never a silent loss.

Not tiled: pose refinement (``reconstruct.refine_poses``) aligns each frame to the model fused so far, which is
the whole scene's; with it, fusion keeps one volume.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np
import open3d as o3d

from pipeline.config import ReconstructParams
from pipeline.errors import StageError
from pipeline.frames import FrameStore
from pipeline.geometry import Intrinsics, invert_pose
from pipeline.prefetch import prefetched
from pipeline.recon import tsdf
from pipeline.recon.keyframes import KeyframeRule, KeyframeSelector
from pipeline.recon.surface import Surface
from pipeline.recon.tiled_mesh import SpilledPart, spill_part, write_tiled_mesh

o3c = o3d.core
_TILE_INITIAL_BLOCKS = 256  # a tile volume's first allocation (the hash map grows on demand)


@dataclass(frozen=True)
class TileLayout:
    """Square tiles of ``tile_blocks`` TSDF blocks, tile ``(0, 0)`` starting at block ``first_block`` (x, y).

    ``shape`` is (tiles along x, tiles along y). Tile ``(i, j)`` owns blocks ``first_block + (i, j) * tile_blocks``
    up to the next tile's first; its volume also holds a margin of one block on every side.
    """

    voxel_size_m: float
    block_resolution: int
    tile_blocks: int
    first_block: tuple[int, int]
    shape: tuple[int, int]

    @property
    def block_m(self) -> float:
        return self.voxel_size_m * self.block_resolution

    @property
    def n_tiles(self) -> int:
        return self.shape[0] * self.shape[1]

    def tiles(self) -> list[tuple[int, int]]:
        """Every tile, x-major."""
        return [(i, j) for i in range(self.shape[0]) for j in range(self.shape[1])]

    def block_range(self, tile: tuple[int, int], margin: int) -> tuple[np.ndarray, np.ndarray]:
        """The tile's block indices (x, y), first and last inclusive, widened by ``margin`` blocks."""
        lo = np.asarray(self.first_block) + np.asarray(tile) * self.tile_blocks
        return lo - margin, lo + self.tile_blocks - 1 + margin

    def owner(self, xy_m: np.ndarray) -> np.ndarray:
        """``(N, 2)`` int tile index owning each world point ``(N, 2)`` metres, clipped into the layout.

        A tile's core in voxel units runs from half a voxel before its first voxel to half a voxel before the next
        tile's first: lattice points (the other two coordinates of an extracted point) never sit on a boundary.
        """
        voxel = np.asarray(xy_m, np.float64) / self.voxel_size_m + 0.5
        first = np.asarray(self.first_block) * self.block_resolution
        tile = np.floor((voxel - first) / (self.tile_blocks * self.block_resolution)).astype(np.int64)
        return np.clip(tile, 0, np.asarray(self.shape) - 1)

    def owns(self, tile: tuple[int, int], xy_m: np.ndarray) -> np.ndarray:
        """``(N,)`` bool: the points ``tile`` keeps (:meth:`owner`)."""
        t = self.owner(xy_m)
        return (t[:, 0] == tile[0]) & (t[:, 1] == tile[1])


def frustum_blocks(T_world_camera: np.ndarray, intr: Intrinsics, p: ReconstructParams) -> np.ndarray:
    """``(F, 2, 2)`` int: the first and last block index (x, y) each camera ``(F, 4, 4)`` can touch.

    Fusion touches blocks along each pixel's ray up to ``sdf_trunc_m`` past a depth of at most ``depth_max_m``:
    inside the pyramid from the camera to its image corners at that z-depth (one pixel wider), plus one block.
    """
    far = p.depth_max_m + p.sdf_trunc_m
    u = np.array([-1.0, intr.width, intr.width, -1.0])
    v = np.array([-1.0, -1.0, intr.height, intr.height])
    corners = np.stack([(u - intr.cx) / intr.fx * far, (v - intr.cy) / intr.fy * far, np.full(4, far)], axis=1)
    local = np.vstack([np.zeros((1, 3)), corners])  # camera frame: apex and far corners
    world = np.einsum("fij,pj->fpi", T_world_camera[:, :3, :3], local) + T_world_camera[:, None, :3, 3]
    block = p.voxel_size_m * p.block_resolution
    lo = np.floor(world[..., :2].min(axis=1) / block).astype(np.int64) - 1
    hi = np.floor(world[..., :2].max(axis=1) / block).astype(np.int64) + 1
    return np.stack([lo, hi], axis=1)


def tile_layout(footprints: np.ndarray, p: ReconstructParams, tile_m: float) -> TileLayout:
    """The tiles covering every footprint ``(F, 2, 2)`` (:func:`frustum_blocks`), ``tile_m`` metres a side
    (rounded to whole blocks, at least one)."""
    tile_blocks = max(1, int(round(tile_m / (p.voxel_size_m * p.block_resolution))))
    lo, hi = footprints[:, 0].min(axis=0), footprints[:, 1].max(axis=0)
    shape = -(-(hi - lo + 1) // tile_blocks)
    return TileLayout(p.voxel_size_m, p.block_resolution, tile_blocks, (int(lo[0]), int(lo[1])),
                      (int(shape[0]), int(shape[1])))


@dataclass
class TiledFusion:
    """What :func:`fuse_tiled` fused and extracted (the fields of :class:`pipeline.recon.tsdf.Fusion` it shares mean
    the same), the voxels spilled under ``workdir``."""

    layout: TileLayout
    workdir: Path
    n_blocks: int = 0
    peak_blocks: int = 0  # the most blocks one tile's volume held (its margin included): what memory is bounded by
    tiles_fused: int = 0  # tiles some frame reached
    frames_fused: list[int] = field(default_factory=list)
    empty_frames: list[int] = field(default_factory=list)
    T_world_camera: dict[int, np.ndarray] = field(default_factory=dict)
    not_keyframes: dict[int, np.ndarray] = field(default_factory=dict)
    keyframe_reasons: dict[str, int] = field(default_factory=dict)
    surface: Surface | None = None  # the surface points, each tile's spilled under workdir
    mesh_parts: list[SpilledPart] = field(default_factory=list)  # each tile's mesh, spilled (written by write_mesh)
    n_triangles: int = 0
    voxel_files: list[Path] = field(default_factory=list)

    def summary(self) -> dict:
        """The tiling as the stage summary records it."""
        return {"side_m": round(self.layout.tile_blocks * self.layout.block_m, 4), "layout": list(self.layout.shape),
                "fused": self.tiles_fused, "peak_blocks": self.peak_blocks}

    def write_mesh(self, path: Path) -> dict:
        """The scene's mesh as :func:`pipeline.recon.store.write_mesh` writes it (a slab at a time)."""
        return write_tiled_mesh(path, self.mesh_parts, self.workdir)

    def voxels(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """The observed voxels (weight >= ``occupancy_min_weight``) as :func:`pipeline.recon.tsdf.iter_voxels`
        yields them, a tile's at a time from the spill files: every voxel of a lattice column comes in one chunk
        (a tile owns whole block columns), so the grids read them with ``whole_columns``."""
        for path in self.voxel_files:
            with np.load(path) as spill:
                yield spill["lattice"], spill["tsdf"]


def _frame_plan(store: FrameStore, p: ReconstructParams, intr: Intrinsics, wanted: np.ndarray,
                footprints: np.ndarray, fusion: TiledFusion) -> dict[int, np.ndarray]:
    """The frames to fuse and the TSDF blocks each touches, from one reading of their depth.

    Every wanted frame with valid depth is fused (with ``reconstruct.keyframes``: the keyframes among them, the
    others recorded in ``fusion.not_keyframes``), frames without depth are recorded in ``fusion.empty_frames``.
    Returns store index -> ``(B, 3)`` int32 block coordinates the frame's integration touches (open3d's
    ``compute_unique_block_coordinates``: every pixel's ray within ``sdf_trunc_m`` of its depth), in frame order.
    They depend on the frame alone, so each tile integrates its share of them without reading the frame's depth
    again to find them. Raises :class:`StageError` naming a frame whose blocks leave its ``footprints`` (the tiles
    it was planned for)."""
    selector = KeyframeSelector(KeyframeRule.from_params(p), intr) if p.keyframes else None
    touch = tsdf.new_volume(p, block_count=1)  # only its frustum hash map is used
    K = o3c.Tensor(intr.K, o3c.float64)
    trunc_mult = p.sdf_trunc_m / p.voxel_size_m
    touched: dict[int, np.ndarray] = {}
    idx = np.flatnonzero(wanted)
    for block in store.iter_blocks(p.block_frames, start=int(idx.min()), stop=int(idx.max()) + 1, rgb=False):
        depth = tsdf.prepare_depth(block.depth_mm, p)
        has_depth = depth.reshape(len(depth), -1).any(axis=1)
        for j in range(len(depth)):
            i = block.start + j
            if not wanted[i]:
                continue
            T = block.T_world_camera[j].astype(np.float64)
            if not has_depth[j]:
                fusion.empty_frames.append(i)
                continue
            if selector is not None and not selector.offer(depth[j], np.eye(4) @ T):
                fusion.not_keyframes[i] = np.eye(4) @ T
                continue
            image = o3d.t.geometry.Image(o3c.Tensor.from_numpy(np.ascontiguousarray(depth[j])))
            extrinsic = o3c.Tensor(invert_pose(T), o3c.float64)
            coords = touch.compute_unique_block_coordinates(image, K, extrinsic, 1000.0, p.depth_max_m,
                                                            trunc_mult).numpy()
            xy = coords[:, :2]
            if len(xy) and ((xy < footprints[i, 0]).any() or (xy > footprints[i, 1]).any()):
                raise StageError(f"{store.path}: frame {i} touches TSDF blocks outside the footprint its pose "
                                 f"predicts (blocks {xy.min(axis=0)}..{xy.max(axis=0)}, predicted "
                                 f"{footprints[i, 0]}..{footprints[i, 1]}): fuse it untiled (run.recon_tile_m: 0)")
            touched[i] = coords
    if selector is not None:
        fusion.keyframe_reasons = dict(selector.reasons)
    return touched


def tile_share(touched: dict[int, np.ndarray], frames: np.ndarray, lo: np.ndarray, hi: np.ndarray
               ) -> dict[int, np.ndarray]:
    """Of each of ``frames`` (sorted store indices, keys of ``touched``), the blocks with x, y within ``lo..hi``
    (inclusive); frames with none are left out."""
    share = {}
    for i in frames:
        xy = touched[i][:, :2]
        inside = ((xy >= lo) & (xy <= hi)).all(axis=1)
        if inside.any():  # (a frame with depth may touch no block at all: open3d samples every 4th pixel)
            share[int(i)] = touched[i] if inside.all() else touched[i][inside]
    return share


def volume_capacity(share: dict[int, np.ndarray]) -> int:
    """The block count an empty volume needs so that integrating ``share`` (block coordinates per frame, fused in
    frame order) never grows it.

    open3d grows a full hash map by rehashing, which gathers and re-inserts every block's voxels (tens of
    microseconds a block: most of fusion's time on a large floor when a tile's volume doubled from a small start);
    it grows when its size plus the keys handed to one ``integrate`` would pass its capacity, new or not. So the
    capacity is the largest of (blocks held before a frame + that frame's blocks).
    """
    parts = [share[i] for i in sorted(share)]
    if not parts:
        return 1
    _, first = np.unique(np.concatenate(parts), axis=0, return_index=True)
    frame_of = np.repeat(np.arange(len(parts)), [len(c) for c in parts])
    held_before = np.concatenate([[0], np.cumsum(np.bincount(frame_of[first], minlength=len(parts)))[:-1]])
    return int((held_before + np.array([len(c) for c in parts])).max())


def _fuse_tile(store: FrameStore, p: ReconstructParams, intr: Intrinsics, share: dict[int, np.ndarray]
               ) -> o3d.t.geometry.VoxelBlockGrid:
    """One tile's volume: each frame of ``share`` (store index -> its blocks in the tile and margin,
    :func:`tile_share`) integrated into those blocks, in frame order, into a volume sized never to grow
    (:func:`volume_capacity`: it holds the tile's blocks, not the whole scene's default)."""
    volume = tsdf.new_volume(p, block_count=volume_capacity(share))
    K_integrate = o3c.Tensor(tsdf.integration_K(intr))
    trunc_mult = p.sdf_trunc_m / p.voxel_size_m
    chunk = store.block_frames
    frames = np.array(sorted(share), dtype=np.int64)

    def blocks():
        for g in np.unique(frames // chunk):
            yield tsdf.prepare_block(store.read(int(g * chunk), int(min((g + 1) * chunk, store.n_frames))), p)

    for block in prefetched(blocks(), name="recon-read"):
        for j in range(len(block.depth_mm)):
            coords = share.get(block.start + j)
            if coords is None:
                continue
            depth = o3d.t.geometry.Image(o3c.Tensor.from_numpy(np.ascontiguousarray(block.depth_mm[j])))
            color = o3d.t.geometry.Image(o3c.Tensor.from_numpy(np.ascontiguousarray(block.rgb[j])))
            extrinsic = o3c.Tensor(invert_pose(block.T_world_camera[j]), o3c.float64)
            volume.integrate(o3c.Tensor.from_numpy(np.ascontiguousarray(coords)), depth, color, K_integrate,
                             extrinsic, 1000.0, p.depth_max_m, trunc_mult)
    return volume


def _extract(volume: o3d.t.geometry.VoxelBlockGrid, layout: TileLayout, tile: tuple[int, int],
             p: ReconstructParams, workdir: Path) -> tuple[tuple[np.ndarray, ...], SpilledPart | None,
                                                         tuple[np.ndarray, ...], int, int]:
    """The tile's own points (xyz, normals, colours), its mesh part spilled under ``workdir``
    (:func:`pipeline.recon.tiled_mesh.spill_part`), the observed voxels of its own blocks (lattice, tsdf), its own
    block and triangle counts."""
    xyz, normals, colors = tsdf.extract_points(volume, p, canonical=False)  # Surface.add sorts what is kept
    keep = layout.owns(tile, xyz[:, :2])
    points = (xyz[keep], normals[keep], colors[keep])
    del xyz, normals, colors

    # open3d's tensor mesh, read as the legacy mesh of tsdf.extract_mesh holds it (float32 widened to float64),
    # without the element-by-element conversion to a legacy mesh
    mesh = volume.extract_triangle_mesh(weight_threshold=p.min_weight)
    v = mesh.vertex.positions.numpy().astype(np.float64) if "positions" in mesh.vertex else np.zeros((0, 3))
    c = mesh.vertex.colors.numpy().astype(np.float64) if "colors" in mesh.vertex else np.zeros((len(v), 3))
    tri = mesh.triangle.indices.numpy() if "indices" in mesh.triangle else np.zeros((0, 3), np.int64)
    del mesh
    if len(tri):
        xy = [v[tri[:, k], :2] for k in range(3)]
        tri = tri[layout.owns(tile, (xy[0] + xy[1] + xy[2]) / 3)]  # by centroid (the sum in np.mean's order)
        del xy
    owned = layout.owns(tile, v[:, :2]) if len(v) else np.zeros(0, bool)
    mesh_part = spill_part(v, c, tri, owned, workdir / f"mesh_{tile[0]}_{tile[1]}")
    n_triangles = len(tri)
    del v, c, tri, owned  # freed before the voxels are read

    lo, hi = layout.block_range(tile, margin=0)
    lattices, values = [], []
    for lattice, t in tsdf.iter_voxels(volume, p, min_weight=p.occupancy_min_weight, blocks_per_chunk=256):
        block_xy = np.floor_divide(lattice[:, :2], p.block_resolution)
        own = ((block_xy >= lo) & (block_xy <= hi)).all(axis=1)
        lattices.append(lattice[own])
        values.append(t[own])
    voxels = (np.concatenate(lattices) if lattices else np.zeros((0, 3), np.int32),
              np.concatenate(values) if values else np.zeros(0, np.float32))
    keys = volume.hashmap().key_tensor()[volume.hashmap().active_buf_indices().to(o3c.int64)].numpy()
    n_blocks = int(((keys[:, :2] >= lo) & (keys[:, :2] <= hi)).all(axis=1).sum())
    return points, mesh_part, voxels, n_blocks, n_triangles


def fuse_tiled(store: FrameStore, p: ReconstructParams, tile_m: float, workdir: Path, *,
               frames: Sequence[int] | None = None, progress: Callable | None = None) -> TiledFusion | None:
    """Fuse ``frames`` (default all) of ``store`` tile by tile (module doc), extracting each tile as it is done.

    Returns None when every view fits in one tile (then :func:`pipeline.recon.tsdf.fuse` is the same work without
    re-reading). Raises :class:`pipeline.errors.InputDataError` for too many frames without depth, as ``fuse``
    does. ``progress(iterator, n_tiles)`` may wrap the tile loop.
    """
    wanted = np.zeros(store.n_frames, bool)
    if frames is None:
        wanted[:] = True
    else:
        idx = np.asarray(list(frames), dtype=np.int64)
        if idx.size == 0 or idx.min() < 0 or idx.max() >= store.n_frames:
            return None  # fuse() reports the bad selection
        wanted[idx] = True
    p = tsdf.with_stride(p, store.intrinsics)
    intr = tsdf.strided(store.intrinsics, p.depth_stride)
    poses = store.poses().astype(np.float64)
    footprints = frustum_blocks(poses, intr, p)
    layout = tile_layout(footprints[wanted], p, tile_m)
    if layout.n_tiles == 1:
        return None
    fusion = TiledFusion(layout, Path(workdir))
    fusion.surface = Surface(layout.owner, fusion.workdir)
    touched = _frame_plan(store, p, intr, wanted, footprints, fusion)
    to_fuse = np.zeros(store.n_frames, bool)
    to_fuse[list(touched)] = True
    tiles = layout.tiles()
    for tile in (progress(iter(tiles), len(tiles)) if progress else tiles):
        lo, hi = layout.block_range(tile, margin=1)
        reach = to_fuse & (footprints[:, 1] >= lo).all(axis=1) & (footprints[:, 0] <= hi).all(axis=1)
        share = tile_share(touched, np.flatnonzero(reach), lo, hi)
        if not share:  # the frames that might reach it did not
            continue
        volume = _fuse_tile(store, p, intr, share)
        fusion.peak_blocks = max(fusion.peak_blocks, int(volume.hashmap().size()))
        fusion.tiles_fused += 1
        tile_points, mesh_part, (lattice, values), n_blocks, n_triangles = _extract(volume, layout, tile, p,
                                                                                     fusion.workdir)
        del volume
        fusion.n_blocks += n_blocks
        fusion.n_triangles += n_triangles
        fusion.surface.add(tile, *tile_points)
        if mesh_part is not None:
            fusion.mesh_parts.append(mesh_part)
        if len(values):
            path = fusion.workdir / f"voxels_{tile[0]}_{tile[1]}.npz"
            np.savez(path, lattice=lattice, tsdf=values)
            fusion.voxel_files.append(path)
    fused = np.flatnonzero(to_fuse)
    fusion.frames_fused = fused.tolist()
    fusion.T_world_camera = {int(i): poses[i] for i in fused}
    tsdf.check_empty_frames(store, p, fusion)
    return fusion


def spill_dir(next_to: Path) -> tempfile.TemporaryDirectory:
    """A temporary folder for the tiles' voxels beside ``next_to`` (the output being written)."""
    return tempfile.TemporaryDirectory(prefix=".recon-tiles-", dir=Path(next_to).parent)
