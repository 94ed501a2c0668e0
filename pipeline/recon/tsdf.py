"""TSDF fusion of a frame store with open3d's tensor ``VoxelBlockGrid``.

The legacy ``ScalableTSDFVolume`` is broken in open3d 0.20 (ENVIRONMENT.md), so fusion uses the
hashed voxel-block grid: memory grows with the observed surface (allocated blocks), never with
the number of frames; frames are streamed from ``frames.zarr`` in blocks.

Voxel lattice: the TSDF value of integer voxel ``k`` is the signed distance sampled at the world
point ``k * voxel_size_m`` (positive in front of a surface, negative behind it, truncated to
[-1, 1] in units of ``sdf_trunc_m``).

Order: the hash map's slots are handed out by racing threads, so open3d returns blocks, points and
mesh vertices in an order that changes from run to run (the values do not). Everything read out of
the volume is put in a canonical order (points sorted here, voxel blocks by block coordinate, meshes
by :func:`pipeline.recon.store.canonical_mesh` when written), so the same frames give the same arrays
and the same bytes for any thread count.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Iterable, Iterator

import numpy as np
import open3d as o3d

from pipeline.config import ReconstructParams
from pipeline.errors import InputDataError
from pipeline.frames import FrameBlock, FrameStore
from pipeline.geometry import Intrinsics, invert_pose
from pipeline.prefetch import prefetched
from pipeline.recon.keyframes import KeyframeRule, KeyframeSelector
from pipeline.recon.store import canonical_point_order

o3c = o3d.core
_CPU = o3c.Device("CPU:0")
_INITIAL_BLOCKS = 4096  # the hash map grows on demand; this only sizes the first allocation


@dataclass
class Fusion:
    """A fused volume and what went into it."""

    volume: o3d.t.geometry.VoxelBlockGrid
    frames_fused: list[int] = field(default_factory=list)  # store indices fused
    empty_frames: list[int] = field(default_factory=list)  # store indices with no valid depth in range
    T_world_camera: dict[int, np.ndarray] = field(default_factory=dict)  # store index -> pose fused with
    # frames with depth that were not keyframes (reconstruct.keyframes): store index -> pose (the recorded one,
    # moved by the last keyframe's refinement when poses are refined)
    not_keyframes: dict[int, np.ndarray] = field(default_factory=dict)
    keyframe_reasons: dict[str, int] = field(default_factory=dict)  # why each keyframe was kept (keyframes on)

    @property
    def n_blocks(self) -> int:
        return int(self.volume.hashmap().size())


def new_volume(p: ReconstructParams, block_count: int = _INITIAL_BLOCKS) -> o3d.t.geometry.VoxelBlockGrid:
    """An empty TSDF volume with ``tsdf``, ``weight`` and ``color`` (0..255 float) per voxel; ``block_count`` sizes
    the first allocation only (its voxels are zeroed up front: 4096 blocks of 16^3 voxels are 335 MB)."""
    return o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"),
        attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=((1), (1), (3)),
        voxel_size=p.voxel_size_m,
        block_resolution=p.block_resolution,
        block_count=block_count,
        device=_CPU,
    )


def strided(intr: Intrinsics, stride: int) -> Intrinsics:
    """Intrinsics of ``image[::stride, ::stride]`` (pixel (u, v) of the result is (stride*u, stride*v))."""
    if stride == 1:
        return intr
    w, h = -(-intr.width // stride), -(-intr.height // stride)
    return Intrinsics(intr.fx / stride, intr.fy / stride, intr.cx / stride, intr.cy / stride, w, h)


def fusion_stride(p: ReconstructParams, intr: Intrinsics) -> int:
    """``reconstruct.depth_stride`` for a camera: the number given, or for ``'auto'`` the largest stride (at most 8)
    whose pixel at ``depth_max_m`` spans no more than one voxel (``stride * depth_max_m / f <= voxel_size_m``,
    with ``f`` the smaller focal length in pixels).

    Fusion looks every voxel of the touched blocks up in the depth image; a coarser image changes which pixel a
    voxel reads by less than a voxel at any depth in range, and every surface voxel is still hit by a pixel.
    """
    if p.depth_stride != "auto":
        return int(p.depth_stride)
    return int(min(8, max(1, math.floor(p.voxel_size_m * min(intr.fx, intr.fy) / p.depth_max_m + 1e-9))))


def with_stride(p: ReconstructParams, intr: Intrinsics) -> ReconstructParams:
    """``p`` with ``depth_stride`` resolved for this camera (:func:`fusion_stride`)."""
    stride = fusion_stride(p, intr)
    return p if p.depth_stride == stride else p.model_copy(update={"depth_stride": stride})


def prepare_depth(depth_mm: np.ndarray, p: ReconstructParams) -> np.ndarray:
    """``(..., H, W)`` uint16 mm -> strided, range-limited, C-contiguous uint16 mm (0 = invalid).

    Works on one frame or a whole block at once (one vectorised pass, one allocation).
    """
    d = depth_mm[..., :: p.depth_stride, :: p.depth_stride]
    lo, hi = int(round(p.depth_min_m * 1000)), int(round(p.depth_max_m * 1000))
    return np.ascontiguousarray(np.where((d >= lo) & (d <= hi), d, np.uint16(0)), dtype=np.uint16)


@dataclass
class PreparedBlock:
    """A frame block ready to fuse: depth ``(B,h,w)`` uint16 mm and rgb ``(B,h,w,3)`` uint8 at the fusion stride."""

    start: int
    depth_mm: np.ndarray
    rgb: np.ndarray
    T_world_camera: np.ndarray  # (B,4,4) float64, native byte order
    has_depth: np.ndarray  # (B,) bool: some depth pixel is valid


def prepare_block(block: FrameBlock, p: ReconstructParams) -> PreparedBlock:
    """Depth range limiting and striding of a whole block (see :func:`prepare_depth`)."""
    depth = prepare_depth(block.depth_mm, p)
    s = p.depth_stride
    rgb = block.rgb if s == 1 else np.ascontiguousarray(block.rgb[:, ::s, ::s])
    return PreparedBlock(block.start, depth, rgb, block.T_world_camera.astype(np.float64),
                         depth.reshape(len(depth), -1).any(axis=1))


def integration_K(intr: Intrinsics) -> np.ndarray:
    """``K`` for open3d's ``integrate``: principal point moved by +0.5 px.

    open3d looks a voxel's depth up at the *truncated* projected pixel coordinate, while pixel k
    covers [k - 0.5, k + 0.5) (OpenCV centres); the shift turns truncation into rounding. Without
    it every slanted surface comes out shifted (about 1 cm down on a floor seen at 320x240).
    """
    K = intr.K.copy()
    K[0, 2] += 0.5
    K[1, 2] += 0.5
    return K


def pinhole_rays(intr: Intrinsics, T_world_camera: np.ndarray) -> o3d.core.Tensor:
    """Rays ``(H,W,6)`` (origin, direction with z = 1) through the pixel centres, OpenCV convention.

    open3d's ``create_rays_pinhole`` puts pixel centres at ``u + 0.5``; zipon's intrinsics put them
    at integer ``u`` (as the simulator and OpenCV do): with the principal point moved by +0.5 px,
    open3d's ray through ``u + 0.5`` is zipon's ray through ``u``. ``t_hit`` of these rays is z-depth.
    """
    K = intr.K.copy()
    K[0, 2] += 0.5
    K[1, 2] += 0.5
    return o3d.t.geometry.RaycastingScene.create_rays_pinhole(
        o3c.Tensor(K), o3c.Tensor(invert_pose(np.asarray(T_world_camera, dtype=np.float64))), intr.width, intr.height)


def integrate(volume: o3d.t.geometry.VoxelBlockGrid, depth_mm: np.ndarray, rgb: np.ndarray,
              T_world_camera: np.ndarray, intr: Intrinsics, p: ReconstructParams) -> None:
    """Fuse one prepared frame: depth ``(h,w)`` uint16 mm, rgb ``(h,w,3)`` uint8, intrinsics of that size.

    The images are handed to open3d without copies (``Tensor.from_numpy`` of contiguous arrays).
    """
    depth = o3d.t.geometry.Image(o3c.Tensor.from_numpy(np.ascontiguousarray(depth_mm)))
    color = o3d.t.geometry.Image(o3c.Tensor.from_numpy(np.ascontiguousarray(rgb)))
    K = o3c.Tensor(intr.K, o3c.float64)
    extrinsic = o3c.Tensor(invert_pose(np.asarray(T_world_camera, dtype=np.float64)), o3c.float64)
    trunc_mult = p.sdf_trunc_m / p.voxel_size_m
    coords = volume.compute_unique_block_coordinates(depth, K, extrinsic, 1000.0, p.depth_max_m, trunc_mult)
    volume.integrate(coords, depth, color, o3c.Tensor(integration_K(intr)), extrinsic, 1000.0, p.depth_max_m,
                     trunc_mult)


def fuse(store: FrameStore, p: ReconstructParams, *, frames: Iterable[int] | None = None,
         refiner: Callable | None = None, progress: Callable[[Iterator, int], Iterator] | None = None) -> Fusion:
    """Fuse ``frames`` (default: all) of ``store``, streamed in blocks of ``p.block_frames``.

    ``refiner(volume, depth_mm, rgb, T, intrinsics, index) -> T`` may correct each pose against the
    model fused so far (:class:`pipeline.recon.refine.PoseRefiner`); ``progress(iterator, n_blocks)``
    may wrap the block iterator. Raises :class:`InputDataError` naming the
    first empty frame when more than ``p.max_invalid_frame_fraction`` of the frames (or all of
    them) have no valid depth in ``[depth_min_m, depth_max_m]``.
    """
    start, stop, wanted = 0, store.n_frames, None
    if frames is not None:
        idx = np.asarray(list(frames), dtype=np.int64)
        if idx.size == 0 or idx.min() < 0 or idx.max() >= store.n_frames:
            raise InputDataError(f"frame selection outside [0, {store.n_frames})", path=store.path, field="frames")
        wanted = np.zeros(store.n_frames, dtype=bool)
        wanted[idx] = True
        start, stop = int(idx.min()), int(idx.max()) + 1
    p = with_stride(p, store.intrinsics)
    intr = strided(store.intrinsics, p.depth_stride)
    fusion = Fusion(volume=new_volume(p))
    selector = KeyframeSelector(KeyframeRule.from_params(p), intr) if p.keyframes else None
    correction = np.eye(4)  # the last keyframe's refinement: refined pose @ inverse(recorded pose)
    blocks = store.iter_blocks(p.block_frames, start=start, stop=stop)
    n_blocks = -(-(stop - start) // p.block_frames)
    # block k+1 is read and prepared while block k is fused
    prepared = prefetched((prepare_block(b, p) for b in blocks), name="recon-read")
    for block in (progress(prepared, n_blocks) if progress else prepared):
        for j in range(len(block.depth_mm)):
            i = block.start + j
            if wanted is not None and not wanted[i]:
                continue
            if not block.has_depth[j]:
                fusion.empty_frames.append(i)
                continue
            depth, rgb, T = block.depth_mm[j], block.rgb[j], block.T_world_camera[j]
            if selector is not None and not selector.offer(depth, correction @ T):
                fusion.not_keyframes[i] = correction @ T
                continue
            if refiner is not None:
                recorded, T = T, refiner(fusion.volume, depth, rgb, T, intr, i)
                correction = T @ invert_pose(recorded)
            integrate(fusion.volume, depth, rgb, T, intr, p)
            fusion.frames_fused.append(i)
            fusion.T_world_camera[i] = T
    if selector is not None:
        fusion.keyframe_reasons = dict(selector.reasons)
    check_empty_frames(store, p, fusion)
    return fusion


def check_empty_frames(store: FrameStore, p: ReconstructParams, fusion) -> None:
    """Raise :class:`InputDataError` naming the first empty frame when more than ``p.max_invalid_frame_fraction`` of
    the frames considered (or all of them) have no valid depth (``fusion``: a :class:`Fusion` or a tiled one)."""
    considered = len(fusion.frames_fused) + len(fusion.not_keyframes) + len(fusion.empty_frames)
    if fusion.empty_frames and (not fusion.frames_fused or
                                len(fusion.empty_frames) > p.max_invalid_frame_fraction * considered):
        raise InputDataError(
            f"{len(fusion.empty_frames)} of {considered} frames have no valid depth in "
            f"[{p.depth_min_m}, {p.depth_max_m}] m (first listed)",
            path=store.path, field="depth", frame=fusion.empty_frames[0],
            expected=f"at most {p.max_invalid_frame_fraction:.0%} of frames without valid depth "
                     "(reconstruct.max_invalid_frame_fraction)",
        )


def extract_mesh(volume: o3d.t.geometry.VoxelBlockGrid, p: ReconstructParams) -> o3d.geometry.TriangleMesh:
    """The fused surface as a legacy triangle mesh with vertex colours (0..1); normals come with the canonical order."""
    return volume.extract_triangle_mesh(weight_threshold=p.min_weight).to_legacy()


def extract_points(volume: o3d.t.geometry.VoxelBlockGrid, p: ReconstructParams, *, canonical: bool = True
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surface points: positions ``(N,3)`` float32 m, unit normals ``(N,3)`` float32, colours ``(N,3)`` uint8.

    In canonical order (:func:`pipeline.recon.store.canonical_point_order`), not open3d's hash-map order;
    ``canonical=False`` leaves them in open3d's order for a caller that sorts what it keeps
    (:meth:`pipeline.recon.surface.Surface.add` does).
    """
    pcd = volume.extract_point_cloud(weight_threshold=p.min_weight)
    if "positions" not in pcd.point or pcd.point.positions.shape[0] == 0:
        z = np.zeros((0, 3), np.float32)
        return z, z.copy(), np.zeros((0, 3), np.uint8)
    xyz = pcd.point.positions.numpy().astype(np.float32)
    normals = pcd.point.normals.numpy().astype(np.float32) if "normals" in pcd.point else np.zeros_like(xyz)
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = normals / np.maximum(norm, 1e-12)
    colors = pcd.point.colors.numpy() if "colors" in pcd.point else np.zeros_like(xyz)
    scale = 255.0 if colors.size and colors.max() <= 1.0 + 1e-6 else 1.0
    colors = np.clip(np.round(colors * scale), 0, 255).astype(np.uint8)
    if not canonical:
        return xyz, normals, colors
    order = canonical_point_order(xyz, normals, colors)
    return xyz[order], normals[order], colors[order]


def iter_voxels(volume: o3d.t.geometry.VoxelBlockGrid, p: ReconstructParams, *, blocks_per_chunk: int = 1024,
                min_weight: float | None = None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Observed voxels (weight >= ``min_weight``, default ``p.min_weight``) in chunks of blocks (bounded memory).

    Yields integer lattice coordinates ``(M,3)`` int32 (world point = ``k * voxel_size_m``) and
    truncated SDF values ``(M,)`` float32. Blocks come sorted by block coordinate, so the chunks are
    the same in every run (the hash map's own order is not).
    """
    hashmap = volume.hashmap()
    active = hashmap.active_buf_indices().to(o3c.int64).numpy()
    keys = hashmap.key_tensor().numpy()[active]
    order = np.lexsort(keys.T[::-1])
    active, keys = active[order], keys[order].astype(np.int32)
    r = p.block_resolution
    # the voxel buffers as numpy views (no copy): row = buffer index, column = voxel (x fastest, then y, then z),
    # read with numpy's row gathers (open3d's own indexing copies element by element, several times slower)
    tsdf_all = volume.attribute("tsdf").numpy().reshape(-1, r**3)
    weight_all = volume.attribute("weight").numpy().reshape(-1, r**3)
    z, y, x = np.meshgrid(np.arange(r), np.arange(r), np.arange(r), indexing="ij")
    offset = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1).astype(np.int32)  # lattice offset of each voxel
    threshold = p.min_weight if min_weight is None else min_weight
    for s in range(0, len(active), blocks_per_chunk):
        buf = active[s : s + blocks_per_chunk]
        keep = weight_all[buf] >= threshold
        if not keep.any():
            continue
        block, voxel = np.nonzero(keep)
        lattice = keys[s + block] * np.int32(r) + offset[voxel]
        yield lattice, tsdf_all[buf[block], voxel].astype(np.float32)
