"""Floors found from the surface and the camera heights (pipeline.recon.floors), and the issue's real-data case:
the TUM fr1/rpy sample given twice, the second copy raised 3 m, reconstructs as two floors."""

import shutil

import numpy as np
import pytest

from pipeline.config import GridParams, IngestParams, ReconstructParams
from pipeline.errors import ConfigError, StageError
from pipeline.readers.ingest import ingest
from pipeline.recon import Recon
from pipeline.recon.build import reconstruct
from pipeline.recon.floors import camera_levels, find_floors, surface_peaks
from pipeline.recon.store import floor_bands
from pipeline.recon.surface import Surface
from tests.fixtures.real_data import TUM_RPY, raised_copy

FLAT = 0.5  # heights of the synthetic floors below: 0.5 and 3.5 m


def _plane(rng, n, z, x=(0, 6), y=(0, 4), normal=(0.0, 0.0, 1.0)):
    xyz = np.c_[rng.uniform(*x, n), rng.uniform(*y, n), z + rng.normal(0, 0.004, n)]
    return xyz, np.tile(normal, (n, 1))


def two_storeys(rng, *, upper_floor=True, ceilings=True):
    """Upward and downward surfaces of a two-storey house: floors at 0.5 and 3.5 m, tables, ceilings."""
    parts = [_plane(rng, 20000, FLAT), _plane(rng, 3000, FLAT + 0.75, x=(1, 2), y=(1, 2))]
    if upper_floor:
        parts += [_plane(rng, 20000, FLAT + 3.0), _plane(rng, 3000, FLAT + 3.72, x=(3, 4), y=(1, 2))]
    if ceilings:
        parts += [_plane(rng, 8000, FLAT + 2.7, normal=(0, 0, -1.0)), _plane(rng, 8000, FLAT + 5.7, normal=(0, 0, -1.0))]
    wall = np.c_[rng.uniform(0, 6, 4000), np.zeros(4000), rng.uniform(FLAT, FLAT + 5.7, 4000)]
    parts.append((wall, np.tile([0.0, 1.0, 0.0], (4000, 1))))
    return np.concatenate([a for a, _ in parts]), np.concatenate([b for _, b in parts])


def cameras(rng, n_low=80, n_high=60, n_stairs=10):
    z = [FLAT + 1.3 + rng.normal(0, 0.05, n_low), FLAT + 4.3 + rng.normal(0, 0.05, n_high),
         np.linspace(FLAT + 1.5, FLAT + 4.1, n_stairs)]
    return np.concatenate(z)


def test_camera_heights_cluster_per_floor_and_stair_frames_belong_to_none():
    rng = np.random.default_rng(0)
    z = cameras(rng)
    levels, label = camera_levels(z)
    assert np.allclose(levels, [FLAT + 1.3, FLAT + 4.3], atol=0.05)
    assert (label[:80] == 0).all() and (label[80:140] == 1).all()
    assert (label[140:] == -1).any()  # mid-flight frames are on no floor
    # a handheld camera sweeping 1.5 m up and down is one floor
    one, lab = camera_levels(1.0 + rng.uniform(-0.75, 0.75, 200))
    assert len(one) == 1 and (lab == 0).all()


def test_two_floors_with_their_ceilings_are_found_from_surface_and_cameras():
    rng = np.random.default_rng(1)
    xyz, normals = two_storeys(rng)
    found = find_floors(Surface.of(xyz, normals), cameras(rng), ReconstructParams())
    assert [round(f.floor_z_m, 2) for f in found.floors] == [FLAT, FLAT + 3.0]
    assert [f.ceiling_z_m for f in found.floors] == pytest.approx([FLAT + 2.7, FLAT + 5.7], abs=0.01)
    assert [f.source for f in found.floors] == ["surface", "surface"]
    # stair frames within half a storey of a level count on its floor, the 4 mid-flight ones on none
    assert [f.frames for f in found.floors] == [80 + 3, 60 + 3] and (found.camera_floor == -1).sum() == 4
    assert found.warnings == []
    (lo0, hi0), (lo1, hi1) = floor_bands(found.floors)
    assert lo0 == -np.inf and hi0 == pytest.approx(FLAT + 3.0 - 0.15, abs=0.01) and hi1 == np.inf
    peaks = dict(surface_peaks(Surface.of(xyz, normals)))
    assert max(peaks.values()) > 20  # the floors' areas (6 x 4 m)


def test_a_camera_level_without_floor_surface_takes_the_other_floors_camera_height_with_a_warning():
    rng = np.random.default_rng(2)
    xyz, normals = two_storeys(rng, upper_floor=False, ceilings=False)
    found = find_floors(Surface.of(xyz, normals), cameras(rng), ReconstructParams())
    assert [f.source for f in found.floors] == ["surface", "cameras"]
    assert found.floors[1].floor_z_m == pytest.approx(FLAT + 3.0, abs=0.05)
    assert len(found.warnings) == 1 and "no floor surface under the cameras at 4.80 m" in found.warnings[0]
    assert "reconstruct.floors" in found.warnings[0]


def test_a_floor_seen_but_never_walked_is_reported():
    rng = np.random.default_rng(3)
    xyz, normals = two_storeys(rng)
    found = find_floors(Surface.of(xyz, normals), FLAT + 1.3 + rng.normal(0, 0.05, 100), ReconstructParams())
    assert len(found.floors) == 1 and found.floors[0].floor_z_m == pytest.approx(FLAT, abs=0.01)
    assert any("looks like a floor no camera stood on" in w and "3.50 m" in w for w in found.warnings)


def test_no_floor_under_any_camera_level_is_an_error_naming_the_key():
    rng = np.random.default_rng(4)
    wall = np.c_[rng.uniform(0, 4, 500), np.zeros(500), rng.uniform(0, 6, 500)]
    with pytest.raises(StageError, match="no floor found under any of the 2 camera levels.*reconstruct.floors"):
        find_floors(Surface.of(wall, np.tile([0.0, 1.0, 0.0], (500, 1))), cameras(rng), ReconstructParams())


def test_pinned_floors_are_checked_against_the_surface():
    rng = np.random.default_rng(5)
    xyz, normals = two_storeys(rng)
    pinned = ReconstructParams(floors=[{"floor_z_m": FLAT, "name": "ground floor"}, {"floor_z_m": FLAT + 3.0}])
    found = find_floors(Surface.of(xyz, normals), cameras(rng), pinned)
    assert [(f.name, f.source) for f in found.floors] == [("ground floor", "pinned"), ("floor 1", "pinned")]
    wrong = ReconstructParams(floors=[{"floor_z_m": FLAT}, {"floor_z_m": FLAT + 2.2}])
    with pytest.raises(ConfigError) as err:
        find_floors(Surface.of(xyz, normals), cameras(rng), wrong)
    line = str(err.value)
    assert "\n" not in line and line.startswith("reconstruct.floors[1].floor_z_m: no floor at 2.70 m")
    assert "3.50 m" in line  # where floors are


def test_a_pinned_floor_list_that_is_not_a_building_is_refused_at_load():
    with pytest.raises(ValueError, match="floors\n.*floor 1 \\(floor_z_m 1.0\\) must lie at least 1.8 m above floor 0"):
        ReconstructParams(floors=[{"floor_z_m": 0.0}, {"floor_z_m": 1.0}])
    with pytest.raises(ValueError, match="either floor_z_m .* or floors"):
        ReconstructParams(floor_z_m=0.0, floors=[{"floor_z_m": 0.0}])
    with pytest.raises(ValueError, match="ceiling_z_m 0.5 must lie above floor_z_m 1.0"):
        ReconstructParams(floors=[{"floor_z_m": 1.0, "ceiling_z_m": 0.5}])
    assert "floors" not in ReconstructParams().model_dump(mode="json")  # unpinned: digests stay as they were


# ----------------------------------------------------------------------------- the real-data case

def occupied_iou(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a == 2, b == 2
    return float((a & b).sum() / max((a | b).sum(), 1))


@pytest.fixture(scope="module")
def tum_two_floors(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tum_floors")
    down = shutil.copytree(TUM_RPY, tmp / "fr1_down")
    up = raised_copy(TUM_RPY, tmp / "fr1_up", 3.0)
    ingest_params = IngestParams(tum_camera="fr1")
    p, grid = ReconstructParams(), GridParams()
    out = {}
    for name, sources in (("single", [down]), ("both", [down, up])):
        frames = tmp / f"{name}_frames.zarr"
        ingest(sources, frames, ingest_params, "tum", params_digest="test", log=lambda m: None)
        recon = tmp / f"{name}.zarr"
        summary = reconstruct(frames, recon, tmp / f"{name}_mesh.ply", tmp / f"{name}_points.ply", p, grid)
        out[name] = (summary, Recon(recon))
    return out


def test_two_logs_three_metres_apart_are_two_floors_each_with_the_single_logs_grid(tum_two_floors):
    single_summary, single = tum_two_floors["single"]
    summary, both = tum_two_floors["both"]
    assert len(single.floors) == 1 and single.attrs["format_version"] == 1 and "floors" not in single.attrs
    assert len(both.floors) == 2 and both.attrs["format_version"] == 2
    f0, f1 = both.floors
    assert f1.floor_z_m - f0.floor_z_m == pytest.approx(3.0, abs=0.05)
    assert f0.floor_z_m == pytest.approx(single.floor_z, abs=0.01)
    assert (f0.frames, f1.frames) == (30, 30)
    for i in (0, 1):
        floor = both.floor(i)
        assert floor.grid == single.grid  # one placement: the copies cover the same x, y
        iou = occupied_iou(floor.occupancy, single.occupancy)
        print(f"floor {i}: floor_z {floor.floor_z:.4f} m, occupied IoU vs the single log {iou:.4f}")
        assert iou >= 0.98
        assert floor.navigable.sum() == pytest.approx(single.navigable.sum(), rel=0.02)
    # floor 0 is read as today's single floor: the root's arrays
    assert np.array_equal(both.occupancy, both.floor(0).occupancy) and both.floor_z == f0.floor_z_m
    # no stairs in this log: usable, with the warning recorded in the summary (the manifest)
    assert both.stairs == () and "stairs" not in single_summary
    assert summary["stairs"] == [] and len(summary["warnings"]) == 1
    assert summary["warnings"][0].startswith("no stairs or ramp joins floor 0 (0.04 m) and floor 1 (3.04 m)")
    assert [f["floor_z_m"] for f in summary["floors"]] == [f0.floor_z_m, f1.floor_z_m]
    assert both.floor_of_z(np.array([0.0, 1.5, 2.8, 3.1, 9.0])).tolist() == [0, 0, 0, 1, 1]
