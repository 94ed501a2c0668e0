"""North-up renders of a recon.zarr."""

import pytest

from pipeline.config import GridParams, ReconstructParams
from pipeline.errors import ConfigError
from pipeline.recon.build import reconstruct
from pipeline.recon.render import WHATS, render_recon
from tests.fixtures.recon_scenes import write_box_room_frames


def test_every_view_renders_a_png(tmp_path):
    import cv2

    frames, _ = write_box_room_frames(tmp_path / "f.zarr", n_frames=36, width=128, height=96)
    recon = tmp_path / "recon.zarr"
    reconstruct(frames, recon, tmp_path / "recon_mesh.ply", tmp_path / "recon_points.ply",
                ReconstructParams(), GridParams(rows=120, cols=160))
    for what in WHATS:
        png = render_recon(recon, what, tmp_path / f"{what}.png")
        img = cv2.imread(str(png))
        assert img is not None and img.shape[0] > 300 and img.shape[1] > 300
        assert (img == 255).all(axis=2).any() or what == "color"
    obstacles = cv2.imread(str(tmp_path / "obstacles.png"))
    assert (obstacles.max(axis=2) < 20).sum() > 1000  # black occupied walls are drawn
    with pytest.raises(ConfigError, match="expected one of obstacles, navigable, color, height"):
        render_recon(recon, "semantic", tmp_path / "x.png")


def test_each_floor_of_a_building_renders_with_its_stairs_and_a_missing_floor_is_refused(house, tmp_path):
    import cv2

    _, recon, _ = house
    pngs = [render_recon(recon.path, "obstacles", tmp_path / f"floor{i}.png", floor=i) for i in (0, 1)]
    lower, upper = (cv2.imread(str(p)) for p in pngs)
    assert lower.shape == upper.shape and not (lower == upper).all()
    orange = [((img[..., 2] > 200) & (img[..., 1] > 100) & (img[..., 1] < 200) & (img[..., 0] < 80)).sum()
              for img in (lower, upper)]
    assert min(orange) > 20  # the stairs' foot on floor 0, its head on floor 1
    with pytest.raises(ConfigError, match="--floor 2: .* has 2 floors \\(0..1\\)"):
        render_recon(recon.path, "obstacles", tmp_path / "x.png", floor=2)


def test_a_region_reads_only_its_tiles_and_the_whole_floor_is_painted_tile_by_tile(tmp_path, monkeypatch):
    import cv2
    import numpy as np

    from pipeline.errors import InputDataError
    from pipeline.region import Region
    from tests.fixtures.tiled_maps import chunk_reads, write_tiled_recon

    recon = write_tiled_recon(tmp_path / "recon.zarr")  # 300 x 420 cells: 3 x 4 tiles of 128
    with chunk_reads(monkeypatch) as reads:
        render_recon(recon, "color", tmp_path / "all.png")
    # the observed box (a pass over the occupancy tiles), then the colour of the 3 x 3 tiles it meets
    assert reads["occupancy"] == 12 and reads["color"] == 9 and "height" not in reads
    # the red block, rows 140..160 x cols 130..170 = x -3.5..-1.5 m, y -1..0 m: tiles (1, 1) only
    with chunk_reads(monkeypatch) as reads:
        png = render_recon(recon, "color", tmp_path / "part.png", region=Region(-3.4, -0.9, -1.6, -0.1))
    assert dict(reads) == {"color": 1}
    img = cv2.imread(str(png))
    red = (img[..., 2] > 180) & (img[..., 1] < 80) & (img[..., 0] < 80)
    assert red.mean() > 0.4  # the picture is the block (with its axes and title around it)
    with chunk_reads(monkeypatch) as reads:
        render_recon(recon, "height", tmp_path / "h.png", region=Region(-9.0, -7.0, -2.0, 6.0))
    assert dict(reads) == {"height": 2 * 6}  # 3 x 2 tiles: their top height first, then the picture
    with pytest.raises(InputDataError, match="field --region: x 12..13 m, y 0..1 m lies outside the floor's grid"):
        render_recon(recon, "color", tmp_path / "x.png", region=Region(12.0, 0.0, 13.0, 1.0))
    assert not (tmp_path / "x.png").exists()
    assert np.isfinite(img).all()
