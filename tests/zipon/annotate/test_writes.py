"""The workbench writes objects files only where it owns: its objects folder and the files the params name; never
the params file, DVC's files, the data root, the manifests or the stored edits (each refused with 403, the path and
the rule named, nothing on disk changed)."""

from __future__ import annotations

import pytest
import yaml

from tests.zipon.annotate.conftest import ORIGIN, SCENE, make_client, tree_state

W = {"headers": {"Origin": ORIGIN}}


def put_objects(client, path: str):
    body = client.get(f"/api/scenes/{SCENE}/objects").json()
    return client.put(f"/api/scenes/{SCENE}/objects", json={**body, "path": path}, **W)


@pytest.fixture(scope="module")
def client(shared_root):
    return make_client(shared_root)


@pytest.mark.parametrize("path, words", [
    ("params.yaml", "it is the params file"),
    ("dvc.lock.yaml", "neither in the objects folder nor an objects file the params name"),
    ("manifests/tiny/goals.json", "inside the manifests folder"),
    (f"data/artifacts/{SCENE}/goals.zarr/zarr.json", "inside the data root"),
    ("data/eval/human/tiny.json", "inside the data root"),
    ("goals_edits/tiny-0000.yaml", "inside the stored goal edits"),
    (".dvc/config.yaml", "inside a version-control folder"),
    ("notes.yaml", "neither in the objects folder"),
    ("objects/../params.yaml", "it is the params file"),
])
def test_writes_outside_what_the_workbench_owns_are_refused(client, shared_root, path, words):
    before = tree_state(shared_root)
    r = put_objects(client, path)
    assert r.status_code == 403, r.text
    body = r.json()
    assert words in body["error"] and repr(path) in body["error"] and body["field"] == "path", body
    assert body["allowed"] == "objects/"
    assert tree_state(shared_root) == before


def test_a_link_in_the_objects_folder_to_the_params_file_is_refused(own_root):
    (own_root / "objects").mkdir()
    (own_root / "objects" / "link.yaml").symlink_to(own_root / "params.yaml")
    before = (own_root / "params.yaml").read_bytes()
    r = put_objects(make_client(own_root), "objects/link.yaml")
    assert r.status_code == 403 and "it is the params file" in r.json()["error"], r.text
    assert (own_root / "params.yaml").read_bytes() == before


def test_the_objects_folder_and_files_the_params_name_are_written(own_root):
    client = make_client(own_root)
    assert client.get(f"/api/scenes/{SCENE}/objects").json()["objects_dir"] == "objects/"
    assert put_objects(client, "objects/sub/mine.json").status_code == 200
    assert (own_root / "objects" / "sub" / "mine.json").is_file()
    params = yaml.safe_load((own_root / "params.yaml").read_text())
    params.setdefault("goals", {})["objects_files"] = {SCENE: "annotations/tiny_objects.yaml"}
    (own_root / "params.yaml").write_text(yaml.safe_dump(params))
    named = put_objects(make_client(own_root), "annotations/tiny_objects.yaml")
    assert named.status_code == 200, named.text
    assert (own_root / "annotations" / "tiny_objects.yaml").is_file()
    other = put_objects(make_client(own_root), "annotations/other.yaml")
    assert other.status_code == 403 and "neither in the objects folder" in other.json()["error"]
