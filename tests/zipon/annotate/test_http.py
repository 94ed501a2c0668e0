"""What no client input may do: get a 500 or a plain-text answer. Deep nesting, huge numbers, non-ASCII tokens,
unknown paths and methods all answer a JSON 4xx naming the field; nothing on disk changes."""

from __future__ import annotations

import pytest

from tests.zipon.annotate.conftest import ORIGIN, SCENE, make_client, tree_state

W = {"headers": {"Origin": ORIGIN, "Content-Type": "application/json"}}


@pytest.fixture(scope="module")
def client(shared_root):
    return make_client(shared_root)


def refused(r, status: int, field: str, words: str) -> None:
    assert r.status_code == status and r.headers["content-type"] == "application/json", (r.status_code, r.text)
    assert r.json()["field"] == field and words in r.json()["error"], r.json()


def test_deeply_nested_body_under_the_cap(client, shared_root):
    before = tree_state(shared_root)
    deep = "[" * 100_000 + "]" * 100_000  # 200 kB, under the 2 MB cap: Python's parser would recurse to death
    refused(client.post(f"/api/scenes/{SCENE}/goals/validate", content=deep, **W), 413, "body", "nests too deeply")
    nested = '{"document": ' + '{"a": ' * 70 + "1" + "}" * 70 + "}"  # parses, but deeper than 64 levels
    refused(client.post(f"/api/scenes/{SCENE}/goals/validate", content=nested, **W), 413, "body", "nested 71 levels deep")
    assert tree_state(shared_root) == before


def test_numbers_the_parser_cannot_convert(client):
    refused(client.post(f"/api/scenes/{SCENE}/goals/validate", content='{"document": ' + "9" * 5000 + "}", **W),
            400, "body", "not JSON")
    refused(client.get(f"/api/scenes/{SCENE}/frames/{'9' * 5000}.png"), 400, "index", "is not an integer")
    refused(client.get(f"/api/scenes/{SCENE}/frames/-1.png"), 400, "index", "is outside 0..")
    refused(client.get(f"/api/scenes/{SCENE}/frames/0.png", params={"u": "1e300", "v": "0"}), 400, "u", "outside")


def test_non_ascii_and_odd_tokens(shared_root):
    client = make_client(shared_root, token="s3cret", allowed_hosts=None)
    refused(client.get("/api/scenes", params={"token": "sécret"}), 403, "token", "a token is needed")
    refused(client.get("/api/scenes", headers={"X-Zipon-Token": "sécret".encode()}), 403, "token", "a token is needed")
    refused(client.get("/api/scenes", headers={"Cookie": "zipon_annotate_token=\xe9\xff".encode("latin-1")}), 403,
            "token", "a token is needed")


def test_unknown_paths_and_methods_are_json(client):
    refused(client.get("/api/nothing"), 404, "path", "Not Found")
    refused(client.delete(f"/api/scenes/{SCENE}/goals"), 405, "method", "Method Not Allowed")
    refused(client.get(f"/api/scenes/{'x' * 3000}"), 404, "scene", "unknown scene")
