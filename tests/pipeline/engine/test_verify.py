import shutil

import pytest

from pipeline.paramsfile import load_params
from pipeline.engine.stagegraph import plan
from pipeline.engine.runner import run_many
from pipeline.engine.verify import content_staleness, locate_corruption, scenes_on_disk, verify_all
from tests.fixtures.toy_stages import TOY_STAGES


@pytest.fixture
def built(workspace):
    """Scenes s0 and s1 through the toy simulate -> ingest stages (real zarr stores and manifests)."""
    params = load_params(workspace.params_path, ["simulate.frames=8"])
    outcomes = run_many(workspace, params, TOY_STAGES, plan(TOY_STAGES, params, list(params.scenes)),
                        show_progress=False, scheduler="sync")
    assert {o.status for o in outcomes} == {"ran"}
    return workspace, params


def rows_by_key(ws, params):
    return {(r.scene, r.stage, r.artifact): r for r in verify_all(ws, params, TOY_STAGES)}


def first_chunk(store):
    return next(p for p in sorted((store / "values" / "c").rglob("*")) if p.is_file())


def test_every_artifact_gets_a_row_whatever_its_state(built):
    ws, params = built
    assert all(r.ok for r in rows_by_key(ws, params).values())
    chunk = first_chunk(ws.artifact("frames", "s0"))
    chunk.write_bytes(b"\x00" * 7)  # not a blosc frame
    ws.artifact("raw_log", "s1").unlink()
    ws.manifest("s1", "ingest").unlink()
    rows = rows_by_key(ws, params)
    assert set(rows) == {("s0", "simulate", "raw_log"), ("s0", "ingest", "frames"),
                         ("s1", "simulate", "raw_log"), ("s1", "ingest", "frames")}
    assert rows[("s0", "simulate", "raw_log")].ok
    bad = rows[("s0", "ingest", "frames")]
    assert not bad.ok and bad.problem.startswith("unreadable: chunk ") and str(chunk) in bad.problem
    assert rows[("s1", "simulate", "raw_log")].problem == f"missing: {ws.artifact('raw_log', 's1')}"
    orphan = rows[("s1", "ingest", "frames")]
    assert not orphan.ok and orphan.problem.startswith("no manifest") and str(ws.artifact("frames", "s1")) in orphan.problem


def test_a_corrupt_manifest_is_a_row_not_an_exception(built):
    ws, params = built
    ws.manifest("s0", "ingest").write_text("{truncated")
    rows = rows_by_key(ws, params)
    assert rows[("s0", "ingest", "frames")].problem.startswith("manifest unreadable:")
    assert str(ws.manifest("s0", "ingest")) in rows[("s0", "ingest", "frames")].problem
    assert rows[("s1", "ingest", "frames")].ok  # the others are still checked


def test_scenes_on_disk_but_not_in_params_are_verified(built):
    ws, params = built
    for stage, name in (("simulate", "raw_log"), ("ingest", "frames")):
        src, dst = ws.artifact(name, "s1"), ws.artifact(name, "ghost")
        dst.parent.mkdir(parents=True, exist_ok=True)
        (shutil.copytree if src.is_dir() else shutil.copy)(src, dst)
        ws.manifest("ghost", stage).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ws.manifest("s1", stage), ws.manifest("ghost", stage))
    shutil.copytree(ws.artifact("frames", "s0"), ws.artifact("frames", "orphan"))
    assert scenes_on_disk(ws) == ["ghost", "orphan", "s0", "s1"]
    rows = rows_by_key(ws, params)
    ghost = rows[("ghost", "ingest", "frames")]
    assert ghost.ok and ghost.note == "scene not in params.yaml"  # its content matches its (copied) manifest
    orphan = rows[("orphan", "ingest", "frames")]
    assert not orphan.ok and orphan.problem.startswith("no manifest") and orphan.note == "scene not in params.yaml"
    assert ("orphan", "simulate", "raw_log") not in rows  # nothing there, nothing reported
    shutil.copy(ws.artifact("raw_log", "s0"), ws.artifact("raw_log", "recorded"))  # as `zipon simulate` writes
    assert "recorded" in scenes_on_disk(ws)
    assert not any(r.scene == "recorded" for r in verify_all(ws, params, TOY_STAGES))  # an input, not an artifact


def test_locate_corruption_names_the_file(built):
    ws, _ = built
    store = ws.artifact("frames", "s0")
    assert locate_corruption(store) is None
    assert locate_corruption(ws.artifact("raw_log", "s0")) is None  # not a zarr store
    meta = store / "values" / "zarr.json"
    meta.write_text(meta.read_text()[:-20])
    assert locate_corruption(store).startswith(f"{meta} is not valid JSON")


def test_content_staleness_rehashes(built):
    import zarr

    ws, _ = built
    spec = TOY_STAGES["ingest"]
    assert content_staleness(ws, spec, "s0") == ""
    arr = zarr.open_array(str(ws.artifact("frames", "s0") / "values"), mode="r+")
    arr[0, 0] = (int(arr[0, 0]) + 1) % 256
    why = content_staleness(ws, spec, "s0")
    assert why.startswith("frames digest blake3:") and "!= manifest" in why and "older zipon" not in why
    assert content_staleness(ws, spec, "s1") == ""


def test_a_store_digest_recorded_the_older_way_says_so(built):
    from pipeline.engine.manifest import Manifest

    ws, params = built
    path = ws.manifest("s0", "ingest")
    man = Manifest.read(path)
    rec = man.outputs["frames"]
    old = man.model_copy(update={"outputs": {"frames": rec.model_copy(update={"digest": "blake2b:" + "0" * 32})}})
    old.write(path)
    row = rows_by_key(ws, params)[("s0", "ingest", "frames")]
    assert not row.ok
    assert "recorded by an older zipon, as 'blake2b'" in row.problem
    assert "zipon run -s s0 --stage ingest --force" in row.problem and "'blake3'" in row.problem
