"""The map store: round trip, tile-major layout, reader errors."""

import json

import numpy as np
import pytest
import torch
import zarr

from pipeline.errors import ArtifactError, MissingInputError
from pipeline.geometry import GridSpec
from pipeline.maps.fusion import BlockPoints, TopDownAccumulator, VoxelAccumulator
from pipeline.maps.store import FORMAT_VERSION, Lattice, MapAttrs, MapVoxels, SemanticMap, tile_order
from pipeline.maps.writer import write_map
from pipeline.store import artifact_attrs

GRID = GridSpec(rows=10, cols=12, cell_size_m=0.5, origin_xy=(0.0, 5.0))
LAT = Lattice(GRID, 0.0, 0.0, 2.0, 0.5)


def _fused(seed=0, n=40, dim=8):
    rng = np.random.default_rng(seed)
    cells = rng.choice(GRID.rows * GRID.cols, n, replace=False)
    pts = BlockPoints(cell=np.repeat(cells, 2), level=rng.integers(0, 4, 2 * n), dist_m=np.ones(2 * n, np.float32))
    feats = torch.from_numpy(rng.standard_normal((2 * n, dim)).astype(np.float32))
    top, vox = TopDownAccumulator(LAT, dim), VoxelAccumulator(LAT, dim)
    top.add(pts, feats)
    vox.add(pts, feats)
    return top.result(), vox.result()


def _write(path, artifact="cfmap", **kw):
    cells, vox = _fused(**kw)
    attrs = artifact_attrs(artifact, FORMAT_VERSION, artifact, "blake2b:test",
                           encoder={"name": "oracle", "dim": cells.features.shape[1], "temperature": None})
    write_map(path, attrs, GRID, LAT, cells.to_store(), tile_cells=4,
              voxels=vox.to_store(GRID) if artifact == "cfmap" else None)
    return cells, vox


def test_round_trip(tmp_path):
    cells, vox = _write(tmp_path / "cfmap.zarr")
    m = SemanticMap(tmp_path / "cfmap.zarr")
    assert m.artifact == "cfmap" and m.grid == GRID and m.dim == 8 and m.n_cells == len(cells.cell)
    order = np.argsort(m.cell)
    assert m.cell[order].tolist() == cells.cell.tolist()
    np.testing.assert_allclose(m.features()[order], cells.features.numpy(), atol=1e-3)  # fp16
    assert m.level[order].tolist() == cells.level.tolist() and m.count[order].tolist() == cells.count.tolist()
    # the index points every observed cell at its row
    rows, cols = np.divmod(m.cell, GRID.cols)
    assert (m.index[rows, cols] == np.arange(m.n_cells)).all()
    assert (m.index >= 0).sum() == m.n_cells
    v = m.voxels()
    assert isinstance(v, MapVoxels) and v.key.shape == (len(vox.cell), 3) and v.features.dtype == np.float16
    assert (np.diff(v.key.astype(np.int64) @ [10**6, 10**3, 1]) > 0).all()  # keys ascending (row, col, level)
    assert isinstance(m.meta, MapAttrs) and m.meta.lattice.levels == 4 and m.meta.encoder.name == "oracle"
    assert m.lattice == LAT and m.meta.n_voxels == len(v)


def test_tiles_are_contiguous_and_hold_only_their_cells(tmp_path):
    _write(tmp_path / "vlmap.zarr", artifact="vlmap")
    m = SemanticMap(tmp_path / "vlmap.zarr")
    seen = 0
    for tr in range(3):
        for tc in range(3):
            cells, feats = m.tile(tr, tc)
            r, c = np.divmod(cells, GRID.cols)
            assert ((r // 4 == tr) & (c // 4 == tc)).all() and feats.shape == (len(cells), 8)
            seen += len(cells)
    assert seen == m.n_cells and m.voxels() is None
    feats = zarr.open_group(str(tmp_path / "vlmap.zarr"), mode="r")["top"]["features"]
    assert feats.chunks == (16, 8)  # tile_cells^2 rows, the whole feature axis


def test_tile_order_offsets():
    grid = GridSpec(rows=4, cols=4, cell_size_m=1.0, origin_xy=(0.0, 4.0))
    order, start = tile_order(np.array([15, 0, 5, 2, 10]), grid, 2)
    # tiles: 0 -> cells 0, 5 (rows/cols < 2); 1 -> cell 2; 2 -> none; 3 -> cells 10, 15
    assert np.array([15, 0, 5, 2, 10])[order].tolist() == [0, 5, 2, 10, 15]
    assert start.tolist() == [0, 2, 3, 3, 5]


def test_reader_errors(tmp_path):
    with pytest.raises(MissingInputError, match="semantic map not found"):
        SemanticMap(tmp_path / "nothing.zarr")
    _write(tmp_path / "m.zarr")
    meta = tmp_path / "m.zarr" / "zarr.json"
    doc = json.loads(meta.read_text())
    doc["attributes"]["format_version"] = 99
    meta.write_text(json.dumps(doc))
    with pytest.raises(ArtifactError, match="format_version 99, this zipon reads 1 and 2; rebuild it with: zipon run --force"):
        SemanticMap(tmp_path / "m.zarr")
    doc["attributes"]["artifact"] = "recon"
    meta.write_text(json.dumps(doc))
    with pytest.raises(ArtifactError, match="attrs.artifact is 'recon', expected one of"):
        SemanticMap(tmp_path / "m.zarr")
    doc["attributes"].update(artifact="cfmap", format_version=FORMAT_VERSION)
    doc["attributes"]["grid"]["rows"] = "many"
    meta.write_text(json.dumps(doc))
    with pytest.raises(ArtifactError, match=r"m.zarr: attrs.grid.rows: .*rebuild it with: zipon run --force"):
        SemanticMap(tmp_path / "m.zarr")


def test_attrs_a_reader_would_refuse_are_never_written(tmp_path):
    cells, _ = _fused()
    attrs = artifact_attrs("vlmap", FORMAT_VERSION, "vlmap", "blake2b:test")  # no encoder identity
    with pytest.raises(ArtifactError, match="attrs.encoder: Field required"):
        write_map(tmp_path / "v.zarr", attrs, GRID, LAT, cells.to_store(), tile_cells=4)
    assert not (tmp_path / "v.zarr").exists()
