"""Object-store data roots (pipeline.fsroot) on a local S3 endpoint (moto's server mode)."""

from __future__ import annotations

import json

import pytest
import s3fs
import zarr

from pipeline.cli import main
from pipeline.config import load_params
from pipeline.errors import LockedError, StageError
from pipeline.fsroot import MANIFEST_KEY, RemoteRoot, remote_stage, version_key
from pipeline.manifest import Manifest
from pipeline.paths import Workspace, cache_dir, is_url
from pipeline.runner import plan, run_many
from pipeline.store import content_digest
from tests.fixtures.toy_stages import TOY_STAGES

pytest_plugins = ["tests.fixtures.s3"]  # s3_endpoint, s3_env

PARAMS = "scenes:\n  s0: {source: simulate}\n"


def remote_ws(tmp_path, url, cache="cache"):
    """The workspace of ``url`` on a machine whose cache is ``tmp_path / cache``."""
    (tmp_path / "params.yaml").write_text(PARAMS)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("ZIPON_CACHE", str(tmp_path / cache))
        return Workspace.resolve(tmp_path / "params.yaml", data_dir=url)


def run_toy(ws, overrides=("simulate.frames=8",), **kw):
    params = load_params(ws.params_path, list(overrides))
    return run_many(ws, params, TOY_STAGES, plan(TOY_STAGES, params, ["s0"]), show_progress=False, **kw)


def keys(bucket):
    fs = s3fs.S3FileSystem()
    fs.invalidate_cache()
    return sorted(k.split("/", 1)[1] for k in fs.find(bucket))


def test_urls_and_local_paths_resolve_as_before(tmp_path):
    (tmp_path / "params.yaml").write_text(PARAMS)
    local = Workspace.resolve(tmp_path / "params.yaml", data_dir=tmp_path / "d")
    assert (local.data_dir, local.manifests_dir, local.remote) == (tmp_path / "d", tmp_path / "manifests", None)
    assert is_url("s3://b/p") and is_url("memory://x") and not is_url("/tmp/x") and not is_url("data")
    remote = Workspace.resolve(tmp_path / "params.yaml", data_dir="s3://bucket/prefix/")
    assert remote.remote == "s3://bucket/prefix"
    assert remote.data_dir == cache_dir("s3://bucket/prefix", tmp_path) and remote.data_dir.parent.name == ".zipon-cache"
    assert remote.manifests_dir == remote.data_dir / "manifests"
    assert cache_dir("s3://bucket/a", tmp_path) != cache_dir("s3://bucket/a_", tmp_path)


def test_run_publishes_versions_then_the_manifest_and_a_fresh_cache_reads_them_back(tmp_path, s3_env):
    url = f"s3://{s3_env}/root"
    ws = remote_ws(tmp_path, url)
    assert [(o.stage, o.status) for o in run_toy(ws)] == [("simulate", "ran"), ("ingest", "ran")]
    man = Manifest.read(ws.manifest("s0", "ingest"))
    digest = man.outputs["frames"].digest
    stored = keys(s3_env)
    frames_key = f"root/{version_key('artifacts/s0/frames.zarr', digest)}"
    assert f"root/{MANIFEST_KEY.format(scene='s0', stage='ingest')}" in stored
    assert f"{frames_key}/zarr.json" in stored
    assert not [k for k in stored if k.endswith(".lock")]  # released
    # the manifest object is byte-identical to the local one, and the store reads in place through zarr's FsspecStore
    assert RemoteRoot(url).read_text("manifests/s0/ingest.json") == ws.manifest("s0", "ingest").read_text()
    group = zarr.open_group(zarr.storage.FsspecStore.from_url(f"s3://{s3_env}/{frames_key}", read_only=True),
                            mode="r")
    assert group["values"].shape == (8, 16) and group.attrs["artifact"] == "frames"
    # re-hashed in place (zarr over fsspec for the store, bytes for the log): the manifests' digests
    assert RemoteRoot(url).digest("artifacts/s0/frames.zarr", digest) == digest
    log = Manifest.read(ws.manifest("s0", "simulate")).outputs["raw_log"].digest
    assert RemoteRoot(url).digest("raw/s0.mcap", log) == log
    # another machine (a fresh cache) pulls, checks digests, and finds everything up to date
    other = remote_ws(tmp_path, url, cache="cache2")
    assert other.data_dir != ws.data_dir
    assert {o.status for o in run_toy(other)} == {"skipped"}
    assert content_digest(other.artifact("frames", "s0")) == digest
    # a new version replaces the old one: the manifest names it, the old objects are pruned
    assert {o.status for o in run_toy(other, ("simulate.frames=9",))} == {"ran"}
    new = Manifest.read(other.manifest("s0", "ingest")).outputs["frames"].digest
    stored = keys(s3_env)
    assert any(k.startswith(f"root/{version_key('artifacts/s0/frames.zarr', new)}/") for k in stored)
    assert not any(k.startswith(f"{frames_key}/") for k in stored)
    # and the first cache, now behind, pulls the new version before deciding
    assert {o.status for o in run_toy(ws, ("simulate.frames=9",))} == {"skipped"}
    assert content_digest(ws.artifact("frames", "s0")) == new


def test_a_held_lock_fails_fast_naming_the_holder_and_the_object(tmp_path, s3_env):
    url = f"s3://{s3_env}/root"
    ws = remote_ws(tmp_path, url)
    with RemoteRoot(url).lock("artifacts/s0/.ingest.lock", "scene s0 stage ingest"):
        with pytest.raises(LockedError, match=rf"scene s0 stage ingest is being built by another zipon run: pid \d+ "
                           rf"on host .* holds {url}/artifacts/s0/.ingest.lock"):
            with remote_stage(ws, "s0", "ingest", {"ingest": ("frames",), "simulate": ("raw_log",)}, ["simulate"]):
                pass
        outcomes = run_toy(ws)
        assert [o.status for o in outcomes] == ["ran", "failed"] and "being built by another" in outcomes[1].error
    assert "root/artifacts/s0/.ingest.lock" not in keys(s3_env)


def test_an_input_republished_meanwhile_is_not_published_over(tmp_path, s3_env):
    url = f"s3://{s3_env}/root"
    ws = remote_ws(tmp_path, url)
    run_toy(ws)
    before = RemoteRoot(url).read_text("manifests/s0/ingest.json")
    outputs = {"ingest": ("frames",), "simulate": ("raw_log",)}
    with pytest.raises(StageError, match="input stage simulate was republished"):
        with remote_stage(ws, "s0", "ingest", outputs, ["simulate"]) as publish_now:
            other = remote_ws(tmp_path, url, cache="cache2")
            params = load_params(other.params_path, ["simulate.frames=9"])
            run_many(other, params, TOY_STAGES, [("s0", "simulate")], show_progress=False)
            publish_now()
    assert RemoteRoot(url).read_text("manifests/s0/ingest.json") == before


def test_a_damaged_version_is_refused_on_pull(tmp_path, s3_env):
    url = f"s3://{s3_env}/root"
    run_toy(remote_ws(tmp_path, url))
    man = json.loads(RemoteRoot(url).read_text("manifests/s0/simulate.json"))
    key = f"{s3_env}/root/{version_key('raw/s0.mcap', man['outputs']['raw_log']['digest'])}"
    s3fs.S3FileSystem().pipe_file(key, b"not the log")
    outcomes = run_toy(remote_ws(tmp_path, url, cache="cache2"))
    assert outcomes[0].status == "failed" and "content digest" in outcomes[0].error


def test_cli_run_status_verify_on_s3_and_other_commands_refuse(tmp_path, s3_env, monkeypatch, capsys):
    """``zipon run`` of a real tiny scene (simulate + ingest) to s3://, then status and verify from a fresh cache."""
    (tmp_path / "params.yaml").write_text(
        "scenes:\n  tiny: {source: simulate}\nsimulate: {frames: 12, width: 80, height: 60, rooms_min: 2, rooms_max: 2}\n")
    url = f"s3://{s3_env}/data"
    monkeypatch.setenv("ZIPON_CACHE", str(tmp_path / "cache"))
    base = ["-q", "-p", str(tmp_path / "params.yaml"), "--data-dir", url]
    assert main([*base, "run", "--stage", "simulate", "--stage", "ingest"]) == 0
    monkeypatch.setenv("ZIPON_CACHE", str(tmp_path / "cache2"))
    capsys.readouterr()
    assert main([*base, "verify"]) == 0
    assert "2 artifact(s) match their manifests" in capsys.readouterr().out
    assert main([*base, "status"]) == 0
    table = capsys.readouterr().out
    assert table.count("up to date") == 2 and "never run" in table  # simulate, ingest; the rest never ran
    code = main([*base, "query", "tiny", "chair"])
    err = capsys.readouterr().err
    assert code == 1 and f"--data-dir {url}: zipon query reads artifacts from a local data root" in err
    # verify re-hashes the published versions in place: a damaged chunk on the store is found, named, exit 1
    fs = s3fs.S3FileSystem()
    chunk = next(k for k in fs.find(f"{s3_env}/data/artifacts/tiny") if "/frames.zarr@" in k and "/c/" in k)
    fs.pipe_file(chunk, b"garbage")
    assert main([*base, "verify"]) == 1
    err = capsys.readouterr().err
    assert "1 published artifact(s)" in err and "frames.zarr@" in err and "unreadable" in err


def test_a_data_root_url_fsspec_cannot_open_is_a_clear_error(tmp_path, capsys):
    (tmp_path / "params.yaml").write_text(PARAMS)
    code = main(["-q", "-p", str(tmp_path / "params.yaml"), "--data-dir", "nosuchfs://bucket/x", "status"])
    err = capsys.readouterr().err
    assert code == 1 and "data root nosuchfs://bucket/x: cannot open it with fsspec" in err


def test_uploading_a_version_again_after_a_cut_short_upload_overwrites_it_in_place(tmp_path):
    """Any fsspec filesystem works as the root (memory:// here): a second push of one version lands on the same
    keys (a cut-short first upload is completed, not nested), and a pull checks the digest."""
    store = tmp_path / "a.zarr"
    group = zarr.open_group(zarr.storage.LocalStore(str(store)), mode="w-", zarr_format=3)
    group.create_array("x", shape=(6,), chunks=(2,), dtype="int32")[:] = range(6)
    digest = content_digest(store)
    remote = RemoteRoot(f"memory://zipon-{tmp_path.name}/root")
    remote.push(store, "artifacts/s0/a.zarr", digest)
    keys_once = sorted(remote.fs.find(remote.key("artifacts")))
    remote.fs.rm_file(keys_once[-1])  # as if the first upload had been cut short
    remote.push(store, "artifacts/s0/a.zarr", digest)
    assert sorted(remote.fs.find(remote.key("artifacts"))) == keys_once
    remote.pull("artifacts/s0/a.zarr", digest, tmp_path / "mirror" / "a.zarr")
    assert content_digest(tmp_path / "mirror" / "a.zarr") == digest
    assert remote.digest("artifacts/s0/a.zarr", digest) == digest


def test_the_python_api_refuses_an_object_store_root_naming_its_mirror(tmp_path):
    import zipon
    from pipeline.errors import ConfigError

    (tmp_path / "params.yaml").write_text(PARAMS)
    with pytest.raises(ConfigError, match=r"data_dir s3://bucket/x: zipon.open reads artifacts from a local data root;"
                       r".* its local mirror is .*\.zipon-cache"):
        zipon.open(tmp_path / "params.yaml", data_dir="s3://bucket/x")
