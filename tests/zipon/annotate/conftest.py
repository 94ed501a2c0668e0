"""A copy of the tiny built scene for the annotation server's tests, and a client that talks to it as the page does
(its own origin on writes)."""

from __future__ import annotations

import io
import shutil
import socket
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

SCENE = "tiny"
ORIGIN = "http://127.0.0.1"


def copy_built(ws, dst: Path) -> Path:
    dst.mkdir(parents=True)
    shutil.copy(ws.params_path, dst / "params.yaml")
    shutil.copytree(ws.data_dir, dst / "data", ignore=shutil.ignore_patterns("renders", ".tmp", "*.lock"))
    shutil.copytree(ws.manifests_dir, dst / "manifests")
    return dst


def tree_state(root: Path) -> dict[str, tuple]:
    """Every file under ``root`` -> (size, mtime ns); lock files and renders left out (not built content)."""
    return {p.relative_to(root).as_posix(): (p.stat().st_size, p.stat().st_mtime_ns) for p in sorted(root.rglob("*"))
            if p.is_file() and not p.name.endswith(".lock") and "renders" not in p.parts}


def refused(r, status: int, *words: str) -> dict:
    """The JSON refusal ``r``, checked: its status, and each of ``words`` in its message or naming its field."""
    assert r.status_code == status, (r.status_code, r.text)
    body = r.json()
    for w in words:
        assert w in body["error"] or w == body.get("field"), (w, body)
    return body


def png(r) -> np.ndarray:
    """The PNG answer ``r`` as an array."""
    assert r.status_code == 200 and r.headers["content-type"] == "image/png", r.text
    return np.asarray(Image.open(io.BytesIO(r.content)))


def make_client(root: Path, **kw):
    from starlette.testclient import TestClient

    from zipon.annotate import app

    return TestClient(app(root / "params.yaml", root / "data", root / "manifests", **kw), base_url=ORIGIN)


def scene_summary(client, scene: str) -> dict:
    """``GET /api/scenes/<scene>``, asserted to answer 200."""
    r = client.get(f"/api/scenes/{scene}")
    assert r.status_code == 200, r.text
    return r.json()


@pytest.fixture(scope="module")
def shared_root(built_scene, tmp_path_factory) -> Path:
    """A copy only read (tests that write take their own)."""
    return copy_built(built_scene[0], tmp_path_factory.mktemp("annotate") / "ws")


@pytest.fixture
def own_root(built_scene, tmp_path) -> Path:
    return copy_built(built_scene[0], tmp_path / "ws")


@contextmanager
def serving(root: Path):
    """The app over ``root`` on a free port of 127.0.0.1, served by uvicorn in a thread while the block runs: its
    URL, ending in /."""
    import uvicorn

    from zipon.annotate import app

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app(root / "params.yaml", root / "data", root / "manifests"),
                                           host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        assert time.monotonic() < deadline and thread.is_alive(), "the server did not start"
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}/"
    finally:
        server.should_exit = True
        thread.join(timeout=10)


@pytest.fixture
def served(own_root):
    """The app over ``own_root`` served for the test's length: (its URL, ending in /, and the root)."""
    with serving(own_root) as url:
        yield url, own_root
