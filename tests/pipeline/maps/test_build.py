"""build_map on the ray-cast box room: chunks spilled by tile and folded tile by tile on a grid of several tiles, the
same bytes for any tile run size; a failure midway (a chunk whose frames cannot be read, a store whose writing
fails) leaves neither a store nor the scratch folder, and keeps the fold cache that was there."""

import shutil

import numpy as np
import pytest
import zarr

from pipeline.maps.build import build_map
from pipeline.maps.config import MAP_CONFIGS
from pipeline.maps.store import SemanticMap
from pipeline.paramsfile import parse_params
from pipeline.recon.build import reconstruct
from pipeline.store import artifact_attrs, content_digest
from tests.fixtures.recon_scenes import write_box_room_frames

N_FRAMES, CHUNK = 40, 16  # chunks of 16, 16 and 8 frames


def _params():
    return parse_params({"scenes": {"box": {"source": "simulate"}}, "grid": {"rows": 100, "cols": 160},
                         "maps": {"chunk_frames": CHUNK, "block_frames": 8, "tile_cells": 32},  # 4 x 5 tiles
                         "encoders": {"simulated": "oracle", "oracle": {"out_size": [30, 40]}}})


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("build")
    frames, _ = write_box_room_frames(tmp / "frames.zarr", n_frames=N_FRAMES, width=80, height=60)
    params = _params()
    reconstruct(frames, tmp / "recon.zarr", tmp / "mesh.ply", tmp / "points.ply", params.reconstruct, params.grid)
    return tmp, frames, tmp / "recon.zarr", params


def _build(params, stage, frames, recon, out, **kw):
    return build_map(MAP_CONFIGS[stage].from_params(params, "box"), frames, recon, out,
                     artifact_attrs(stage, 1, stage, "t"), **kw)


def _leftovers(folder):
    return sorted(p.name for p in folder.iterdir())


@pytest.mark.parametrize("stage", ["vlmap", "cfmap"])
def test_the_map_is_folded_by_tile_and_does_not_depend_on_the_run_size(room, stage, tmp_path, monkeypatch):
    _, frames, recon, params = room
    summary = _build(params, stage, frames, recon, tmp_path / "a" / f"{stage}.zarr")
    assert summary["chunks"] == 3 and summary["frames_fused"] == N_FRAMES
    m = SemanticMap(tmp_path / "a" / f"{stage}.zarr")
    assert (np.diff(m.tile_start) > 0).sum() >= 4  # the room spans several tiles
    assert _leftovers(tmp_path / "a") == [f"{stage}.zarr"]  # the scratch folder is gone
    monkeypatch.setattr("pipeline.maps.tilefold.FOLD_ROWS", 1)  # every tile folded on its own
    _build(params, stage, frames, recon, tmp_path / "b" / f"{stage}.zarr")
    assert content_digest(tmp_path / "b" / f"{stage}.zarr") == content_digest(tmp_path / "a" / f"{stage}.zarr")


def test_a_chunk_that_fails_midway_leaves_no_store_no_scratch_and_the_old_fold(room, tmp_path):
    tmp, frames, recon, params = room
    fold = tmp_path / ".vlmap.fold"
    _build(params, "vlmap", frames, recon, tmp_path / "first" / "vlmap.zarr", fold_path=fold)
    kept = {p.name: p.read_bytes() for p in fold.iterdir()}
    assert "meta.json" in kept
    broken = shutil.copytree(frames, tmp_path / "broken.zarr")
    depth = zarr.open_group(str(broken), mode="r")["depth"]
    last = broken / "depth" / "c" / str((N_FRAMES - 1) // depth.chunks[0]) / "0" / "0"
    assert last.is_file()
    last.write_bytes(b"not a compressed chunk")  # the frames of the last chunk cannot be decoded
    out = tmp_path / "second" / "vlmap.zarr"
    with pytest.raises(RuntimeError, match="decompression"):  # zarr's own error (the frame store passes it on)
        _build(params, "vlmap", broken, recon, out, fold_path=fold)
    assert _leftovers(tmp_path / "second") == []  # no store, no scratch
    assert {p.name: p.read_bytes() for p in fold.iterdir()} == kept


def test_a_store_whose_writing_fails_is_removed(room, tmp_path, monkeypatch):
    _, frames, recon, params = room
    from pipeline.maps.writer import LayerWriter

    written = []

    def failing(self, *args):
        if written:
            raise OSError(28, "No space left on device")
        written.append(args)
        return add_cells(self, *args)

    add_cells = LayerWriter.add_cells
    monkeypatch.setattr(LayerWriter, "add_cells", failing)
    with pytest.raises(OSError, match="No space left"):
        _build(params, "cfmap", frames, recon, tmp_path / "out" / "cfmap.zarr")
    assert written and _leftovers(tmp_path / "out") == []


def test_an_existing_store_is_refused_and_kept(room, tmp_path):
    _, frames, recon, params = room
    out = tmp_path / "vlmap.zarr"
    out.mkdir()
    (out / "mine.txt").write_text("not yours")
    with pytest.raises(FileExistsError, match="refusing to overwrite"):
        _build(params, "vlmap", frames, recon, out)
    assert (out / "mine.txt").read_text() == "not yours" and _leftovers(tmp_path) == ["vlmap.zarr"]
