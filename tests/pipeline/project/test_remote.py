"""The version cycle of a dataset project with real git and real DVC: two versions built (the session's
``dataset_versions``), pushed to a local-folder remote and to an S3 remote (moto's server), restored in turn in fresh
clones, each verified; a version the remote lacks and a remote that cannot be reached fail with one line, exit 1,
changing nothing local."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from tests.pipeline.project.conftest import artifact_digests, git, set_params
from zipon.cli import main

pytest_plugins = ["tests.fixtures.s3"]  # s3_endpoint


def dvc(root: Path, *args: str) -> str:
    done = subprocess.run([sys.executable, "-m", "dvc", *args], cwd=root, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


def zipon(root: Path, *args: str) -> int:
    return main(["-q", "-p", str(root / "params.yaml"), *args])


def tree(root: Path) -> dict[str, tuple[int, int]]:
    """Every file under ``root`` -> (size, mtime_ns): what a failed pull must leave as it was."""
    return {p.relative_to(root).as_posix(): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(root.rglob("*")) if p.is_file()}


def restore_each_version(clone: Path, expected: dict[str, dict[str, str]], capsys, tags=("v1", "v2")) -> None:
    for tag in tags:
        git(clone, "checkout", "-q", tag)
        assert zipon(clone, "pull") == 0, capsys.readouterr().err
        assert zipon(clone, "verify") == 0, capsys.readouterr().out
        assert zipon(clone, "status", "--check") == 0, capsys.readouterr()
        assert artifact_digests(clone) == expected[tag]
        capsys.readouterr()


@pytest.fixture(scope="module")
def pushed(dataset_versions, tmp_path_factory):
    """The project's versions pushed (every tag) to a local-folder remote; the remotes are the builder's own
    (``.dvc/config.local``), so the committed versions stay as built."""
    root = dataset_versions.root
    folder = tmp_path_factory.mktemp("remote") / "store"
    dvc(root, "remote", "add", "--local", "-f", "shelf", str(folder))
    assert zipon(root, "push", "-r", "shelf", "--all-tags") == 0
    return dataset_versions, folder


@pytest.mark.slow
def test_versions_restored_from_a_local_folder_remote_in_a_fresh_clone(pushed, tmp_path, capsys):
    versions, folder = pushed
    assert versions.digests["v1"]["sim_00/goals"] != versions.digests["v2"]["sim_00/goals"]
    assert versions.digests["v1"]["sim_00/frames"] == versions.digests["v2"]["sim_00/frames"]
    clone = tmp_path / "clone"
    git(tmp_path, "clone", "-q", str(versions.root), str(clone))
    dvc(clone, "remote", "add", "--local", "-d", "shelf", str(folder))
    restore_each_version(clone, versions.digests, capsys, ("v1", "v2", "v1"))


@pytest.mark.slow
def test_versions_restored_from_an_s3_remote(pushed, s3_endpoint, monkeypatch, tmp_path, capsys):
    from tests.fixtures.s3 import new_bucket  # here: a module-level import would come before pytest_plugins

    versions, _ = pushed
    bucket = new_bucket(s3_endpoint, monkeypatch)
    for where in (versions.root, tmp_path / "clone"):
        if where != versions.root:
            git(tmp_path, "clone", "-q", str(versions.root), str(where))
        dvc(where, "remote", "add", "--local", "-f", "-d", "s3", f"s3://{bucket}/ds")
        dvc(where, "remote", "modify", "--local", "s3", "endpointurl", s3_endpoint)
        if where == versions.root:
            assert zipon(where, "push", "-r", "s3", "--all-tags") == 0
            assert "remote s3 (s3://" in " ".join(capsys.readouterr().out.split())
    restore_each_version(tmp_path / "clone", versions.digests, capsys)


@pytest.mark.slow
def test_a_version_the_remote_lacks_names_its_missing_artifacts_and_changes_nothing(pushed, tmp_path, capsys):
    """v3 is built and tagged in one clone but never pushed: another clone that has v2 restored cannot pull v3, is
    told which artifacts the remote lacks, exit 1, and keeps its v2 data as they were."""
    versions, folder = pushed
    builder, other = tmp_path / "builder", tmp_path / "other"
    git(tmp_path, "clone", "-q", str(versions.root), str(builder))
    dvc(builder, "remote", "add", "--local", "-d", "shelf", str(folder))
    git(builder, "checkout", "-q", "-b", "more", "v2")
    assert zipon(builder, "pull") == 0
    set_params(builder / "params.yaml", {"goals": {"max_goals": 1}})
    assert zipon(builder, "run") == 0
    git(builder, "add", "-A")
    git(builder, "commit", "-q", "-m", "v3")
    git(builder, "tag", "v3")
    git(tmp_path, "clone", "-q", str(builder), str(other))
    dvc(other, "remote", "add", "--local", "-d", "shelf", str(folder))
    git(other, "checkout", "-q", "v2")
    assert zipon(other, "pull") == 0
    before = tree(other / "data")
    git(other, "checkout", "-q", "v3")
    capsys.readouterr()
    assert zipon(other, "pull") == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 or "\n" not in " ".join(err.split())
    said = " ".join(err.split())
    assert f"remote shelf ({folder}) lacks the data of this version: sim_00/goals (data/artifacts/sim_00/goals.zarr), " \
           "sim_00/routes (data/artifacts/sim_00/routes.zarr)" in said and "nothing local was changed" in said
    assert "frames" not in said.split("lacks the data")[1]
    assert tree(other / "data") == before


@pytest.mark.slow
def test_an_unreachable_remote_is_one_line_naming_it_and_the_artifact(pushed, tmp_path, monkeypatch, capsys):
    versions, folder = pushed
    clone = tmp_path / "clone"
    git(tmp_path, "clone", "-q", str(versions.root), str(clone))
    dvc(clone, "remote", "add", "--local", "-d", "shelf", str(folder))
    git(clone, "checkout", "-q", "v1")
    assert zipon(clone, "pull") == 0
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    dvc(clone, "remote", "add", "--local", "gone", "s3://nowhere/ds")
    dvc(clone, "remote", "modify", "--local", "gone", "endpointurl", f"http://127.0.0.1:{port}")
    for key, value in {"AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing", "AWS_MAX_ATTEMPTS": "1",
                       "AWS_DEFAULT_REGION": "us-east-1"}.items():
        monkeypatch.setenv(key, value)
    before = tree(clone / "data")
    git(clone, "checkout", "-q", "v2")
    capsys.readouterr()
    for command in ("pull", "push"):
        assert zipon(clone, command, "-r", "gone") == 1
        err = capsys.readouterr().err
        said = " ".join(err.split())
        assert said.startswith("error: remote gone (s3://nowhere/ds) unreachable while asking for sim_00/raw_log "
                               "(data/raw/sim_00.mcap) (EndpointConnectionError"), said
        assert err.count("error:") == 1
    assert tree(clone / "data") == before
    assert zipon(clone, "pull", "-r", "nonesuch") == 1
    assert "no DVC remote 'nonesuch'" in capsys.readouterr().err and os.path.isdir(clone / "data")
