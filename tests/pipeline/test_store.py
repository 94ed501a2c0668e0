import os
import socket
import subprocess
import sys

import numpy as np
import pytest

from pipeline.errors import ArtifactError, MissingInputError
from pipeline.store import (ArrayDigests, artifact_attrs, compressor, content_digest, new_group, new_tmp_dir,
                            open_group, publish, sweep_tmp, tmp_owner)


def _store(path, values, level=3):
    g = new_group(path, artifact_attrs("frames", 1, "ingest", "p"))
    a = g.create_array("v", shape=values.shape, chunks=(2,) + values.shape[1:], dtype=values.dtype,
                       compressors=compressor(level))
    a[:] = values
    return g


def test_digest_is_content_not_bytes(tmp_path):
    values = np.arange(60, dtype=np.uint16).reshape(6, 10)
    _store(tmp_path / "a.zarr", values, level=1)
    _store(tmp_path / "b.zarr", values, level=9)  # different compressed bytes, same content
    assert content_digest(tmp_path / "a.zarr") == content_digest(tmp_path / "b.zarr")
    values[3, 3] += 1
    _store(tmp_path / "c.zarr", values)
    assert content_digest(tmp_path / "c.zarr") != content_digest(tmp_path / "a.zarr")


def test_digests_kept_while_writing_equal_the_store_read_back(tmp_path):
    rng = np.random.default_rng(0)
    values, stamps = rng.integers(0, 9000, (7, 5, 4), dtype=np.uint16), np.arange(7, dtype=np.int64) * 10
    g = new_group(tmp_path / "a.zarr", artifact_attrs("frames", 1, "ingest", "p"))
    arrays = {"v": g.create_array("v", shape=(0, 5, 4), chunks=(2, 5, 4), dtype="uint16", compressors=compressor(1)),
              "t": g.create_array("t", shape=(0,), chunks=(1024,), dtype="int64", compressors=compressor(1))}
    kept = ArrayDigests()
    for start, stop in ((0, 3), (3, 4), (4, 7)):  # blocks that do not follow the chunks
        for name, rows in (("v", values[start:stop]), ("t", stamps[start:stop])):
            arrays[name].resize((stop,) + arrays[name].shape[1:])
            arrays[name][start:stop] = rows
            kept.update(name, rows)
    g.attrs["n_frames"] = 7  # attrs written after the arrays are read from the store, not kept
    digest = content_digest(tmp_path / "a.zarr")
    assert digest.startswith("blake3:")
    assert content_digest(tmp_path / "a.zarr", kept.known()) == digest
    assert kept.known()["v"][0] == (7, 5, 4)
    arrays["t"].resize((8,))  # grown after the writer: the kept digest no longer applies and is not used
    assert content_digest(tmp_path / "a.zarr", kept.known()) == content_digest(tmp_path / "a.zarr") != digest


def test_open_group_checks_identity(tmp_path):
    _store(tmp_path / "a.zarr", np.zeros((2, 2), np.uint8))
    assert open_group(tmp_path / "a.zarr", artifact="frames", format_version=1).attrs["stage"] == "ingest"
    with pytest.raises(ArtifactError, match="attrs.artifact is 'frames', expected 'recon'"):
        open_group(tmp_path / "a.zarr", artifact="recon")
    with pytest.raises(ArtifactError, match="format_version 1, this zipon reads 2"):
        open_group(tmp_path / "a.zarr", artifact="frames", format_version=2)
    with pytest.raises(MissingInputError, match="not found"):
        open_group(tmp_path / "nope.zarr", artifact="frames")


def test_publish_replaces_atomically(tmp_path):
    _store(tmp_path / "new.zarr", np.ones((2, 2), np.uint8))
    _store(tmp_path / "final.zarr", np.zeros((2, 2), np.uint8))
    want = content_digest(tmp_path / "new.zarr")
    publish(tmp_path / "new.zarr", tmp_path / "final.zarr")
    assert content_digest(tmp_path / "final.zarr") == want
    assert sorted(p.name for p in tmp_path.iterdir()) == ["final.zarr"]


def test_tmp_dirs_record_their_owner(tmp_path):
    path = new_tmp_dir(tmp_path, "ingest")
    assert tmp_owner(path) == ("ingest", socket.gethostname(), os.getpid())
    assert tmp_owner(tmp_path / "notes") is None and tmp_owner(tmp_path / "a-12-ff") is None


def test_sweep_removes_only_dead_local_owners(tmp_path):
    host = socket.gethostname()
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(dead.stdout)  # a process of this host that has exited
    mine = new_tmp_dir(tmp_path, "ingest")
    gone = tmp_path / f"ingest@{host}-{dead_pid}-0badf00d"
    gone_other_label = tmp_path / f"vlmap@{host}-{dead_pid}-0badf00d"
    remote = tmp_path / f"ingest@node-17.cluster-{dead_pid}-0badf00d"  # another host: its pids mean nothing here
    foreign = tmp_path / "user-notes"
    for p in (gone, gone_other_label, remote, foreign):
        p.mkdir()
        (p / "x").write_text("x")
    assert sweep_tmp(tmp_path, label="ingest") == [gone]
    assert sweep_tmp(tmp_path) == [gone_other_label]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([mine.name, remote.name, foreign.name])
    assert (remote / "x").read_text() == "x"


READ_EVERY_ARTIFACT = """
import json, sys
import numpy as np
from pipeline.paramsfile import load_params
from pipeline.frames import FrameStore
from pipeline.goals.store import Goals
from pipeline.maps.query import open_query
from pipeline.maps.store import SemanticMap
from pipeline.recon import Recon
from pipeline.routes.store import Routes

params_path, art = sys.argv[1], sys.argv[2]
fs = FrameStore(f"{art}/frames.zarr")
block = next(fs.iter_blocks())
assert fs.ground_truth is not None and len(block) and fs.meta.n_frames == fs.n_frames
recon = Recon(f"{art}/recon.zarr")
assert recon.navigable.any() and recon.occupancy.shape == recon.color.shape[:2] and len(recon.poses) == fs.n_frames
for name in ("vlmap", "cfmap"):
    m = SemanticMap(f"{art}/{name}.zarr")
    assert m.dot(m.features()[:2]).shape == (m.n_cells, 2)
assert len(SemanticMap(f"{art}/cfmap.zarr").voxels()) > 0
goals = Goals(f"{art}/goals.zarr")
assert goals.goals and goals.object_index().any()
routes = Routes(f"{art}/routes.zarr")
assert routes.episodes and routes.step_m > 0
params = load_params(params_path)
for name in ("vlmap", "cfmap"):  # a query on an oracle map: numpy scoring, the oracle's numpy text side
    result = open_query(f"{art}/{name}.zarr", params, recon_path=f"{art}/recon.zarr",
                        frames_path=f"{art}/frames.zarr").query(goals.objects[goals.object_keys[0]].cls)
    assert result.candidates
print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in ("torch", "open3d", "open_clip", "dask"))))
"""


def test_reading_every_artifact_imports_no_torch_or_open3d(built_scene):
    """Readers of frames, recon (grids), maps, goals and routes, and a query on an oracle map, run without torch,
    open3d or dask: a fresh interpreter reads every artifact of the tiny scene and lists what it imported."""
    import json

    ws, _ = built_scene
    out = subprocess.run([sys.executable, "-c", READ_EVERY_ARTIFACT, str(ws.params_path),
                          str(ws.data_dir / "artifacts" / "tiny")], capture_output=True, text=True,
                         env={**os.environ, "HF_HUB_OFFLINE": "1"}, timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    assert json.loads(out.stdout.splitlines()[-1]) == []
