"""VLMaps' REAL map-building loop, timed on the frames ``bench_maps.py`` fuses (calibrates ``vlmaps_loop.py``).

Needs a checkout of VLMaps (github.com/vlmaps/vlmaps, ``vlmaps/map/vlmap_builder.py``), passed as ``--vlmaps-src``;
nothing of it is copied into this repository. Its ``VLMapBuilder.create_mobile_base_map`` runs UNMODIFIED on
files written the way VLMaps reads them (RGB PNGs, depth ``.npy`` in metres, a pose file of 4x4 base poses), except
for the encoder: ``_init_lseg`` is overridden to load no network and ``get_lseg_feat`` (with the LSeg network module
it needs) is replaced by a stub returning pre-made random unit features of the stated ``(1, D, h, w)`` size, so the
encoder costs nothing. ``gdown`` (the checkpoint download in ``_init_lseg``) is stubbed too; ``h5py`` (its map
writer) is real.

The builder's own calls are timed from outside: its ``tqdm`` frame iterator records when each frame starts and its
``transform_pc`` (the last call before the per-point loop) when the loop starts, so a frame's LOOP time is
``start of next frame - end of transform_pc`` (the per-point loop plus one ``set.add``); file reads, the encoder
stub, back-projection and the final map save are outside it and reported as the whole call's wall time.
"""

from __future__ import annotations

import importlib.util
import sys
import tempfile
import time
import types
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from omegaconf import OmegaConf

from pipeline.geometry import Intrinsics, camera_pose_from_base

VLMAPS_SAMPLE_RATE = 100  # config/map_config/vlmaps.yaml depth_sample_rate: every 100th valid depth pixel


@dataclass
class RealLoopTiming:
    """What one ``create_mobile_base_map`` call cost."""

    frames: int
    points: int  # points the per-point loop iterated over (valid depth after sampling)
    in_range: int  # of those, the points inside the map (the rest leave the loop at its first check)
    loop_seconds: float  # the per-point loops of all frames, wall
    loop_cpu_seconds: float  # the same, CPU time of this process (robust to other load on a shared machine)
    call_seconds: float  # the whole call: file reads, encoder stub, back-projection, loops, map save
    voxels: int  # occupied voxels of the saved map

    @property
    def us_per_point(self) -> float:
        return self.loop_seconds / self.points * 1e6

    @property
    def cpu_us_per_point(self) -> float:
        return self.loop_cpu_seconds / self.points * 1e6

    @property
    def loop_cpu_ms_per_frame(self) -> float:
        return self.loop_cpu_seconds / self.frames * 1e3


def load_builder(src: Path) -> types.ModuleType:
    """The module of ``VLMapBuilder`` from the checkout at ``src``, with the encoder modules replaced by stubs (see the module doc).

    Raises ``FileNotFoundError`` naming the file when ``src`` is not a VLMaps checkout.
    """
    path = Path(src) / "vlmaps" / "map" / "vlmap_builder.py"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: not found; --vlmaps-src must be a checkout of github.com/vlmaps/vlmaps")
    import h5py  # noqa: F401  (VLMaps' save_3d_map writes the map with it: fail here, not after the loops)

    def encoder_missing(*args, **kwargs):
        raise RuntimeError("the LSeg network is stubbed out in this benchmark")

    stubs = {
        "gdown": types.ModuleType("gdown"),
        "vlmaps.lseg.modules.models.lseg_net": types.ModuleType("vlmaps.lseg.modules.models.lseg_net"),
        "vlmaps.utils.lseg_utils": types.ModuleType("vlmaps.utils.lseg_utils"),
    }
    stubs["vlmaps.lseg.modules.models.lseg_net"].LSegEncNet = encoder_missing
    stubs["vlmaps.utils.lseg_utils"].get_lseg_feat = encoder_missing  # replaced per run by FeatureStub
    saved_path, saved_modules = list(sys.path), {name: sys.modules.get(name) for name in stubs}
    sys.path.insert(0, str(Path(src).resolve()))
    sys.modules.update(stubs)
    try:
        spec = importlib.util.spec_from_file_location("vlmaps_real_vlmap_builder", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)  # imports the real vlmaps.utils.mapping_utils from src
    finally:
        sys.path[:] = saved_path
        for name, old in saved_modules.items():
            if old is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = old
    return module


def _now() -> tuple[float, float]:
    return time.perf_counter(), time.process_time()


class _FrameClock:
    """Wraps the builder's ``tqdm(...)`` iterator: records when each frame starts (and when iteration ends)."""

    def __init__(self, stamps: list[tuple[float, float]]):
        self.stamps = stamps

    def __call__(self, iterable, total=None, **kwargs):
        for item in iterable:
            self.stamps.append(_now())
            yield item
        self.stamps.append(_now())


def run_real_loop(src: Path, depth_m: np.ndarray, T_world_camera: np.ndarray, intr: Intrinsics, rgb: np.ndarray,
                  feats_bdhw: np.ndarray, *, camera_height_m: float, pitch: float, sample_rate: int,
                  map_height_m: float = 2.0, cell_size_m: float = 0.05, grid_cells: int = 1000) -> RealLoopTiming:
    """Run VLMaps' ``create_mobile_base_map`` on these frames; returns its timings.

    ``depth_m`` ``(N,H,W)`` float32 metres (0 invalid), ``T_world_camera`` ``(N,4,4)`` of a camera ``camera_height_m``
    above the floor pitched down by ``pitch`` (as :func:`~pipeline.geometry.camera_pose_from_base` builds it), ``intr``
    of the depth AND the ``rgb`` ``(N,H,W,3)`` uint8 images (VLMaps projects both with one matrix), ``feats_bdhw``
    ``(B,D,h,w)`` float32 features returned by the encoder stub, cycled over the frames. ``map_height_m`` sets the
    number of height cells VLMaps keeps (its ``camera_height`` / ``cell_size``); ``sample_rate`` is its
    ``depth_sample_rate`` (1 = every valid pixel).
    """
    module = load_builder(src)
    n = len(depth_m)
    # VLMaps' base frame: x forward, y left, z up on the floor; base2cam is the camera on its mast
    base2cam = camera_pose_from_base(0.0, 0.0, 0.0, camera_height_m, pitch=pitch)
    base_poses = T_world_camera @ np.linalg.inv(base2cam)
    calls = {"frame": 0}

    def encoder_stub(model, image, labels, transform, device, *args, **kwargs) -> np.ndarray:
        out = feats_bdhw[calls["frame"] % len(feats_bdhw)][None]
        calls["frame"] += 1
        return out

    loop_starts: list[tuple[float, float]] = []
    points: list[int] = []
    in_range: list[int] = []
    real_transform_pc = module.transform_pc
    levels = int(map_height_m / cell_size_m)  # VLMaps' vh

    def transform_pc(pc, pose):
        out = real_transform_pc(pc, pose)
        # the loop's base_pos2grid_id_3d and _out_of_range, vectorized (int() truncates toward zero)
        row = grid_cells / 2 - np.trunc(out[0] / cell_size_m)
        col = grid_cells / 2 - np.trunc(out[1] / cell_size_m)
        h = np.trunc(out[2] / cell_size_m)
        inside = (row >= 0) & (row < grid_cells) & (col >= 0) & (col < grid_cells) & (h >= 0) & (h < levels)
        points.append(pc.shape[1])
        in_range.append(int(inside.sum()))
        loop_starts.append(_now())
        return out

    frame_starts: list[tuple[float, float]] = []
    module.get_lseg_feat = encoder_stub
    module.transform_pc = transform_pc
    module.tqdm = _FrameClock(frame_starts)
    dim = feats_bdhw.shape[1]

    class Builder(module.VLMapBuilder):
        def _init_lseg(self):  # the encoder stub: no network, no checkpoint
            self.device, self.clip_feat_dim = "cpu", dim
            return None, None, 480, 520, [0.5] * 3, [0.5] * 3

    K = [float(v) for v in (intr.fx, 0.0, intr.cx, 0.0, intr.fy, intr.cy, 0.0, 0.0, 1.0)]
    config = OmegaConf.create({
        "pose_info": {"rot_type": "mat", "camera_height": map_height_m},
        "cell_size": cell_size_m, "grid_size": grid_cells, "depth_sample_rate": sample_rate, "cam_calib_mat": K,
    })
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        rgb_paths, depth_paths = [], []
        for i in range(n):
            rgb_paths.append(root / f"rgb_{i}.png")
            depth_paths.append(root / f"depth_{i}.npy")
            cv2.imwrite(str(rgb_paths[-1]), cv2.cvtColor(rgb[i], cv2.COLOR_RGB2BGR))
            np.save(depth_paths[-1], depth_m[i].astype(np.float32))
        pose_path = root / "poses.txt"
        np.savetxt(pose_path, base_poses.reshape(n, 16))
        builder = Builder(root, config, pose_path, rgb_paths, depth_paths, base2cam, np.eye(4))
        np.random.seed(0)  # its depth sampling shuffles with the global generator
        t0 = time.perf_counter()
        builder.create_mobile_base_map()
        call_seconds = time.perf_counter() - t0
        import h5py

        with h5py.File(root / "vlmap" / "vlmaps.h5df", "r") as f:
            voxels = int(f["grid_pos"].shape[0])
    wall, cpu = np.sum(np.array(frame_starts[1:]) - np.array(loop_starts), axis=0)
    return RealLoopTiming(frames=n, points=int(sum(points)), in_range=int(sum(in_range)), loop_seconds=float(wall),
                          loop_cpu_seconds=float(cpu), call_seconds=call_seconds, voxels=voxels)
