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
