"""Fuzzing the parsers users feed, as the trusted parsers are fuzzed (Hypothesis).

Structured: params documents, goal edits and objects files -- a valid document with random parts replaced,
removed or added (random structures and scalars), and random text -- read through the real loaders: the outcome
is a valid model or one clear error naming the file (ConfigError / InputDataError), never another exception.

Byte-level: real-format inputs written here (a TUM folder with PNG frames, a Replica sequence with JPEG
frames, a 7-Scenes sequence, an MCAP log, a ROS 1 bag) get bytes flipped, the file cut, or a run of bytes
duplicated, then go through ingest. Outcomes: ``identical`` frames (rgb, depth, pose, stamp, intrinsics as the
unmutated input gives), ``error`` (a ZiponError on one line naming a path of the input), or ``different`` frames.
``different`` is a failure wherever the format can tell a changed byte (PNG's chunk CRCs, MCAP's chunk CRCs,
a cut JPEG); it is tolerated, counted and documented (docs/input-validation.md) where the format carries no
integrity data: a digit changed in a TUM list or a pose file, a byte changed inside JPEG scan data or inside a
ROS 1 bag message's payload is a different valid input.

Bounded by default (fixed examples, ``derandomize``) so the module runs in well under a minute; set
``ZIPON_FUZZ_EXAMPLES=N`` for N random examples per property, and ``ZIPON_FUZZ_REPORT=FILE`` to write the
outcome counts as JSON.
"""

from __future__ import annotations

import copy
import json
import os
import shutil
import tempfile
from collections import Counter, defaultdict
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline.config import IngestParams, Params
from pipeline.paramsfile import load_params
from pipeline.errors import ConfigError, InputDataError, ZiponError
from pipeline.frames import FrameStore
from pipeline.goals.objects import objects_from_file
from pipeline.goals.schema import GoalsDocument, load_document
from pipeline.imagecodec import read_image_file
from pipeline.readers.ingest import ingest_path
from tests.fixtures.raw_datasets import (make_recording, write_7scenes, write_bag, write_mcap, write_replica,
                                         write_tum)

LONG = int(os.environ.get("ZIPON_FUZZ_EXAMPLES", "0"))
TALLY: dict[str, Counter] = defaultdict(Counter)


def fuzz_settings(bounded: int):
    """``bounded`` fixed examples in the suite; ``ZIPON_FUZZ_EXAMPLES`` random ones in a long run."""
    return settings(max_examples=LONG or bounded, deadline=None, database=None, derandomize=not LONG,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.filter_too_much])


@pytest.fixture(scope="module", autouse=True)
def report():
    yield
    figures = {k: dict(sorted(v.items())) for k, v in sorted(TALLY.items())}
    print("\nfuzz outcomes:", json.dumps(figures))
    if os.environ.get("ZIPON_FUZZ_REPORT"):
        Path(os.environ["ZIPON_FUZZ_REPORT"]).write_text(json.dumps(figures, indent=1) + "\n")


# ----------------------------------------------------------------------------- structured documents

SCALARS = st.one_of(st.none(), st.booleans(), st.integers(-(2**70), 2**70),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
                    st.sampled_from(["", "tiny", "simulate", "0.05", "yes", "~", "chair_0", "bedroom_1"]))
VALUES = st.recursive(SCALARS, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=10), inner, max_size=4)), max_leaves=10)


def _slots(doc, found=None, where=()):
    """Every (container, key) in ``doc`` (dict keys and list indices), depth first."""
    found = [] if found is None else found
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for k, v in items:
        found.append((doc, k))
        _slots(v, found)
    return found


def mutated(data, doc):
    """``doc`` with one to three random edits: a value replaced by a random structure, a key removed, a key added."""
    doc = copy.deepcopy(doc)
    for _ in range(data.draw(st.integers(1, 3), label="edits")):
        slots = _slots(doc)
        op = data.draw(st.sampled_from(["replace", "remove", "add", "root"] if slots else ["root"]), label="op")
        if op == "root":
            return data.draw(VALUES, label="whole document")
        container, key = data.draw(st.sampled_from(slots), label="slot")
        if op == "replace":
            container[key] = data.draw(VALUES, label="value")
        elif op == "remove":
            del container[key]
        elif isinstance(container, dict):
            container[data.draw(st.text(max_size=10), label="new key")] = data.draw(VALUES, label="value")
        else:
            container.insert(key, data.draw(VALUES, label="value"))
    return doc


def _dump(doc, suffix: str) -> str:
    return (yaml.safe_dump(doc, allow_unicode=True) if suffix == ".yaml"
            else json.dumps(doc, allow_nan=True, ensure_ascii=False))


def _structured(kind: str, load, doc, suffix: str, errors=(InputDataError,)):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"doc{suffix}"
        path.write_text(_dump(doc, suffix) if not isinstance(doc, str) else doc, encoding="utf-8")
        try:
            load(path)
        except errors as err:
            text = str(err)
            lines = text.splitlines()
            assert lines and all(str(path) in line for line in lines), text
            TALLY[kind]["error"] += 1
        else:
            TALLY[kind]["valid"] += 1


PARAMS_DOC = {"scenes": {"tiny": {"source": "simulate"}},
              **Params.model_validate({"scenes": {"tiny": {"source": "simulate"}}}).model_dump(mode="json")}


@fuzz_settings(60)
@given(st.data(), st.sampled_from([".yaml"]))
def test_params_documents(data, suffix):
    _structured("params documents", load_params, mutated(data, PARAMS_DOC), suffix, errors=(ConfigError,))


@fuzz_settings(30)
@given(st.text(max_size=200))
def test_params_text(text):
    _structured("params text", load_params, text, ".yaml", errors=(ConfigError,))


GOALS_DOC = {
    "format": "zipon-goals", "format_version": 1, "scene": "tiny",
    "rooms": {"bedroom_1": {"type": "bedroom", "owners": ["Alice"], "name": "Alice's bedroom"}},
    "objects": {"chair_0": {"class": "chair", "identity": "Alice's chair", "room": "bedroom_1", "position_xy": [5.8, 3.5]},
                "chair_1": {"class": "chair", "identity": "Bob's chair", "room": None, "position_xy": [1.0, 2.0]}},
    "goals": [{"id": "chair_0", "name": "Alice's chair", "type": "ambiguous", "room": "Alice's bedroom",
               "room_id": "bedroom_1", "objects": ["chair_0"],
               "feedback": {"corrective": {"chair_1": "This is Bob's chair."}, "descriptive": "A red chair.",
                            "landmark": "Next to the bed.", "procedural": None}}],
}
OBJECTS_DOC = {"rooms": [{"id": "r1", "type": "kitchen", "polygon": [[0, 0], [4, 0], [4, 3], [0, 3]]}],
               "objects": [{"key": "chair_0", "cls": "chair", "instance_id": 1, "footprint": [[0, 0], [1, 0], [1, 1]],
                            "mass_center": [0.7, 0.3], "room": "r1"}]}


def test_base_documents_are_valid(tmp_path):
    """The mutations start from valid documents (so the fuzzers reach the checks beyond the first one)."""
    GoalsDocument.model_validate(GOALS_DOC)
    path = tmp_path / "objects.yaml"
    path.write_text(yaml.safe_dump(OBJECTS_DOC))
    assert [o.key for o in objects_from_file(path, "tiny").objects] == ["chair_0"]


@fuzz_settings(60)
@given(st.data(), st.sampled_from([".yaml", ".json"]))
def test_goal_edits(data, suffix):
    _structured("goal edits", load_document, mutated(data, GOALS_DOC), suffix)


@fuzz_settings(60)
@given(st.data(), st.sampled_from([".yaml", ".json"]))
def test_objects_files(data, suffix):
    _structured("objects files", lambda p: objects_from_file(p, "tiny"), mutated(data, OBJECTS_DOC), suffix)


# ----------------------------------------------------------------------------- byte mutation of real-format inputs

REC = make_recording(n=6, h=24, w=32, seed=3)


def mutate_bytes(data, blob: bytes) -> tuple[bytes, str]:
    """Flip one bit, cut the file, or duplicate a run of up to 64 bytes in place; always a change."""
    kind = data.draw(st.sampled_from(["flip", "cut", "duplicate"]), label="mutation")
    at = data.draw(st.integers(0, len(blob) - 1), label="at")
    if kind == "flip":
        bit = data.draw(st.integers(0, 7), label="bit")
        return blob[:at] + bytes([blob[at] ^ (1 << bit)]) + blob[at + 1:], kind
    if kind == "cut":
        return blob[:at], kind
    n = data.draw(st.integers(1, 64), label="length")
    return blob[:at + n] + blob[at:at + n] + blob[at + n:], kind


def frames_of(store: Path) -> dict:
    fs = FrameStore(store)
    out = {name: fs.group[name][:] for name in ("rgb", "depth", "pose", "stamp")}
    out["intrinsics"] = fs.intrinsics.to_dict()
    return out


def same_frames(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        a[k] == b[k] if k == "intrinsics" else (a[k].shape == b[k].shape and np.array_equal(a[k], b[k])) for k in a)


def _write_sources(root: Path) -> dict[str, Path]:
    return {"tum": write_tum(root / "tum", REC), "replica": write_replica(root / "replica", REC),
            "7scenes": write_7scenes(root / "7scenes", REC), "mcap": write_mcap(root / "log.mcap", REC),
            "ros1": write_bag(root, REC, "ros1")}


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    """Each source and the frames ingest makes of it unmutated."""
    root = tmp_path_factory.mktemp("fuzz_sources")
    out = {}
    for name, src in _write_sources(root).items():
        ingest_path(src, root / f"{name}.zarr", IngestParams(), log=lambda m: None)
        out[name] = (src, frames_of(root / f"{name}.zarr"))
    return out


# target -> (source, files of it to mutate (globs; '' = the source file itself), outcomes allowed per mutation kind)
STRICT = {"identical", "error"}
ANY = {"identical", "error", "different"}
TARGETS = {
    "TUM PNG frames": ("tum", ("rgb/*.png", "depth/*.png"), {"flip": STRICT, "cut": STRICT, "duplicate": STRICT}),
    "TUM lists": ("tum", ("rgb.txt", "depth.txt", "groundtruth.txt"), {"flip": ANY, "cut": ANY, "duplicate": ANY}),
    "Replica JPEG frames": ("replica", ("results/frame*.jpg",), {"flip": ANY, "cut": STRICT, "duplicate": ANY}),
    "Replica traj.txt": ("replica", ("traj.txt",), {"flip": ANY, "cut": ANY, "duplicate": ANY}),
    "7-Scenes pose files": ("7scenes", ("frame-*.pose.txt",), {"flip": ANY, "cut": ANY, "duplicate": ANY}),
    "MCAP log": ("mcap", ("",), {"flip": STRICT, "cut": STRICT, "duplicate": STRICT}),
    "ROS 1 bag": ("ros1", ("",), {"flip": ANY, "cut": STRICT, "duplicate": ANY}),
}


def _ingest_mutated(target: str, data, sources) -> None:
    source_name, globs, allowed = TARGETS[target]
    src, expected = sources[source_name]
    with tempfile.TemporaryDirectory() as tmp:
        copy_ = Path(tmp) / src.name
        (shutil.copytree if src.is_dir() else shutil.copy)(src, copy_)
        files = sorted(f for g in globs for f in ([copy_] if g == "" else copy_.glob(g)))
        victim = data.draw(st.sampled_from(files), label="file")
        blob, kind = mutate_bytes(data, victim.read_bytes())
        victim.write_bytes(blob)
        try:
            ingest_path(copy_, Path(tmp) / "out.zarr", IngestParams(), log=lambda m: None)
        except ZiponError as err:
            text = str(err)
            assert "\n" not in text and str(copy_) in text, text
            outcome = "error"
        else:
            outcome = "identical" if same_frames(frames_of(Path(tmp) / "out.zarr"), expected) else "different"
        TALLY[target][f"{kind}: {outcome}"] += 1
        assert outcome in allowed[kind], f"{target}: {kind} of {victim.relative_to(copy_.parent)} -> {outcome}"


@pytest.mark.parametrize("target", list(TARGETS))
def test_byte_mutation_through_ingest(target, sources):
    @fuzz_settings(12)
    @given(st.data())
    def run(data):
        _ingest_mutated(target, data, sources)

    run()


PNG = cv2.imencode(".png", REC.rgb[0])[1].tobytes()
PNG16 = cv2.imencode(".png", REC.depth_mm[0])[1].tobytes()
JPEG = cv2.imencode(".jpg", REC.rgb[0])[1].tobytes()


@fuzz_settings(150)
@given(st.data(), st.sampled_from(["png", "png16", "jpeg"]))
def test_byte_mutation_of_frames(data, which):
    """One frame file mutated and decoded as the readers decode it: a changed PNG is always refused; a cut JPEG is
    refused; any other JPEG change decodes to an image of the same size or is refused (JPEG has no checksum)."""
    blob, kind = mutate_bytes(data, {"png": PNG, "png16": PNG16, "jpeg": JPEG}[which])
    with tempfile.TemporaryDirectory() as tmp:
        f = Path(tmp) / f"frame.{'jpg' if which == 'jpeg' else 'png'}"
        f.write_bytes(blob)
        try:
            img = read_image_file(f, cv2.IMREAD_UNCHANGED, frame=0, what="colour")
        except InputDataError as err:
            assert str(err).startswith(f"file {f}; frame 0: ")
            outcome = "error"
        else:
            assert which == "jpeg" and kind != "cut", f"{which}: {kind} decoded"
            assert img.shape[:2] == REC.rgb[0].shape[:2]
            outcome = "decoded"
    TALLY[f"{which} frame"][f"{kind}: {outcome}"] += 1


# ----------------------------------------------------------------------------- the workbench's endpoints

HOSTILE_TEXT = st.one_of(st.text(max_size=40), st.sampled_from([
    "tiny", "..", "../params.yaml", "%2e%2e", "9" * 5000, "-1", "0", "1e400", "NaN", "é", "\x00", "a" * 3000,
    "recon", "vlmap", "cfmap", "occupancy", "ffffff", "0" * 64]))
OBJECT_PATHS = st.one_of(HOSTILE_TEXT, st.sampled_from([
    "params.yaml", "dvc.lock", "manifests/tiny/goals.json", "data/artifacts/tiny/goals.zarr/zarr.json",
    "objects/../params.yaml", "objects/x.yaml", "goals_edits/tiny-0.yaml", "/etc/passwd", ".dvc/config"]))


@pytest.fixture(scope="module")
def workbench(built_scene, tmp_path_factory):
    from starlette.routing import Route
    from starlette.testclient import TestClient

    from tests.zipon.annotate.conftest import ORIGIN, copy_built
    from zipon.annotate import app

    root = copy_built(built_scene[0], tmp_path_factory.mktemp("fuzz_workbench") / "ws")
    application = app(root / "params.yaml", root / "data", root / "manifests")
    routes = [(r.path, sorted(r.methods - {"HEAD"})) for r in application.routes if isinstance(r, Route)]
    client = TestClient(application, base_url=ORIGIN, raise_server_exceptions=False)
    goals = client.get("/api/scenes/tiny/goals").json()["document"]
    return client, root, routes, goals


def _state(root: Path) -> dict:
    return {p.relative_to(root).as_posix(): (p.stat().st_size, p.stat().st_mtime_ns) for p in sorted(root.rglob("*"))
            if not p.name.endswith(".lock") and "renders" not in p.parts}


def _hostile_body(data, goals):
    kind = data.draw(st.sampled_from(["document", "objects", "play", "reply", "values", "bytes", "deep"]), label="body")
    if kind == "document":
        return "json", {"document": mutated(data, goals)}
    if kind == "objects":
        return "json", {"path": data.draw(OBJECT_PATHS), "objects": data.draw(VALUES), "rooms": data.draw(VALUES)}
    if kind == "play":
        return "json", {"method": data.draw(st.one_of(HOSTILE_TEXT, st.sampled_from(["human", "cow", "orion"]))),
                        "goal": data.draw(VALUES), "seed": data.draw(SCALARS)}
    if kind == "reply":
        return "json", {"text": data.draw(VALUES)}
    if kind == "values":
        return "json", data.draw(VALUES)
    if kind == "bytes":
        return "raw", data.draw(st.binary(max_size=200))
    opener = data.draw(st.sampled_from(["[", '{"a":', '{"document":[']))
    return "raw", (opener * data.draw(st.integers(60, 60_000))).encode()


@fuzz_settings(150)
@given(st.data())
def test_workbench_endpoints(workbench, data):
    """Every route of the app with hostile path parameters, query strings, headers and bodies: never a 5xx, every
    refusal a JSON error naming a field, and nothing on disk changed (an objects file the policy allows is the
    one write that may happen; it is removed again)."""
    import re as _re
    from urllib.parse import quote

    client, root, routes, goals = workbench
    path, methods = data.draw(st.sampled_from(routes), label="route")
    method = data.draw(st.sampled_from(methods), label="method")
    url = _re.sub(r"\{(\w+)(:\w+)?\}", lambda m: quote(data.draw(HOSTILE_TEXT, label=m.group(1)) if data.draw(
        st.booleans(), label=f"hostile {m.group(1)}") else ("tiny" if m.group(1) == "scene" else "0"), safe=""), path)
    query = data.draw(st.dictionaries(st.sampled_from(["x", "y", "u", "v", "yaw_deg", "map", "text", "objects", "floor",
                                                       "token"]), HOSTILE_TEXT, max_size=4), label="query")
    headers = {"Origin": data.draw(st.one_of(st.just("http://127.0.0.1"),  # the page's own, half the time
                                             st.sampled_from(["http://evil.example", "null", ""]))),
               "If-Match": data.draw(st.one_of(HOSTILE_TEXT, st.just('"' + "0" * 64 + '"'))).encode(),
               "X-Zipon-Token": data.draw(st.binary(max_size=8)).replace(b"\n", b"").replace(b"\r", b"")}
    if data.draw(st.integers(0, 3), label="odd host") == 0:
        headers["Host"] = data.draw(st.sampled_from(["evil.example", "127.0.0.1:1", "[::1]", "é"])).encode()
    before = _state(root)
    if method in ("POST", "PUT"):
        kind, body = _hostile_body(data, goals)
        content = json.dumps(body, allow_nan=True).encode() if kind == "json" else body
        r = client.request(method, url, params=query, headers=headers, content=content)
    else:
        r = client.request(method, url, params=query, headers=headers)
    assert r.status_code < 500, (method, url, r.status_code, r.text[:500])
    kind = "ok" if r.status_code < 400 else "refused"
    if r.status_code >= 400:
        assert r.headers["content-type"] == "application/json", r.text[:200]
        assert "field" in r.json() and r.json()["error"], r.text[:200]
    after = _state(root)
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    if changed and method == "PUT" and path.endswith("/objects") and r.status_code == 200:
        written = r.json()["path"]
        assert all(k == written or k.startswith("objects") for k in changed), changed
        shutil.rmtree(root / "objects", ignore_errors=True)
        (root / written).unlink(missing_ok=True)
        kind = "objects file written"
        changed = sorted(k for k in set(before) | set(_state(root)) if before.get(k) != _state(root).get(k))
    assert not changed, (method, url, r.status_code, changed)
    TALLY["workbench endpoints"][f"{method} {path}: {kind}"] += 1


# ----------------------------------------------------------------------------- what zipon reads back

HUMAN_RECORD = {"scene": "tiny", "method": "cow", "feedback": "human", "seed": 0, "goal": "g0", "goal_type": "big",
                "episode": "e0", "success": True, "spl": 0.5, "sit": 1.0, "talk_turns": 1, "steps": 12,
                "travelled_m": 3.2, "geodesic_m": 1.6, "collisions": 0, "end": "found", "final_distance_m": 0.4,
                "log": {"dialogue": [{"speaker": "user", "text": "No."}]}}


@fuzz_settings(80)
@given(st.data())
def test_human_episode_records(data):
    """A stored human-answered episode with random parts replaced, removed or added: kept as a valid record (its
    numbers finite), left out (another scene, method or goal), or one error naming the file, the line and a field."""
    from orion_eval.records import read_human_episodes

    record = mutated(data, HUMAN_RECORD)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "tiny.episodes.jsonl"
        path.write_text(json.dumps(HUMAN_RECORD) + "\n" + json.dumps(record, allow_nan=True) + "\n")
        try:
            read = read_human_episodes(path, "tiny", {"g0"}, ["cow"])
        except InputDataError as err:
            assert str(path) in str(err) and "line 2" in str(err) and "\n" not in str(err), str(err)
            TALLY["human episode records"]["error"] += 1
            return
    json.dumps(read.records, allow_nan=False)  # what is kept can be written as strict JSON
    TALLY["human episode records"]["kept" if len(read.records) == 2 else "left out"] += 1


@fuzz_settings(150)
@given(st.one_of(st.text(max_size=300), st.builds(lambda doc: json.dumps(doc, allow_nan=True), VALUES),
                 st.builds(lambda pre, action, args, post: pre + json.dumps({"thought": "", "action": action,
                                                                            "args": args}) + post,
                           st.text(max_size=20), st.sampled_from(["talk", "move", "goto_object", "fly"]),
                           st.dictionaries(st.sampled_from(["content", "dist_m", "obj_id"]), SCALARS, max_size=3),
                           st.text(max_size=20)),
                 st.builds(lambda n, c: c * n, st.integers(1, 50_000), st.sampled_from(["{", "[", '{"a":', "{{}"]))))
def test_llm_replies(text):
    """Whatever a model answers, parsing its reply is one clear error or an action, in linear time."""
    import time

    from orion_eval.llm import AGENT_FUNCTIONS, parse_action

    t0 = time.perf_counter()
    try:
        act = parse_action(text)
    except InputDataError as err:
        TALLY["llm replies"]["error"] += 1
        assert str(err).count("\n") == 0
    else:
        assert act.action in AGENT_FUNCTIONS
        TALLY["llm replies"]["action"] += 1
    assert time.perf_counter() - t0 < 1.0, len(text)
