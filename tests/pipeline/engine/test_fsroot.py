"""Object-store data roots (pipeline.engine.fsroot) on a local S3 endpoint (moto's server mode)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import s3fs
import zarr

from zipon.cli import main
from pipeline.paramsfile import load_params
from pipeline.errors import LockedError, StageError
from pipeline.engine.fsroot import MANIFEST_KEY, RemoteRoot, reclaim_guard, remote_stage, version_key
from pipeline.engine.manifest import Manifest
from pipeline.paths import ARTIFACTS, Workspace, cache_dir, is_url
from pipeline.engine.stagegraph import plan
from pipeline.engine.runner import run_many
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


def test_cli_run_status_verify_on_s3_and_a_reader_of_an_unpublished_stage_fails(tmp_path, s3_env, monkeypatch, capsys):
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
    # a reading command: the stage it needs was never published, so it is absent: the usual error, exit 1
    assert main([*base, "query", "tiny", "chair"]) == 1
    err = capsys.readouterr().err
    assert "scene 'tiny' has no vlmap yet (build it: zipon run -s tiny --stage vlmap)" in err
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


@pytest.mark.parametrize("args, why", [
    (["simulate"], "zipon simulate writes its logs into the data root's raw/ folder outside any stage, so they would "
     "not be published; list the scenes in params.yaml with source: simulate and `zipon run` builds and publishes "
     "their logs (stage simulate)"),
    (["ingest", "robot.mcap", "--scene", "lab"], "zipon ingest builds a scene that params.yaml does not list; add it "
     "under scenes: in params.yaml and run `zipon run -s SCENE --stage ingest`, which publishes it"),
    (["dvc"], "zipon dvc writes dvc.yaml for DVC, which tracks outputs in a local data root"),
    (["demo"], "zipon demo builds, draws and evaluates in one local data root; on an object store run `zipon run`, "
     "then `zipon eval` or `zipon render`, which read the published artifacts"),
])
def test_commands_that_would_write_the_data_root_outside_the_stages_refuse_an_object_store(tmp_path, capsys, args, why):
    (tmp_path / "params.yaml").write_text(PARAMS)
    assert main(["-q", "-p", str(tmp_path / "params.yaml"), "--data-dir", "s3://bucket/x", *args]) == 1
    assert f"error: --data-dir s3://bucket/x: {why}" in capsys.readouterr().err.replace("\n", " ")


def test_a_command_not_classified_for_object_stores_is_refused(tmp_path):
    from zipon.cli.common import remote_root_ready
    from pipeline.errors import ConfigError

    (tmp_path / "params.yaml").write_text(PARAMS)
    ws = Workspace.resolve(tmp_path / "params.yaml", data_dir="s3://bucket/x")
    with pytest.raises(ConfigError, match=r"--data-dir s3://bucket/x: zipon newcmd works on a local data "
                       r"root only; on an object store zipon run, stage, .* work. After one of them the local "
                       r"mirror is "):
        remote_root_ready(ws, load_params(ws.params_path), "newcmd")


def test_every_command_says_what_it_does_on_an_object_store():
    """A new command must be classified (works there, or refused saying why) before it can meet an s3 root."""
    import typer

    from zipon.cli import app
    from zipon.cli.common import REMOTE_COMMANDS, REMOTE_REFUSED

    root = typer.main.get_command(app)
    names = {f"{n} {sub}" if sub else n for n, cmd in root.commands.items()
             for sub in (list(getattr(cmd, "commands", {})) or [""])}
    assert names == set(REMOTE_COMMANDS) | set(REMOTE_REFUSED) and not set(REMOTE_COMMANDS) & set(REMOTE_REFUSED)


@pytest.fixture(scope="module")
def tiny_on_s3(built_scene, s3_endpoint):
    """The session's tiny scene, every stage published to a bucket of its own through zipon run's publication code;
    returns the data root URL. Tests only read it (s3_env points botocore at the endpoint again)."""
    from stages import STAGES
    from tests.fixtures.s3 import new_bucket  # here: a module-level import would come before pytest_plugins

    ws, _ = built_scene
    with pytest.MonkeyPatch.context() as mp:
        url = f"s3://{new_bucket(s3_endpoint, mp)}/data"
        for stage in STAGES:
            RemoteRoot(url).publish_stage(ws, "tiny", stage, STAGES[stage].outputs)
    return url


def test_readers_mirror_the_published_scene_from_a_fresh_cache(built_scene, tiny_on_s3, tmp_path, s3_env,
                                                               monkeypatch, capsys):
    """`zipon query`, `zipon goals export`, `zipon render` and zipon.open on the s3 root, from a fresh cache, read
    what the local root reads; a scene never published is absent (the usual error, exit 1)."""
    import numpy as np

    import zipon
    from pipeline.goals.store import Goals

    ws, _ = built_scene
    url = tiny_on_s3
    text = ws.params_path.read_text()
    (tmp_path / "params.yaml").write_text(text.replace("  tiny: {source: simulate}\n",
                                                       "  tiny: {source: simulate}\n  ghost: {source: simulate}\n"))
    assert "ghost" in (tmp_path / "params.yaml").read_text()
    goals = Goals(ws.artifact("goals", "tiny"))
    cls = goals.objects[goals.goals[0].object_keys[0]].cls
    local = ["-q", "-p", str(ws.params_path), "--data-dir", str(ws.data_dir), "--manifests-dir", str(ws.manifests_dir)]
    capsys.readouterr()
    assert main([*local, "query", "tiny", cls, "--json"]) == 0
    want = json.loads(capsys.readouterr().out)
    assert main([*local, "goals", "export", "tiny", "-o", str(tmp_path / "local.yaml")]) == 0
    capsys.readouterr()

    monkeypatch.setenv("ZIPON_CACHE", str(tmp_path / "fresh"))
    base = ["-q", "-p", str(tmp_path / "params.yaml"), "--data-dir", url]
    assert main([*base, "query", "tiny", cls, "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["candidates"] and got["candidates"] == want["candidates"]
    assert got["cells_observed"] == want["cells_observed"]
    mirror = cache_dir(url, tmp_path)
    assert mirror.is_relative_to(tmp_path / "fresh")
    # what the query reads came down, each the published version (digest-checked); nothing else did
    for stage in ("ingest", "reconstruct", "vlmap", "goals"):
        for name, rec in Manifest.read(ws.manifest("tiny", stage)).outputs.items():
            assert content_digest(mirror / ARTIFACTS[name].format(scene="tiny")) == rec.digest
    assert sorted(p.name for p in (mirror / "artifacts/tiny").iterdir() if not p.name.startswith(".")) == [
        "frames.zarr", "goals.zarr", "recon.zarr", "recon_mesh.ply", "recon_points.ply", "vlmap.zarr"]
    assert not (mirror / "raw").exists()
    assert main([*base, "goals", "export", "tiny", "-o", str(tmp_path / "s3.yaml")]) == 0
    assert (tmp_path / "s3.yaml").read_text() == (tmp_path / "local.yaml").read_text()
    assert main([*base, "render", "tiny", "--what", "goals", "-o", str(tmp_path / "goals.png")]) == 0
    assert main([*local, "render", "tiny", "--what", "goals", "-o", str(tmp_path / "local.png")]) == 0
    assert (tmp_path / "goals.png").read_bytes() == (tmp_path / "local.png").read_bytes()
    capsys.readouterr()
    assert main([*base, "query", "ghost", cls]) == 1
    assert "scene 'ghost' has no vlmap yet (build it: zipon run -s ghost --stage vlmap)" in capsys.readouterr().err
    assert not (mirror / "artifacts/ghost").exists()
    assert main([*base, "query", "nope", cls]) == 1
    assert "unknown scene 'nope'" in capsys.readouterr().err

    ds = zipon.open(tmp_path / "params.yaml", data_dir=url)  # the Python API (the mirror is current: no download)
    assert ds.workspace.remote == url and ds.workspace.data_dir == mirror and list(ds) == ["tiny", "ghost"]
    ref = zipon.open(ws.params_path, data_dir=ws.data_dir, manifests_dir=ws.manifests_dir)["tiny"]
    np.testing.assert_array_equal(ds["tiny"].vlmap.query(cls).heatmap, ref.vlmap.query(cls).heatmap)
    np.testing.assert_array_equal(ds["tiny"].frames.poses(), ref.frames.poses())


def test_eval_on_s3_mirrors_every_stage_of_its_scenes(built_scene, tiny_on_s3, tmp_path, s3_env, monkeypatch):
    ws, _ = built_scene
    monkeypatch.setenv("ZIPON_CACHE", str(tmp_path / "fresh"))
    assert main(["-q", "-p", str(ws.params_path), "--data-dir", tiny_on_s3, "eval", "-o", str(tmp_path / "eval"),
                 "-s", "tiny", "-m", "vlmap", "-f", "none", "--seeds", "1"]) == 0
    assert json.loads((tmp_path / "eval" / "results.json").read_text())["overall"]["vlmap"]["none"]["episodes"] > 0
    mirror = cache_dir(tiny_on_s3, ws.root)
    for stage in ("ingest", "reconstruct", "vlmap", "cfmap", "goals", "routes"):
        assert Manifest.read(mirror / "manifests" / "tiny" / f"{stage}.json") == Manifest.read(ws.manifest("tiny", stage))
    assert not (mirror / "raw").exists()


def test_goals_import_on_s3_publishes_its_rebuild(built_scene, tiny_on_s3, tmp_path, s3_env, monkeypatch):
    """`zipon goals import` on an s3 root mirrors the goals, stores the edit beside params.yaml and rebuilds goals and
    routes as stages, which publishes them: another cache exports the edit."""
    import yaml

    ws, _ = built_scene
    fs = s3fs.S3FileSystem()
    src = fs.find(tiny_on_s3.removeprefix("s3://"))
    fs.copy(src, [f"{s3_env}/{k.split('/', 1)[1]}" for k in src])  # a bucket of its own, server-side
    url = f"s3://{s3_env}/data"
    (tmp_path / "params.yaml").write_text(ws.params_path.read_text())  # the edit is recorded in this copy
    monkeypatch.setenv("ZIPON_CACHE", str(tmp_path / "cache"))
    base = ["-q", "-p", str(tmp_path / "params.yaml"), "--data-dir", url]
    assert main([*base, "goals", "export", "tiny", "-o", str(tmp_path / "goals.yaml")]) == 0
    doc = yaml.safe_load((tmp_path / "goals.yaml").read_text())
    key = next(iter(doc["objects"]))
    doc["objects"][key]["identity"] = "Grandma's one"
    (tmp_path / "edited.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    before = {stage: RemoteRoot(url).read_text(f"manifests/tiny/{stage}.json") for stage in ("goals", "routes")}
    assert main([*base, "goals", "import", "tiny", str(tmp_path / "edited.yaml")]) == 0
    rel = yaml.safe_load((tmp_path / "params.yaml").read_text())["goals"]["edits"]["tiny"]
    assert (tmp_path / rel).is_file()
    assert all(RemoteRoot(url).read_text(f"manifests/tiny/{stage}.json") != text for stage, text in before.items())
    monkeypatch.setenv("ZIPON_CACHE", str(tmp_path / "other"))
    assert main([*base, "goals", "export", "tiny", "-o", str(tmp_path / "again.yaml")]) == 0
    assert yaml.safe_load((tmp_path / "again.yaml").read_text())["objects"][key]["identity"] == "Grandma's one"


# ----------------------------------------------------------------------------- locks of dead runs

REPO = Path(__file__).resolve().parents[3]
LOCK_REL = "artifacts/tiny/.simulate.lock"


def _record_of_exited_process() -> str:
    """The owner record of a process of this host that has exited (its pid is dead)."""
    return subprocess.run([sys.executable, "-c", "from pipeline.engine.locks import holder_record; "
                           "print(holder_record(), end='')"], cwd=REPO, capture_output=True, text=True,
                          check=True).stdout


def test_a_dead_runs_lock_of_this_host_is_reclaimed_another_hosts_never(tmp_path, s3_env, monkeypatch, capsys):
    (tmp_path / "params.yaml").write_text("scenes:\n  tiny: {source: simulate}\n"
                                          "simulate: {frames: 6, width: 80, height: 60, rooms_min: 2, rooms_max: 2}\n")
    url = f"s3://{s3_env}/data"
    monkeypatch.setenv("ZIPON_CACHE", str(tmp_path / "cache"))
    base = ["-q", "-p", str(tmp_path / "params.yaml"), "--data-dir", url]
    remote = RemoteRoot(url)
    dead = _record_of_exited_process() + "nonce\n"
    assert len(dead.splitlines()) == 4 and dead.splitlines()[2].isdigit()  # pid, host, start token, nonce
    remote.write_text(LOCK_REL, dead)
    assert main([*base, "run", "--stage", "simulate"]) == 0
    assert remote.read_text(LOCK_REL) is None and remote.read_text("manifests/tiny/simulate.json")
    other = "4242\nnode-17.cluster\n12345\nnonce\n"
    remote.write_text(LOCK_REL, other)
    capsys.readouterr()
    assert main([*base, "run", "--stage", "simulate", "--force"]) == 1
    err = capsys.readouterr().err
    assert (f"scene tiny stage simulate is being built by another zipon run: pid 4242 on host node-17.cluster holds "
            f"{url}/{LOCK_REL}. Wait for that run to finish; if it is gone, delete {url}/{LOCK_REL} and run "
            "again") in err
    assert remote.read_text(LOCK_REL) == other


def test_a_reused_pid_is_not_taken_for_the_holder(tmp_path, s3_env):
    from pipeline.engine.locks import parse_holder

    remote = RemoteRoot(f"s3://{s3_env}/data")
    live = subprocess.Popen([sys.executable, "-c", "import time; from pipeline.engine.locks import holder_record; "
                             "import os; print(holder_record(), end='', flush=True); os.close(1); time.sleep(60)"],
                            cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        record = live.stdout.read()
        pid, host, token = parse_holder(record)
        assert pid == live.pid and token is not None
        remote.write_text(LOCK_REL, f"{pid}\n{host}\n{token + 1}\nnonce\n")  # that pid, another process's start
        with remote.lock(LOCK_REL, "x"):
            assert parse_holder(remote.read_text(LOCK_REL))[0] == os.getpid()
        remote.write_text(LOCK_REL, record + "nonce\n")  # the live process itself: respected
        with pytest.raises(LockedError, match=f"x is being built by another zipon run: pid {pid} on host "):
            with remote.lock(LOCK_REL, "x"):
                pass
        assert remote.read_text(LOCK_REL) == record + "nonce\n"
    finally:
        live.kill()
        live.wait()


RACER = """
import sys, time
from pathlib import Path
from pipeline.errors import LockedError
from pipeline.engine.fsroot import RemoteRoot
url, rel, folder, me = sys.argv[1:]
remote = RemoteRoot(url)
Path(folder, "ready-" + me).touch()
while not Path(folder, "go").exists():
    time.sleep(0.01)
try:
    with remote.lock(rel, "x"):
        print("won", flush=True)
        deadline = time.time() + 60
        while not Path(folder, "release").exists() and time.time() < deadline:
            time.sleep(0.05)
except LockedError as err:
    print("lost:", err, flush=True)
"""


def test_processes_reclaiming_one_dead_lock_take_turns_and_exactly_one_wins(tmp_path, s3_env):
    """Three processes of this host find the same dead lock at once. While the host-local guard of that lock is held
    (here by the test) none of them may touch it; once it is free, one takes the lock over and two fail fast naming
    it."""
    from filelock import FileLock

    url, n = f"s3://{s3_env}/data", 3
    dead = _record_of_exited_process() + "nonce\n"
    RemoteRoot(url).write_text(LOCK_REL, dead)
    guard = FileLock(str(reclaim_guard(f"{url}/{LOCK_REL}")))
    guard.acquire()
    racers = [subprocess.Popen([sys.executable, "-c", RACER, url, LOCK_REL, str(tmp_path), str(i)], cwd=REPO,
                               stdout=subprocess.PIPE, text=True) for i in range(n)]
    try:
        deadline = time.time() + 60
        while not all((tmp_path / f"ready-{i}").exists() for i in range(n)) and time.time() < deadline:
            assert all(r.poll() is None for r in racers), "a racer died before the start"
            time.sleep(0.02)
        (tmp_path / "go").touch()
        time.sleep(1.0)  # each racer finds the dead record, then waits for the guard
        assert all(r.poll() is None for r in racers) and RemoteRoot(url).read_text(LOCK_REL) == dead
        guard.release()
        deadline = time.time() + 20  # the losers fail fast while the winner holds the lock
        while sum(r.poll() is not None for r in racers) < n - 1 and time.time() < deadline:
            time.sleep(0.02)
        running = [r for r in racers if r.poll() is None]
        assert len(running) == 1, f"{len(running)} racers hold the lock"
        winner = running[0]
        for loser in (r for r in racers if r is not winner):
            assert loser.stdout.read().startswith(f"lost: x is being built by another zipon run: pid {winner.pid} on "
                                                  "host")
        (tmp_path / "release").touch()
        assert winner.wait(60) == 0 and winner.stdout.read() == "won\n"
    finally:
        guard.release()
        for r in racers:
            r.kill()
            r.wait()
    assert RemoteRoot(url).read_text(LOCK_REL) is None


# ----------------------------------------------------------------------------- reaching the store, once, at start

@pytest.mark.parametrize("url", ["s3://", "s3:///prefix", "gs://"])
def test_an_object_store_url_without_a_bucket_is_refused(tmp_path, url):
    from pipeline.errors import ConfigError
    from pipeline.paths import Workspace

    with pytest.raises(ConfigError, match=rf"--data-dir {url}: no bucket named \(expected \w+://BUCKET"):
        Workspace.resolve(tmp_path / "params.yaml", url)
    assert not any(tmp_path.iterdir())


def test_missing_credentials_are_named_once_with_the_url(tmp_path, monkeypatch):
    import s3fs

    from pipeline.engine.fsroot import RemoteRoot
    from pipeline.errors import ConfigError

    for key in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_SESSION_TOKEN", "AWS_PROFILE"):
        monkeypatch.delenv(key, raising=False)
    monkeypatch.setenv("AWS_SHARED_CREDENTIALS_FILE", str(tmp_path / "none"))
    monkeypatch.setenv("AWS_CONFIG_FILE", str(tmp_path / "none"))
    monkeypatch.setenv("AWS_EC2_METADATA_DISABLED", "true")
    s3fs.S3FileSystem.clear_instance_cache()
    with pytest.raises(ConfigError, match=r"--data-dir s3://bucket/prefix: cannot reach the object store "
                                          r"\(NoCredentialsError.*set AWS_ACCESS_KEY_ID"):
        RemoteRoot("s3://bucket/prefix").check()


def test_an_endpoint_that_never_answers_times_out_naming_the_url(tmp_path, monkeypatch):
    import socket
    import time

    import s3fs

    import pipeline.engine.fsroot as fsroot
    from pipeline.errors import ConfigError

    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(8)  # accepts connections (the kernel's backlog) and never answers
    endpoint = f"http://127.0.0.1:{silent.getsockname()[1]}"
    for key, value in {"AWS_ENDPOINT_URL_S3": endpoint, "AWS_ENDPOINT_URL": endpoint, "AWS_ACCESS_KEY_ID": "k",
                       "AWS_SECRET_ACCESS_KEY": "s", "AWS_DEFAULT_REGION": "us-east-1"}.items():
        monkeypatch.setenv(key, value)
    monkeypatch.setattr(fsroot, "READ_TIMEOUT_S", 1.0)
    monkeypatch.setattr(fsroot, "MAX_ATTEMPTS", 1)
    s3fs.S3FileSystem.clear_instance_cache()
    t0 = time.monotonic()
    try:
        with pytest.raises(ConfigError, match=r"--data-dir s3://bucket/p: cannot reach the object store \(.*Timeout"):
            fsroot.RemoteRoot("s3://bucket/p").check()
    finally:
        silent.close()
    assert time.monotonic() - t0 < 20


def test_a_bucket_that_does_not_exist(s3_env):
    from pipeline.engine.fsroot import RemoteRoot
    from pipeline.errors import ConfigError

    RemoteRoot(f"s3://{s3_env}/data").check()  # the fresh bucket exists
    with pytest.raises(ConfigError, match=r"bucket 'zipon-nowhere-0' does not exist"):
        RemoteRoot("s3://zipon-nowhere-0/data").check()
