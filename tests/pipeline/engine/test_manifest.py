"""Manifests read back as user input: each bad file one ArtifactError naming it and the first problem."""

from __future__ import annotations

import json

import pytest

from pipeline.engine.manifest import MAX_MANIFEST_BYTES, Manifest
from pipeline.errors import ArtifactError

GOOD = {"stage": "goals", "scene": "tiny", "code_version": "1", "code_digest": "d", "params": {}, "params_digest": "p",
        "inputs": {}, "outputs": {"goals": {"path": "data/x", "digest": "blake3:00"}}}


@pytest.mark.parametrize("data, words", [
    (b"\xff\xfe{", "Invalid JSON"),
    (b"[" * 100_000, "recursion limit"),
    (json.dumps({**GOOD, "params_digest": 3}).encode(), "params_digest: Input should be a valid string"),
    (json.dumps({k: v for k, v in GOOD.items() if k != "outputs"}).encode(), "outputs: Field required"),
    (json.dumps({**GOOD, "extra": 1}).encode(), "extra: Extra inputs are not permitted"),
    (b" " * (MAX_MANIFEST_BYTES + 1), "over 16,777,216 bytes"),
])
def test_bad_manifests_are_named(tmp_path, data, words):
    path = tmp_path / "goals.json"
    path.write_bytes(data)
    with pytest.raises(ArtifactError) as err:
        Manifest.read(path)
    assert str(err.value).startswith(f"{path}: not a valid zipon manifest: ") and words in str(err.value), str(err.value)


def test_a_good_manifest_round_trips(tmp_path):
    man = Manifest.model_validate(GOOD)
    man.write(tmp_path / "m.json")
    assert Manifest.read(tmp_path / "m.json") == man and Manifest.read(tmp_path / "none.json") is None
