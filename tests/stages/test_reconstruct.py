"""The reconstruct stage end to end on a two-room scene rendered by the simulator, with known ground truth."""

from pathlib import Path

import numpy as np
import pytest

from pipeline.config import GridParams, ReconstructParams
from pipeline.paramsfile import parse_params
from pipeline.errors import InputDataError, StageError
from pipeline.paths import Workspace
from pipeline.recon import Recon
from pipeline.recon.build import reconstruct
from pipeline.recon.evaluate import grid_accuracy
from pipeline.engine.runner import StageContext
from stages import STAGES
from stages.reconstruct import run
from tests.fixtures.recon_scenes import write_box_room_frames

FLOOR_Z = 0.3  # not zero, so the floor must really be estimated


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("recon")
    frames, gt = write_box_room_frames(tmp / "frames.zarr", n_frames=96, width=320, height=240, floor_z=FLOOR_Z)
    params = parse_params({"scenes": {"box": {"source": "simulate"}}, "grid": {"rows": 160, "cols": 200}})
    ws = Workspace(root=tmp, data_dir=tmp / "data", manifests_dir=tmp / "manifests")
    out = tmp / "out"
    out.mkdir()
    outputs = {name: out / Path(ws.artifact(name, "box")).name for name in STAGES["reconstruct"].outputs}
    ctx = StageContext.build(STAGES["reconstruct"], params, "box", ws, {"frames": frames}, outputs, show_progress=False)
    summary = run(ctx)
    return summary, Recon(outputs["recon"]), gt, params, frames


def gt_footprint(built, instance_id):
    _, recon, gt, _, _ = built
    return gt.instance_footprints(recon.grid) == instance_id


def test_grids_match_the_ground_truth_floor_plan(built):
    summary, recon, gt, params, _ = built
    figures = grid_accuracy(recon, gt, params.reconstruct)
    print(figures)
    assert figures["floor_error_m"] <= 0.02
    assert figures["iou_occupied"] >= 0.9
    assert figures["iou_free"] >= 0.9
    assert figures["iou_navigable"] >= 0.9


def test_artifact_contract_for_downstream_stages(built):
    summary, recon, _, params, _ = built
    g = recon.grid
    assert (g.rows, g.cols, g.cell_size_m) == (160, 200, 0.05)
    assert recon.occupancy.dtype == np.uint8 and recon.occupancy.shape == (160, 200)
    assert recon.navigable.dtype == bool and recon.color.shape == (160, 200, 3) and recon.color.dtype == np.uint8
    h = recon.height
    assert h.dtype == np.float32 and np.isnan(h[recon.occupancy == 0]).mean() > 0.9
    # The table (0.75 m tall, brown) reads as such on most of its footprint (its top is seen at grazing angles).
    table = gt_footprint(built, 1)
    seen = np.isfinite(h[table])
    assert seen.mean() > 0.6
    assert abs(np.median(h[table][seen]) - 0.75) < 0.03
    rgb = np.median(recon.color[table][seen], axis=0)
    assert rgb[0] > rgb[2] + 40
    assert recon.attrs["occupancy_codes"] == {"0": "unknown", "1": "free", "2": "occupied"}
    assert params.reconstruct.depth_stride == "auto" and recon.attrs["tsdf"]["depth_stride"] == 1  # the stride used
    assert recon.robot_radius_m == 0.18 and recon.height_band_m == (0.1, 1.5)
    assert recon.fused.all() and np.isfinite(recon.poses).all()
    assert recon.mesh_path.name == "recon_mesh.ply" and recon.points_path.is_file()
    assert len(recon.mesh().triangles) == summary["mesh_triangles"] > 1000
    assert summary["frames_fused"] == 96 and summary["points_outside_grid"] == 0
    assert summary["bounds_min"][2] == pytest.approx(FLOOR_Z, abs=0.03)


def test_same_inputs_give_the_same_bytes(built, tmp_path):
    *_, frames = built
    p, grid = ReconstructParams(), GridParams(rows=160, cols=200)
    for k in ("a", "b"):
        (tmp_path / k).mkdir()
        reconstruct(frames, tmp_path / k / "recon.zarr", tmp_path / k / "recon_mesh.ply",
                    tmp_path / k / "recon_points.ply", p, grid)
    from pipeline.store import content_digest

    for name in ("recon.zarr", "recon_mesh.ply", "recon_points.ply"):
        assert content_digest(tmp_path / "a" / name) == content_digest(tmp_path / "b" / name), name


def test_a_grid_too_small_for_the_cameras_names_the_frame(built, tmp_path):
    *_, frames = built
    with pytest.raises(InputDataError, match=r"field pose; frame \d+: camera at .* lies outside the top-down grid"):
        reconstruct(frames, tmp_path / "r.zarr", tmp_path / "m.ply", tmp_path / "p.ply", ReconstructParams(),
                    GridParams(rows=20, cols=20, extent="fixed"))


def test_surface_outside_the_grid_is_counted_not_clipped_silently(built, tmp_path):
    *_, frames = built
    with pytest.raises(StageError, match=r"surface points \(.*\) fall outside the 60x120 grid"):
        reconstruct(frames, tmp_path / "r.zarr", tmp_path / "m.ply", tmp_path / "p.ply", ReconstructParams(),
                    GridParams(rows=60, cols=120, extent="fixed"))


def test_a_grid_too_small_for_the_surface_grows_by_whole_tiles(built, tmp_path):
    *_, frames = built
    reconstruct(frames, tmp_path / "r.zarr", tmp_path / "m.ply", tmp_path / "p.ply", ReconstructParams(),
                GridParams(rows=60, cols=120))
    recon = Recon(tmp_path / "r.zarr")
    assert (recon.grid.rows, recon.grid.cols) == (128, 256)  # the 3 x 6 m rooms plus 1 m each side, in 128-cell tiles
    assert recon.meta.stats["points_outside_grid"] == 0
