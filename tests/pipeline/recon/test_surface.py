"""The surface points in parts (pipeline.recon.surface): exact order statistics, and a points file and face test
that are those of the whole arrays whatever the parts."""

import numpy as np
import pytest

from pipeline.recon.store import write_points
from pipeline.recon.surface import Surface, median, order_statistics, percentiles


def _chunked(values, size):
    return lambda: (values[i : i + size] for i in range(0, len(values), size))


@pytest.mark.parametrize("seed", range(6))
def test_medians_and_percentiles_streamed_are_numpys_on_the_whole_array(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 20000))
    values = rng.normal(0.0, rng.uniform(0.01, 60.0), n).astype(np.float32)
    if seed % 2:
        values = np.round(values, 2).astype(np.float32)  # many ties, negative and positive
    chunks = _chunked(values, 777)
    assert median(chunks) == np.median(values.astype(np.float64))
    want = np.percentile(values, [0.5, 99.5])
    got = percentiles(chunks, [0.5, 99.5])
    assert got.dtype == want.dtype and np.array_equal(got, want)
    ranks = rng.integers(0, n, 5)
    stats = order_statistics(chunks, ranks)
    assert [stats[int(r)] for r in ranks] == [np.sort(values)[r] for r in ranks]


def test_a_rank_outside_the_values_is_refused():
    with pytest.raises(ValueError, match="outside 0..2"):
        order_statistics(_chunked(np.ones(3, np.float32), 2), [3])


def _cloud(rng, n):
    xyz = rng.uniform([0.0, 0.0, 0.0], [4.0, 3.0, 2.0], (n, 3)).astype(np.float32)
    xyz[: n // 4] = np.round(xyz[: n // 4], 1)  # shared positions: the colours and normals break the ties
    normals = rng.normal(size=(n, 3)).astype(np.float32)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    colors = rng.integers(0, 4, (n, 3)).astype(np.uint8)
    return xyz, normals, colors


def tiled_surface(xyz, normals, colors, tmp_path, side=1.0):
    """The points in ``side`` m tiles, spilled under ``tmp_path`` in shuffled tile order."""
    owner = lambda xy: np.floor(np.asarray(xy, np.float64) / side).astype(np.int64)  # noqa: E731
    surface = Surface(owner, tmp_path)
    tile = owner(xyz[:, :2])
    for t in np.random.default_rng(1).permutation(np.unique(tile, axis=0)):
        mine = (tile == t).all(axis=1)
        surface.add((int(t[0]), int(t[1])), xyz[mine], normals[mine], colors[mine])
    return surface


def test_the_points_file_of_spilled_tiles_is_the_bytes_open3d_writes_for_the_whole_cloud(tmp_path):
    xyz, normals, colors = _cloud(np.random.default_rng(0), 30000)
    write_points(tmp_path / "whole.ply", xyz, normals, colors)
    surface = tiled_surface(xyz, normals, colors, tmp_path)
    assert len(surface.parts) >= 12 and surface.count == len(xyz)
    assert surface.write_ply(tmp_path / "tiled.ply") == {"file": "tiled.ply", "count": len(xyz)}
    assert Surface.of(xyz, normals, colors).write_ply(tmp_path / "one.ply")["count"] == len(xyz)
    whole = (tmp_path / "whole.ply").read_bytes()
    assert (tmp_path / "tiled.ply").read_bytes() == whole == (tmp_path / "one.ply").read_bytes()


def test_a_parts_x_range_is_the_float64_comparison_searched_in_float32():
    rng = np.random.default_rng(2)
    xyz = np.c_[rng.normal(0, 10, (5000, 1)), np.zeros((5000, 2))].astype(np.float32)
    part = Surface.of(xyz, np.zeros_like(xyz)).parts[(0, 0)]
    x = part.read("x").astype(np.float64)
    bounds = [*rng.normal(0, 10, 200), *x[:50], *np.nextafter(x[:50], np.inf), *np.nextafter(x[:50], -np.inf)]
    for lo in bounds:
        start, stop = part.x_range(lo, lo + 1.0)
        assert (start, stop) == (int((x < lo).sum()), int((x < lo + 1.0).sum()))
