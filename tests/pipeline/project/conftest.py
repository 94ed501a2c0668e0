"""One dataset project built once for the tests of :mod:`pipeline.project`: ``zipon init``, a tiny simulated scene
built as version v1, ``goals.max_goals`` changed and built as v2, both committed and tagged with real git and recorded
with real DVC. Tests read it, clone it or copy it; they never change it."""

from __future__ import annotations

import json
import os
import subprocess
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

GIT_ENV = {"GIT_AUTHOR_NAME": "zipon tests", "GIT_AUTHOR_EMAIL": "tests@zipon.invalid",
           "GIT_COMMITTER_NAME": "zipon tests", "GIT_COMMITTER_EMAIL": "tests@zipon.invalid"}
TINY = {"simulate": {"frames": 6, "width": 160, "height": 120, "rooms_min": 2, "rooms_max": 2},
        "grid": {"rows": 240, "cols": 240}, "routes": {"episodes_per_goal": 1}, "goals": {"max_goals": 3}}


def git(root: Path, *args: str) -> str:
    done = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True,
                          env={**os.environ, **GIT_ENV})
    assert done.returncode == 0, done.stderr
    return done.stdout


def set_params(path: Path, changes: dict) -> None:
    """Update sections of a params file (its comments are lost: a test's edit)."""
    from pipeline.paramsfile import params_yaml, parse_params

    raw = yaml.safe_load(path.read_text())
    for section, values in changes.items():
        node = raw[section]
        for key, value in values.items():
            if isinstance(value, dict):
                node[key].update(value)
            else:
                node[key] = value
    path.write_text(params_yaml(parse_params(raw)))


def artifact_digests(root: Path) -> dict[str, str]:
    """``scene/artifact -> digest`` from the manifests under ``root``."""
    found = {}
    for path in sorted((root / "manifests").glob("*/*.json")):
        for name, rec in json.loads(path.read_text())["outputs"].items():
            found[f"{path.parent.name}/{name}"] = rec["digest"]
    return found


@dataclass(frozen=True)
class Versions:
    root: Path
    digests: dict[str, dict[str, str]]  # tag -> scene/artifact -> digest


@pytest.fixture(scope="session")
def dataset_versions(tmp_path_factory) -> Versions:
    from zipon.cli import main

    root = tmp_path_factory.mktemp("versions") / "ds"
    assert main(["-q", "init", str(root)]) == 0
    params = root / "params.yaml"
    set_params(params, {**TINY, "encoders": {"simulated_lseg": {"out_size": [30, 40]},
                                             "simulated_cf": {"out_size": [30, 40]}}})
    digests = {}
    for tag, max_goals in (("v1", 3), ("v2", 2)):
        set_params(params, {"goals": {"max_goals": max_goals}})
        assert main(["-q", "-p", str(params), "run"]) == 0
        git(root, "add", "-A")
        git(root, "commit", "-q", "-m", f"dataset {tag}")
        git(root, "tag", tag)
        digests[tag] = artifact_digests(root)
    return Versions(root, digests)
