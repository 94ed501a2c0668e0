"""Frame-to-model pose refinement on real TUM RGB-D frames."""


import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.config import ReconstructParams
from pipeline.frames import FrameStore
from pipeline.recon import tsdf
from pipeline.recon.refine import PoseRefiner
from tests.fixtures.recon_scenes import write_tum_frames
from tests.fixtures.real_data import TUM_RPY as TUM



def _err(T, T_ref):
    rot = Rotation.from_matrix(T[:3, :3] @ T_ref[:3, :3].T).magnitude()
    return float(np.linalg.norm(T[:3, 3] - T_ref[:3, 3])), float(np.degrees(rot))


def test_a_perturbed_pose_is_pulled_back_toward_the_model(tmp_path):
    store = FrameStore(write_tum_frames(tmp_path / "tum.zarr", TUM))
    p = ReconstructParams(refine_poses=True, depth_stride=1)  # full resolution: the intrinsics below are unstrided
    fusion = tsdf.fuse(store, p, frames=range(20))
    block = store.read(20, 21)
    depth = tsdf.prepare_depth(block.depth_mm[0], p)
    T_true = block.T_world_camera[0].astype(np.float64)
    delta = np.eye(4)
    delta[:3, :3] = Rotation.from_euler("y", 1.0, degrees=True).as_matrix()
    delta[:3, 3] = (0.02, 0.0, 0.01)
    T_pred = T_true @ delta
    refiner = PoseRefiner(p)
    refiner.n_seen = 10  # past the warm-up: align at once
    T = refiner(fusion.volume, depth, block.rgb[0], T_pred, store.intrinsics, 20)
    before, after = _err(T_pred, T_true), _err(T, T_true)
    print({"before_m_deg": before, "after_m_deg": after})
    assert after[0] < 0.5 * before[0] and after[1] < before[1]
    assert refiner.summary()["frames_aligned"] == 1 and refiner.rejected == []


def test_refinement_off_keeps_recorded_poses_and_reports_it(tmp_path):
    from pipeline.config import GridParams
    from pipeline.recon import Recon
    from pipeline.recon.build import reconstruct
    from tests.fixtures.recon_scenes import write_box_room_frames

    frames, _ = write_box_room_frames(tmp_path / "f.zarr", n_frames=24, width=96, height=72)
    s = reconstruct(frames, tmp_path / "r.zarr", tmp_path / "m.ply", tmp_path / "p.ply", ReconstructParams(),
                    GridParams(rows=100, cols=160))
    assert s["refinement"] == {"enabled": False, "max_moved_m": 0.0, "median_moved_m": 0.0}
    assert np.array_equal(Recon(tmp_path / "r.zarr").poses, FrameStore(frames).poses())


def test_refined_poses_are_the_same_bits_for_any_number_of_open3d_threads(tmp_path):
    import open3d as o3d

    store = FrameStore(write_tum_frames(tmp_path / "tum.zarr", TUM))
    p = ReconstructParams(refine_poses=True, depth_stride=2)
    runs = []
    try:
        for threads in (1, 0, 0):  # one thread, then open3d's default (every core) twice
            o3d.utility.set_max_threads(threads)
            limit = o3d.utility.get_max_threads()
            refiner = PoseRefiner(p)
            fusion = tsdf.fuse(store, p, frames=range(12), refiner=refiner)
            runs.append(np.stack([fusion.T_world_camera[i] for i in range(12)]))
            assert refiner.summary()["frames_aligned"] >= 6
            assert o3d.utility.get_max_threads() == limit  # the caller's thread limit is restored
    finally:
        o3d.utility.set_max_threads(0)
    recorded = store.poses()[:12]
    assert not np.allclose(runs[0], recorded, atol=1e-6)  # refinement moved the frames ...
    assert np.array_equal(runs[0], runs[1]) and np.array_equal(runs[1], runs[2])  # ... the same way every time
